"""Which directions of (T_base_cam, td) did the recording determine, and which came from a prior?

Input: the joint marginal covariance of (T_base_cam, td) after the optimisation (everything else
marginalised) and the information the priors alone put on those seven numbers. Both are expressed in
"user axes": rotation about the base axes (roll about x forward, pitch about y left, yaw about z up),
translation of the camera along the base axes, and td.

For each axis the posterior sigma is compared with the prior sigma. The ratio says how much the data
shrank the uncertainty: close to 1 means the data said nothing (the value is the prior's), small means
the recording pinned it down. The same comparison along the eigen-directions of the posterior
information relative to the prior information (a generalised eigenproblem) finds unobservable
*combinations* (for example td traded against forward position under constant-speed driving).

Thresholds (ratio = posterior sigma / prior sigma): <= ``OBSERVABLE_RATIO`` observable, >=
``UNOBSERVABLE_RATIO`` unobservable, in between weak. With a weak regularising prior of 1 m / 0.5 rad /
50 ms, "observable" means the data knows the direction at least ten times better than the prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..errors import InputError

OBSERVABLE_RATIO = 0.1
UNOBSERVABLE_RATIO = 0.5

AXES = ("roll", "pitch", "yaw", "x", "y", "z", "td")
UNITS = ("deg", "deg", "deg", "m", "m", "m", "ms")
_TO_UNIT = np.array([np.degrees(1.0)] * 3 + [1.0] * 3 + [1e3])
DESCRIPTIONS = {
    "roll": "camera rotation about the base's forward axis (roll, base x)",
    "pitch": "camera rotation about the base's left axis (pitch, base y)",
    "yaw": "camera rotation about the base's vertical axis (yaw, base z)",
    "x": "camera position forward (translation x)",
    "y": "camera position sideways (translation y)",
    "z": "camera height (translation z)",
    "td": "time offset td between camera and odometry clocks",
}
# Why a direction is typically lost, and what fixes it; added to the message of an unobservable axis.
_WHY = {
    "z": (
        "under planar motion the base never moves along its vertical axis, so a camera mounted higher or lower "
        "(with the board correspondingly higher or lower) explains the images equally well; give the measured "
        "camera height (--camera-height) or the height of the board's origin above the floor (--board-height)"
    ),
    "roll": "driving straight without turning does not excite rotation about the driving direction; turn while driving",
    "yaw": "turning in place does not excite rotation about the turning axis; drive forward and backward as well",
    "x": "without turning, a shift of the camera cannot be told from a shift of the board; turn while driving",
    "y": "without turning, a shift of the camera cannot be told from a shift of the board; turn while driving",
    "td": "the speed never changes enough to time-align the streams; accelerate and brake during the recording",
}


def status_of(ratio: float) -> str:
    if not np.isfinite(ratio):
        return "unknown"
    if ratio <= OBSERVABLE_RATIO:
        return "observable"
    if ratio >= UNOBSERVABLE_RATIO:
        return "unobservable"
    return "weak"


def user_axes_jacobian(R_base_cam: np.ndarray) -> np.ndarray:
    """Map (7 x 7) from GTSAM tangent (rotation, translation in the camera frame; td) to user axes.

    A right perturbation ``T Exp(w, u)`` rotates the camera by ``R w`` about base axes and moves it by
    ``R u`` in the base frame (to first order).
    """
    J = np.eye(7)
    J[:3, :3] = R_base_cam
    J[3:6, 3:6] = R_base_cam
    return J


@dataclass(frozen=True)
class AxisVerdict:
    """One named axis (or eigen-direction) with its posterior and prior sigma in display units."""

    name: str
    description: str
    sigma: float
    prior_sigma: float
    ratio: float
    status: str
    unit: str = ""
    composition: dict = field(default_factory=dict)  # for eigen-directions: axis -> share (sums to 1)
    message: str = ""


@dataclass(frozen=True)
class ObservabilityReport:
    """Verdicts per axis and per eigen-direction, and sentences for the user."""

    axes: tuple[AxisVerdict, ...]
    directions: tuple[AxisVerdict, ...]
    messages: tuple[str, ...]
    converged: bool
    regularized: bool

    @property
    def unobservable(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes if a.status == "unobservable")

    @property
    def weak(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes if a.status == "weak")

    @property
    def observable(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes if a.status == "observable")

    def status(self, name: str) -> str:
        for a in self.axes:
            if a.name == name:
                return a.status
        raise KeyError(name)

    def to_dict(self) -> dict:
        def row(a: AxisVerdict) -> dict:
            return {
                "name": a.name,
                "description": a.description,
                "sigma": a.sigma,
                "prior_sigma": a.prior_sigma,
                "unit": a.unit,
                "ratio": a.ratio,
                "status": a.status,
                "composition": dict(a.composition),
                "message": a.message,
            }

        return {
            "converged": self.converged,
            "regularized": self.regularized,
            "axes": [row(a) for a in self.axes],
            "directions": [row(a) for a in self.directions],
            "messages": list(self.messages),
        }

    def to_markdown(self) -> str:
        lines = ["| axis | posterior sigma | prior sigma | ratio | verdict |", "|---|---|---|---|---|"]
        for a in self.axes:
            sig = f"{a.sigma:.3g} {a.unit} | {a.prior_sigma:.3g} {a.unit}"
            lines.append(f"| {a.description} | {sig} | {a.ratio:.3f} | {a.status} |")
        if self.directions:
            lines += ["", "| eigen-direction (share of each axis) | ratio | verdict |", "|---|---|---|"]
            for d in self.directions:
                lines.append(f"| {d.description} | {d.ratio:.3f} | {d.status} |")
        if self.messages:
            lines.append("")
            lines += [f"- {m}" for m in self.messages]
        return "\n".join(lines)


def not_converged_report(reason: str) -> ObservabilityReport:
    """A report that refuses to classify: a covariance of an unconverged solve is not to be trusted."""
    axes = tuple(
        AxisVerdict(n, DESCRIPTIONS[n], float("nan"), float("nan"), float("nan"), "unknown", u)
        for n, u in zip(AXES, UNITS, strict=True)
    )
    msg = f"no uncertainty or observability verdict: {reason}"
    return ObservabilityReport(axes, (), (msg,), converged=False, regularized=True)


def _describe_direction(share: np.ndarray, signs: np.ndarray) -> str:
    order = np.argsort(share)[::-1]
    parts = []
    for k in order:
        if share[k] < 0.05 or len(parts) == 3:
            break
        parts.append(f"{'-' if signs[k] < 0 and parts else ''}{AXES[k]} {100 * share[k]:.0f}%")
    return "combination of " + ", ".join(parts) if len(parts) > 1 else f"{AXES[order[0]]} alone"


def observability_report(
    cov_user: np.ndarray,
    prior_information_user: np.ndarray,
    *,
    converged: bool = True,
    regularized: bool = True,
    planar_motion: bool = True,
    prior_notes: dict[str, str] | None = None,
    held_weak: tuple[str, ...] = (),
) -> ObservabilityReport:
    """Classify the 7 user axes and the eigen-directions of a posterior covariance against the priors.

    ``cov_user`` (7, 7): posterior covariance of (roll, pitch, yaw [rad], x, y, z [m], td [s]) in base axes;
    ``prior_information_user`` (7, 7): information the priors alone put on the same axes (must be positive
    definite: the regularising priors guarantee it). ``prior_notes`` maps an axis name to a sentence about a
    user prior that informs it (e.g. a measured camera height); such an axis is reported as coming from
    that prior even when the classification calls it observable. ``held_weak``: unobservable axes that the data did
    determine, too weakly to be used (held at the seed by the refinement's freezing rule): their message says so
    instead of naming a motion that would not excite them (the note in ``prior_notes`` says how well they were
    determined).
    """
    if not converged:
        return not_converged_report("the optimisation did not converge")
    cov = np.asarray(cov_user, dtype=float)
    Lp = np.asarray(prior_information_user, dtype=float)
    if cov.shape != (7, 7) or Lp.shape != (7, 7) or not (np.all(np.isfinite(cov)) and np.all(np.isfinite(Lp))):
        raise InputError("observability: need finite 7 x 7 posterior covariance and prior information")
    cov = 0.5 * (cov + cov.T)
    prior_cov = np.linalg.inv(Lp)
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    psig = np.sqrt(np.diag(prior_cov))
    notes = dict(prior_notes or {})
    axes = []
    messages = []
    for k, name in enumerate(AXES):
        ratio = float(sig[k] / psig[k])
        st = status_of(ratio)
        msg = ""
        if st == "unobservable":
            why = _WHY.get(name, "")
            if name == "z" and not planar_motion:
                why = ""
            if name in held_weak:
                msg = (f"{DESCRIPTIONS[name]} is too weakly determined by this recording to be used; its value is the "
                       "seed's.")
            else:
                msg = f"{DESCRIPTIONS[name]} is not observable from this recording; its value comes from the prior"
                msg += f" ({why})." if why else "."
        elif st == "weak":
            why = _WHY.get(name, "") if (name != "z" or planar_motion) else ""
            msg = (
                f"{DESCRIPTIONS[name]} is only weakly observed (sigma {sig[k] * _TO_UNIT[k]:.3g} {UNITS[k]}, "
                f"{100 * ratio:.0f}% of the prior's)"
            )
            msg += f"; {why}." if why else "."
        if name in notes:
            msg = (msg + " " if msg else "") + notes[name]
        if msg:
            messages.append(msg)
        axes.append(
            AxisVerdict(name, DESCRIPTIONS[name], float(sig[k] * _TO_UNIT[k]), float(psig[k] * _TO_UNIT[k]),
                        ratio, st, UNITS[k], message=msg)
        )
    # Generalised eigenproblem: posterior information against prior information along each direction.
    S = np.diag(psig)  # prior-scaled (dimensionless) coordinates
    info_post = np.linalg.inv(cov)
    lam, V = scipy.linalg.eigh(S @ info_post @ S, S @ Lp @ S)
    lam = np.clip(lam, 1e-300, None)
    directions = []
    for j in range(7):
        v = V[:, j] / np.linalg.norm(V[:, j])
        share = v**2
        ratio = float(1.0 / np.sqrt(lam[j]))
        dom = int(np.argmax(share))
        signs = np.sign(v) * np.sign(v[dom])
        st = status_of(ratio)
        directions.append(
            AxisVerdict(f"e{j}", _describe_direction(share, signs), float("nan"), float("nan"), ratio, st,
                        composition={AXES[k]: float(share[k]) for k in range(7) if share[k] >= 0.01})
        )
        if st == "unobservable" and share[dom] < 0.9:
            messages.append(
                f"the {directions[-1].description} is not observable as a whole "
                f"(posterior/prior sigma {ratio:.2f}): these axes trade off against each other."
            )
    if regularized:
        messages.append(
            "weak regularising priors on T_base_cam and td keep the problem solvable; axes marked unobservable "
            "carry the prior's value and sigma, not a measurement."
        )
    return ObservabilityReport(tuple(axes), tuple(directions), tuple(messages), True, regularized)
