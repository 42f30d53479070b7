"""Closed-form calibration from a camera track and a base track: time offset, rotation, planar translation.

What planar motion can determine (frames: base x forward, y left, z up; ``R = R_base_cam``)

* Angular velocity. The base turns about its z axis only, so omega_cam = R^T (0, 0, w): turning fixes where
  the base's vertical axis lies in the camera frame, i.e. the camera's roll and pitch relative to the floor,
  and nothing about its yaw (any rotation about base z maps (0, 0, w) to itself).
* Linear velocity. The camera moves with v_cam = R^T (v_base + omega_base x t), t = t_base_cam. Without
  turning this is R^T (v, 0, 0): driving fixes where the base's forward axis lies in the camera frame (yaw and
  pitch), not the roll about it. The lever-arm term w (-t_y, t_x, 0) lies in the floor plane; it is not known
  before t is, so it is estimated and removed in a few alternations (rotation, then translation, repeat).
* Together, turning while driving fixes two different base axes and so all three angles. Spinning in place
  (no forward speed) leaves the yaw unknown: the linear velocity is then the lever-arm term alone, whose base
  direction depends on the unknown t. Driving straight leaves the roll unknown.
* Translation. Relative motions A (base) and B (camera) over ~1 s satisfy A X = X B; with planar A the
  equations (R_A - I) t = R t_B - t_A have a zero third row (after Guo et al. 2012, CamOdoCal): t_x and t_y
  follow by least squares once there is turning, the camera height t_z never does (the translation along the
  rotation axis of every motion is invisible). The result reports t_z as NaN and says so.
* Constant-curvature driving (v proportional to w, e.g. one steady circle) confounds yaw with the sideways
  lever arm in the velocity equations; it is detected and reported.

The default rotation solver is PLS (``plsgraph.calib.solvers.solve``) on the stacked angular and linear velocity
rows, the linear rows scaled to the same RMS as the angular ones so that both axes weigh alike, weighted by the
pose covariances and reweighted (Huber) against samples the model does not explain. The lever arm comes with
the odometry's speed and turn-rate scale factors (wrong wheel radius, effective track width), and td is refined
from the full velocity residual once the model is known. See docs/odometry_and_time_offset.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.geometry import inv_T
from ..core.tracks import BaseTrack, CameraTrack
from ..errors import DegenerateMotionError, InputError, PlsgraphError
from ..odometry.wheels import in_gap, rescale_planar_track
from . import solvers as closedform
from .time_offset import (
    DEFAULT_WINDOW_S,
    CameraVelocities,
    PairedSamples,
    TimeOffsetResult,
    camera_velocities_on_grid,
    estimate_time_offset,
    pair_samples,
)

log = logging.getLogger(__name__)

#: RMS turn rate (rad/s) below which the angular velocity says nothing about roll and pitch.
MIN_TURN_RATE = 0.05
#: RMS forward speed (m/s) below which the linear velocity says nothing about yaw.
# Speed (m/s) below which the robot only spins (yaw unobservable): its RMS over the paired samples, or its 90th
# percentile (the RMS alone is diluted by every extra detection of a board seen while the robot crept or stood).
MIN_DRIVING_SPEED = 0.05
#: Huber threshold in robust sigmas for the velocity rows and the td refinement.
HUBER_K = 2.5
#: |cosine| between forward speed and turn rate above which the driving is constant-curvature.
MAX_SPEED_TURN_COSINE = 0.98


@dataclass(frozen=True)
class MethodResult:
    """One solver's answer, or why it gave none (``error``)."""

    R_base_cam: np.ndarray | None
    t_base_cam: np.ndarray | None = None
    error: str | None = None
    warnings: list[str] = field(default_factory=list)
    diagnostics: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ClosedFormResult:
    """Closed-form calibration.

    ``R_base_cam`` (3, 3) from ``method`` (None if the motion did not determine it); ``t_xy`` (2,) the camera
    position in the floor plane (None if unobservable) and ``t_base_cam`` (3,) with z = NaN (the height is not
    observable from planar motion); ``td`` (s, t_odom = t_cam + td) with the search in ``time_offset``;
    ``methods`` every solver's answer (pls, pls_paper, cca, procrustes, hand_eye_*); ``vertical_axis_cam`` the
    base's up axis seen in the camera frame (from turning alone, available even when the yaw is not) and
    ``forward_axis_cam`` its forward axis (from driving alone, available even when the roll is not);
    ``observable`` per axis (roll, pitch, yaw, x, y, z, td); ``n_pairs`` paired samples used and
    ``discarded`` counts of what was dropped; ``degenerate`` with ``degenerate_reasons`` when a quantity the
    result reports could not be determined; ``warnings`` everything else worth a look.
    """

    R_base_cam: np.ndarray | None
    t_xy: np.ndarray | None
    t_base_cam: np.ndarray | None
    td: float
    method: str
    time_offset: TimeOffsetResult | None
    methods: dict[str, MethodResult]
    vertical_axis_cam: np.ndarray | None
    forward_axis_cam: np.ndarray | None
    observable: dict[str, bool]
    excitation: dict[str, float]
    n_pairs: int
    discarded: dict[str, int]
    degenerate: bool
    degenerate_reasons: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    t_xy_velocity: np.ndarray | None = None
    odometry_scale: dict[str, float] = field(default_factory=dict)
    # The model-based time-offset search found its best offset at the edge of its first range (+-100 ms around the
    # correlation's): the camera's and the odometry's motions agree at no offset near the correlation's.
    td_at_border: bool = False


def _stack_rows(
    pairs: PairedSamples, t_xy: np.ndarray, speed_scale: float = 1.0, turn_scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray, float]:
    """Stacked camera (X) and base (Y) rows: angular velocities, then lever-arm-corrected linear velocities.

    The odometry's velocities are corrected by the current scale estimates; the linear rows are scaled by
    RMS(omega) / RMS(v) so both blocks carry the same weight.
    """
    t3 = np.r_[t_xy, 0.0]
    w_b = turn_scale * pairs.omega_base
    v_eff = speed_scale * pairs.v_base + np.cross(w_b, t3)
    rms_w = np.sqrt(np.mean(np.sum(w_b**2, axis=1)))
    rms_v = np.sqrt(np.mean(np.sum(v_eff**2, axis=1)))
    k = rms_w / rms_v if rms_v > 0 and rms_w > 0 else 1.0
    X = np.vstack([pairs.omega_cam, k * pairs.v_cam])
    Y = np.vstack([w_b, k * v_eff])
    return X, Y, float(k)


def lever_arm_and_odometry_scales(
    pairs: PairedSamples,
    R_base_cam: np.ndarray,
    estimate_scales: bool = True,
    estimate_speed_scale: bool = True,
    weights: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, float, float]:
    """Camera position t_xy and the odometry's speed and turn-rate scale factors from paired velocities.

    The camera measures true rates; if the odometry's are off by factors (a wrong wheel radius, a skid-steer
    robot's effective track width), R omega_cam = s_w omega_base and R v_cam = s_v v_base + s_w omega_base x t.
    s_w comes from the first equation; s_v, t_x, t_y jointly from the second by least squares. Without
    ``estimate_scales`` both are 1; without ``estimate_speed_scale`` s_v is 1 (needed when speed and turn rate
    are proportional, which makes s_v and t_y inseparable). ``weights`` = (angular, linear) per-sample weights.
    """
    n = pairs.t.size
    ww_, wv_ = (np.ones(n), np.ones(n)) if weights is None else weights
    w = pairs.omega_base[:, 2]
    ww = float(ww_ @ (w * w))
    if not ww > 0:
        raise DegenerateMotionError("lever arm: the base never turns, so the camera position is unobservable")
    s_w = float(ww_ @ ((pairs.omega_cam @ R_base_cam.T)[:, 2] * w) / ww) if estimate_scales else 1.0
    if not s_w > 0:
        raise DegenerateMotionError(
            f"the camera turns against the odometry (turn-rate scale {s_w:.3f}); check the wheel order/signs"
        )
    r = pairs.v_cam @ R_base_cam.T
    vx, vy = pairs.v_base[:, 0], pairs.v_base[:, 1]
    z = np.zeros_like(w)
    sq = np.sqrt(np.r_[wv_, wv_])
    if estimate_scales and estimate_speed_scale:
        # Unknowns (s_v, t_x, t_y): x rows s_v v_x - s_w w t_y, y rows s_v v_y + s_w w t_x.
        A = np.vstack([np.column_stack([vx, z, -s_w * w]), np.column_stack([vy, s_w * w, z])])
        sol, *_ = np.linalg.lstsq(A * sq[:, None], np.r_[r[:, 0], r[:, 1]] * sq, rcond=None)
        if not sol[0] > 0:
            raise DegenerateMotionError(
                f"the camera drives against the odometry (speed scale {sol[0]:.3f}): this rotation points the "
                "camera's motion backwards (a rotation solver that latched onto noise, or swapped wheel signs): "
                "check the wheel order and signs, and seed with the PLS closed form (--method pls) if another was "
                "used"
            )
        return sol[1:], float(sol[0]), s_w
    A = np.vstack([np.column_stack([z, -s_w * w]), np.column_stack([s_w * w, z])])
    sol, *_ = np.linalg.lstsq(A * sq[:, None], np.r_[r[:, 0] - vx, r[:, 1] - vy] * sq, rcond=None)
    return sol, 1.0, s_w


def model_residuals(
    pairs: PairedSamples, R_base_cam: np.ndarray, t_xy: np.ndarray, speed_scale: float, turn_scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample residual norms of the calibrated model: angular (rad/s) and linear (m/s)."""
    w_b = turn_scale * pairs.omega_base
    rw = pairs.omega_cam @ R_base_cam.T - w_b
    rv = pairs.v_cam @ R_base_cam.T - (speed_scale * pairs.v_base + np.cross(w_b, np.r_[t_xy, 0.0]))
    return np.linalg.norm(rw, axis=1), np.linalg.norm(rv, axis=1)


def _robust_sigma(e: np.ndarray) -> float:
    """Scale of residual norms of 3-vectors: their median over that of a 3-D unit Gaussian's norm (1.538)."""
    return float(np.median(e) / 1.538) + 1e-12


def huber_weights(e: np.ndarray, sigma: float, k: float = HUBER_K) -> np.ndarray:
    """IRLS weights of the Huber loss for residual norms ``e`` with scale ``sigma``."""
    return np.minimum(1.0, k * sigma / np.maximum(e, 1e-15))


def planar_hand_eye_translation(
    T_world_base: np.ndarray,
    T_board_cam: np.ndarray,
    R_base_cam: np.ndarray,
    min_angle_deg: float = 2.0,
    huber_k: float = 2.0,
    huber_iterations: int = 5,
) -> tuple[np.ndarray, dict]:
    """t_xy from relative motion pairs: (R_A - I)[:2, :2] t_xy = (R t_B - t_A)[:2].

    ``T_world_base`` (m, 2, 4, 4) and ``T_board_cam`` (m, 2, 4, 4) hold the start and end pose of each pair.
    Pairs turning less than ``min_angle_deg`` carry no information and are skipped; the rest are solved by
    least squares with Huber weights (``huber_k`` robust sigmas, from the median residual). Returns t_xy and
    diagnostics (pairs used and downweighted, residual RMS, smallest singular value of the system,
    out-of-plane residual).
    """
    A = inv_T(T_world_base[:, 0]) @ T_world_base[:, 1]
    B = inv_T(T_board_cam[:, 0]) @ T_board_cam[:, 1]
    ang = np.arccos(np.clip(A[:, 0, 0], -1.0, 1.0))  # planar: the angle of R_A from its first column
    use = ang > np.radians(min_angle_deg)
    if np.count_nonzero(use) < 2:
        raise DegenerateMotionError(
            f"planar hand-eye: only {int(np.count_nonzero(use))} motion pair(s) turn by more than {min_angle_deg} "
            "deg; the camera position needs turning (curves, spins)"
        )
    A, B = A[use], B[use]
    M = (A[:, :3, :3] - np.eye(3))[:, :2, :2].reshape(-1, 2)
    rhs_full = np.einsum("ij,nj->ni", R_base_cam, B[:, :3, 3]) - A[:, :3, 3]
    rhs = rhs_full[:, :2].reshape(-1)
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    # Huber reweighting per motion pair: a pair spoiled by slip or a bad pose gets a bounded influence.
    w = np.ones(len(A))
    for _ in range(huber_iterations):
        r = np.linalg.norm((M @ sol - rhs).reshape(-1, 2), axis=1)
        sigma = 1.4826 * np.median(r) + 1e-9
        w = np.minimum(1.0, huber_k * sigma / np.maximum(r, 1e-12))
        sw = np.repeat(np.sqrt(w), 2)
        sol, *_ = np.linalg.lstsq(M * sw[:, None], rhs * sw, rcond=None)
    resid = M @ sol - rhs
    sv = np.linalg.svd(M, compute_uv=False)
    diag = {
        "pairs": int(use.sum()),
        "pairs_downweighted": int(np.count_nonzero(w < 1.0)),
        "residual_rms_m": float(np.sqrt(np.mean(resid**2))),
        "min_singular_value": float(sv[-1] / np.sqrt(use.sum())),
        # For planar motion the third row must vanish: (R t_B - t_A)_z = 0. Its size checks R and the planarity.
        "out_of_plane_rms_m": float(np.sqrt(np.mean(rhs_full[:, 2] ** 2))),
    }
    return sol, diag


def _motion_pairs(
    camera_track: CameraTrack, base: BaseTrack, t_cam: np.ndarray, td: float, interval_s: float, max_pairs: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Start/end poses (m, 2, 4, 4) of relative motions ~``interval_s`` apart; pairs across gaps are dropped."""
    t0 = t_cam[(t_cam + interval_s <= camera_track.t[-1]) & (t_cam + interval_s + td <= base.t[-1])]
    if t0.size > max_pairs:
        t0 = t0[np.unique(np.linspace(0, t0.size - 1, max_pairs).round().astype(int))]
    t1 = t0 + interval_s
    # Camera holes: both ends must lie within a normal frame spacing of a real frame.
    dt_c = float(np.median(np.diff(camera_track.t)))

    def near_frame(tq: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(camera_track.t, tq), 1, camera_track.t.size - 1)
        return np.minimum(np.abs(camera_track.t[i] - tq), np.abs(camera_track.t[i - 1] - tq)) <= dt_c

    ok = near_frame(t0) & near_frame(t1)
    # Odometry gaps or jumps anywhere inside the interval spoil the relative motion.
    mid = np.linspace(0.0, 1.0, 9)
    inside = (t0[:, None] + td) + interval_s * mid[None, :]
    ok &= ~in_gap(base, inside).any(axis=1)
    t0, t1 = t0[ok], t1[ok]
    Tb = np.stack([base.poses_at(t0 + td), base.poses_at(t1 + td)], axis=1)
    Tc = np.stack([camera_track.poses_at(t0), camera_track.poses_at(t1)], axis=1)
    return Tb, Tc, int(np.count_nonzero(~ok))


#: Odometry scale factors further than this from 1 are reported as a warning.
SCALE_WARN = 0.03


def _scale_report(s_v: float, s_w: float, info: dict) -> dict[str, float]:
    out = {"speed": float(s_v), "turn_rate": float(s_w)}
    r, b = info.get("wheel_radius"), info.get("track_width")
    if r and b:
        # v = r (w_R + w_L) / 2 scales with r; omega = r (w_R - w_L) / b with r / b.
        out["wheel_radius_m"] = float(r * s_v)
        out["track_width_m"] = float(b * s_v / s_w)
    return out


def _scale_warnings(s_v: float, s_w: float, info: dict) -> list[str]:
    if abs(s_v - 1) <= SCALE_WARN and abs(s_w - 1) <= SCALE_WARN:
        return []
    rep = _scale_report(s_v, s_w, info)
    msg = (
        f"the camera's speed is x{s_v:.3f} and its turn rate x{s_w:.3f} of what the odometry reports; "
        "the translation was computed from the corrected odometry"
    )
    if "track_width_m" in rep:
        msg += (f". The closed form's effective wheel radius {rep['wheel_radius_m']:.4f} m and track width "
                f"{rep['track_width_m']:.4f} m (the refinement estimates them again, with sigmas: the result's "
                "odometry section)")
        if s_w < 1 - SCALE_WARN:
            msg += " (skid-steer robots turn less than their geometric track width predicts)"
    if abs(s_v - 1) > SCALE_WARN:
        msg += (f". The camera's distances differ from the odometry's by {100 * (s_v - 1):+.1f} %: tyres (pressure, "
                "wear) or a wrong --wheel-radius, or a board printed at another size than its YAML says (e.g. scaled "
                "to fit the page), which looks the same and which the radius's sigma does not hold: measure the "
                "printed circle spacing once")
    return [msg]


def refine_time_offset(
    cv: CameraVelocities,
    base: BaseTrack,
    td0: float,
    R_base_cam: np.ndarray,
    t_xy: np.ndarray,
    speed_scale: float = 1.0,
    turn_scale: float = 1.0,
    half_range: float = 0.1,
    coarse_step: float = 0.005,
    step: float = 0.001,
) -> tuple[float, np.ndarray, np.ndarray]:
    """td minimising the full 3-D velocity residual of the calibrated model within ``half_range`` of ``td0``.

    Once R, t_xy and the odometry scales are known, every shift can be scored by how well the camera's angular
    and linear velocities are explained: the Huber loss of |R w_cam - s_w w_base| plus that of the linear
    velocity residual with the lever arm, each in robust sigmas of the starting shift. Unlike the correlation
    this uses all axes and the linear velocity too. The samples are the same for every shift; a coarse grid,
    then a fine one around its minimum, then a parabola. Returns td and the sorted shifts and costs.
    """
    reach = cv.info["half"] / cv.info["rate"]
    lo, hi = td0 - half_range, td0 + half_range
    sel = cv.valid & (cv.t + lo >= base.t[0] + reach) & (cv.t + hi <= base.t[-1] - reach)
    sub = CameraVelocities(cv.t[sel], cv.omega[sel], cv.v[sel], np.ones(int(sel.sum()), dtype=bool), cv.info)

    def residuals(shift: float) -> tuple[np.ndarray, np.ndarray] | None:
        try:
            return model_residuals(pair_samples(sub, base, shift), R_base_cam, t_xy, speed_scale, turn_scale)
        except PlsgraphError:
            return None

    # Huber loss with scales fixed at the starting shift, so that a few samples the model cannot explain
    # (slip bursts) do not pull the minimum.
    mid = residuals(float(td0))
    if mid is None:
        return float(td0), np.array([td0]), np.array([np.inf])
    sig = (_robust_sigma(mid[0]), _robust_sigma(mid[1]))

    def cost(shift: float) -> float:
        r = residuals(shift)
        if r is None:
            return np.inf
        total = 0.0
        for e, sigma in zip(r, sig, strict=True):
            x = e / sigma
            total += float(np.mean(np.where(x <= HUBER_K, 0.5 * x * x, HUBER_K * (x - 0.5 * HUBER_K))))
        return total

    s_coarse = td0 + np.arange(-half_range, half_range + 0.5 * coarse_step, coarse_step)
    c_coarse = np.array([cost(float(x)) for x in s_coarse])
    i0 = int(np.argmin(c_coarse))
    s_fine = s_coarse[i0] + np.arange(-coarse_step, coarse_step + 0.5 * step, step)
    c_fine = np.array([cost(float(x)) for x in s_fine])
    j = int(np.argmin(c_fine))
    td = float(s_fine[j])
    if 0 < j < s_fine.size - 1 and np.all(np.isfinite(c_fine[j - 1 : j + 2])):
        y0, y1, y2 = c_fine[j - 1 : j + 2]
        den = y0 - 2 * y1 + y2
        if den > 0:
            td += 0.5 * step * (y0 - y2) / den
    shifts = np.r_[s_coarse, s_fine]
    order = np.argsort(shifts, kind="stable")
    return td, shifts[order], np.r_[c_coarse, c_fine][order]


def _solve_rotation(
    X: np.ndarray, Y: np.ndarray, method: str, weights: np.ndarray | None = None
) -> closedform.RotationResult:
    if method == "pls_paper":
        return closedform.solve(X, Y, "pls", paper=True, weights=weights)
    return closedform.solve(X, Y, method, weights=weights)


def covariance_weights(camera_track: CameraTrack, t: np.ndarray, clip: float = 10.0) -> np.ndarray | None:
    """Per-row weights (2n,) for the stacked rows from the camera poses' covariance, or None without one.

    Angular rows get 1 / tr(rotation covariance), linear rows 1 / tr(translation covariance), interpolated to
    the paired times, each normalised to mean 1 and clipped to [1 / clip, clip] times its median so that one
    overconfident pose cannot dominate. Uniform covariances give uniform weights.
    """
    cov = camera_track.cov
    if cov is None or cov.shape != (len(camera_track), 6, 6) or not np.all(np.isfinite(cov)):
        return None
    out = []
    for block in (slice(0, 3), slice(3, 6)):
        tr = np.trace(cov[:, block, block], axis1=1, axis2=2)
        if not np.all(tr > 0):
            return None
        w = 1.0 / np.interp(t, camera_track.t, tr)
        med = np.median(w)
        w = np.clip(w, med / clip, med * clip)
        out.append(w / w.mean())
    return np.concatenate(out)


@dataclass(frozen=True)
class ClosedFormOptions:
    """Settings of :func:`calibrate_closed_form`.

    ``method`` picks the rotation solver of the headline result: "pls" (default), "pls_paper" (the paper's
    Eqs. 11-21 verbatim), "cca", "procrustes". ``td`` skips the time-offset search when the offset is known;
    otherwise it is searched in ``td_range`` with ``time_offset_method``. ``iterations`` alternations of
    rotation and lever arm; ``hand_eye_interval_s`` the span of the relative motions for the translation and
    the OpenCV hand-eye comparison. ``compare`` also runs every other solver (results in ``methods``).
    (``iterations`` is the least number of alternations: they go on until rotation and lever arm settle, at most
    MAX_ALTERNATIONS times, after each of the ``robust_iterations`` reweightings too.)
    ``use_covariance`` weights the velocity rows by the camera poses' covariance when the track has one.
    ``estimate_odometry_scale`` estimates the odometry's speed and turn-rate scale factors (wrong wheel radius,
    effective track width) along with the lever arm, reports them and corrects the odometry for the translation.
    ``refine_td`` re-estimates td (within +-100 ms of the correlation peak) from the full velocity residual once
    the rotation is known; ``time_offset`` keeps the correlation search, ``td`` is the refined value.
    ``robust_iterations`` Huber reweightings of the velocity samples the model does not explain (0 = plain
    least squares); the count of downweighted samples is in ``discarded["velocity_samples_downweighted"]``.
    """

    method: str = "pls"
    td_range: tuple[float, float] = (-0.5, 0.5)
    td: float | None = None
    time_offset_method: str = "correlation"
    window_s: float = DEFAULT_WINDOW_S
    iterations: int = 3
    hand_eye_interval_s: float = 1.0
    hand_eye_methods: tuple[str, ...] = closedform.HAND_EYE_METHODS
    compare: bool = True
    raise_on_degenerate: bool = False
    use_covariance: bool = True
    estimate_odometry_scale: bool = True
    refine_td: bool = True
    robust_iterations: int = 3

    def __post_init__(self) -> None:
        if self.method not in ROTATION_METHODS:
            raise InputError(f"unknown method {self.method!r}; use one of {', '.join(ROTATION_METHODS)}")


ROTATION_METHODS = ("pls", "pls_paper", "cca", "procrustes")
#: Rotation and lever arm are alternated until the rotation moves by less than SETTLED_RAD and the lever arm by
#: less than SETTLED_M between two alternations, at most MAX_ALTERNATIONS times per weighting.
MAX_ALTERNATIONS = 100
SETTLED_RAD = 1e-6
SETTLED_M = 1e-6


def _settled(R0: np.ndarray, R1: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> bool:
    c = np.clip((np.trace(R0.T @ R1) - 1.0) / 2.0, -1.0, 1.0)
    return bool(np.arccos(c) < SETTLED_RAD and np.linalg.norm(np.asarray(t1) - np.asarray(t0)) < SETTLED_M)


def calibrate_closed_form(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    options: ClosedFormOptions | None = None,
    **settings,
) -> ClosedFormResult:
    """Closed-form T_base_cam (rotation, floor-plane translation) and td from a camera and a base track.

    ``options`` (:class:`ClosedFormOptions`), with any of its fields overridden by keyword (``method="cca"``).
    Input problems raise (InputError, InsufficientDataError); motion that leaves something undetermined gives
    a result with ``degenerate`` set, or raises DegenerateMotionError with ``raise_on_degenerate``.
    """
    try:
        o = replace(options or ClosedFormOptions(), **settings)
    except TypeError as exc:
        raise InputError(f"calibrate_closed_form: {exc}") from exc
    method, td_range, td, window_s = o.method, tuple(o.td_range), o.td, o.window_s
    iterations, robust_iterations, use_covariance = o.iterations, o.robust_iterations, o.use_covariance
    estimate_odometry_scale, compare = o.estimate_odometry_scale, o.compare
    if not isinstance(camera_track, CameraTrack) or not isinstance(base_track, BaseTrack):
        raise InputError("calibrate_closed_form needs a CameraTrack and a BaseTrack")
    warnings: list[str] = list(base_track.info.get("warnings", []))
    reasons: list[str] = []
    cv: CameraVelocities = camera_velocities_on_grid(camera_track, window_s=window_s)
    if cv.info.get("outliers"):
        # The relative motions for the translation must not use the poses the differentiation rejected.
        keep = ~cv.info["outlier_mask"]
        cov = None if camera_track.cov is None else camera_track.cov[keep]
        camera_track = CameraTrack(camera_track.t[keep], camera_track.T_board_cam[keep], cov=cov)

    # 1. Time offset.
    to_res: TimeOffsetResult | None = None
    if td is None:
        to_res = estimate_time_offset(cv, base_track, td_range=td_range, method=o.time_offset_method)
        td_est = to_res.td
        warnings += to_res.warnings
        if to_res.at_range_edge:
            lo, hi = td_range
            reasons.append(f"time offset at the border of the search range [{lo:g}, {hi:g}] s: the offset may lie "
                           "outside it, and the search could not confirm its peak (a refinement may move past the "
                           "border); widen --td-range (td_range; at most 10 s; clocks further apart: --clock-align "
                           "always or --clock-offset)")
        elif not to_res.ok:
            reasons.append("time offset poorly determined (weak or ambiguous correlation peak)")
    else:
        td_est = float(td)

    # 2. Pairing and excitation.
    pairs = pair_samples(cv, base_track, td_est)
    discarded = dict(pairs.discarded, camera_outlier_frames=int(cv.info.get("outliers", 0)))
    n = pairs.t.size
    w = pairs.omega_base[:, 2]
    v = pairs.v_base[:, 0]
    turn_rms = float(np.sqrt(np.mean(w**2)))
    speed_rms = float(np.sqrt(np.mean(v**2)))
    speed_p90 = float(np.percentile(np.abs(v), 90)) if v.size else 0.0
    cos_vw = float(abs(v @ w) / np.sqrt((v @ v) * (w @ w))) if turn_rms > 0 and speed_rms > 0 else 0.0
    turning = turn_rms >= MIN_TURN_RATE
    driving = speed_rms >= MIN_DRIVING_SPEED or speed_p90 >= MIN_DRIVING_SPEED
    excitation = {"turn_rate_rms": turn_rms, "speed_rms": speed_rms, "speed_p90": speed_p90,
                  "speed_turn_cosine": cos_vw}
    if not turning and not driving:
        reasons.append(
            f"the robot neither turns (RMS {turn_rms:.3f} rad/s) nor drives (RMS {speed_rms:.3f} m/s): nothing is "
            "observable"
        )
    elif not turning:
        reasons.append(
            f"no turning (RMS turn rate {turn_rms:.3f} rad/s < {MIN_TURN_RATE}): the roll about the driving "
            "direction and the camera position are unobservable; drive curves"
        )
    elif not driving:
        reasons.append(
            f"no driving (RMS speed {speed_rms:.3f} m/s, 90th percentile {speed_p90:.3f} m/s, both < "
            f"{MIN_DRIVING_SPEED}): the yaw is unobservable (spinning in "
            "place fixes only the camera's tilt); drive forwards/backwards while turning"
        )
    elif cos_vw > MAX_SPEED_TURN_COSINE:
        warnings.append(
            f"speed and turn rate are nearly proportional (|cos| = {cos_vw:.3f}, constant-curvature driving): yaw "
            "and sideways position are weakly separated; vary the curvature"
        )
    full_rotation = turning and driving
    observable = {
        # Turning fixes the base's up axis in the camera frame (roll, pitch); driving its forward axis (yaw, pitch).
        "roll": turning,
        "pitch": turning or driving,
        "yaw": driving,
        "x": full_rotation,
        "y": full_rotation,
        "z": False,
        "td": bool(td is not None or (to_res is not None and to_res.ok)),
    }

    # Tilt from turning alone: the base's up axis in the camera frame is the direction of omega_cam.
    vertical = None
    if turning:
        vertical = pairs.omega_cam.T @ w
        vertical = vertical / np.linalg.norm(vertical)
    # Likewise the forward axis from driving alone (exact without turning; the lever-arm term averages out
    # unless speed and turn rate are correlated).
    forward = None
    if driving:
        forward = pairs.v_cam.T @ v
        forward = forward / np.linalg.norm(forward)

    # 3. Rotation and lever arm, alternating.
    methods: dict[str, MethodResult] = {}
    R = None
    t_xy = np.zeros(2)
    s_v = s_w = 1.0
    t_xy_vel = None
    td_at_border = False
    he_diag: dict = {}
    if full_rotation:
        try:
            speed_ok = cos_vw <= MAX_SPEED_TURN_COSINE

            def solve_model(pairs: PairedSamples, n_iter: int, t_xy, s_v, s_w):
                """Alternate rotation and lever arm / scales until both settle (at least ``n_iter`` times, at most
                MAX_ALTERNATIONS), then reweight the velocity samples (Huber) and settle again, ``robust_iterations``
                times. Settling matters when the robot mostly turns: the lever arm's share of the camera's velocity
                is then large against the driving's, and each alternation gains little (three left the yaw 10 deg
                off on exact data)."""
                weights = covariance_weights(camera_track, pairs.t) if use_covariance else None
                rob = (np.ones(pairs.t.size), np.ones(pairs.t.size))
                R = None
                settled = False
                for k in range(robust_iterations + 1):
                    for i in range(max(MAX_ALTERNATIONS, n_iter)):
                        X, Y, _k = _stack_rows(pairs, t_xy, s_v, s_w)
                        W = np.r_[rob[0], rob[1]] if weights is None else weights * np.r_[rob[0], rob[1]]
                        R_new = _solve_rotation(X, Y, method, W).R_base_cam
                        t_new, s_v, s_w = lever_arm_and_odometry_scales(pairs, R_new, estimate_odometry_scale, speed_ok,
                                                                        rob)
                        settled = R is not None and _settled(R, R_new, t_xy, t_new)
                        R, t_xy = R_new, t_new
                        if settled and i + 1 >= n_iter:
                            break
                    if k < robust_iterations:
                        e_w, e_v = model_residuals(pairs, R, t_xy, s_v, s_w)
                        rob = (huber_weights(e_w, _robust_sigma(e_w)), huber_weights(e_v, _robust_sigma(e_v)))
                unsettled.append(not settled)  # the last weighting's alternations reached their cap
                return R, t_xy, s_v, s_w, int(np.count_nonzero((rob[0] < 1) | (rob[1] < 1)))

            unsettled: list[bool] = []

            R, t_xy, s_v, s_w, downweighted = solve_model(pairs, max(1, iterations), t_xy, s_v, s_w)
            if o.refine_td and td is None:
                # Two rounds: the first may move td far enough that the model is worth re-solving before the second.
                for first, half_range in ((True, 0.1), (False, 0.02)):
                    td_ref, _, costs = refine_time_offset(
                        cv, base_track, td_est, R, t_xy, s_v, s_w, half_range=half_range
                    )
                    if not (np.isfinite(costs).sum() >= 3 and abs(td_ref - td_est) < 0.95 * half_range):
                        warnings.append(
                            f"the model-based time-offset refinement found its minimum at the border of "
                            f"+-{1e3 * half_range:.0f} ms around {td_est:+.4f} s; kept that estimate"
                        )
                        td_at_border = td_at_border or first
                        break
                    td_est = td_ref
                    pairs = pair_samples(cv, base_track, td_est)
                    R, t_xy, s_v, s_w, downweighted = solve_model(pairs, 1, t_xy, s_v, s_w)
            t_xy_vel = t_xy.copy()
            discarded["velocity_samples_downweighted"] = downweighted
            if unsettled[-1]:
                warnings.append(
                    f"the rotation and the lever arm had not settled after {MAX_ALTERNATIONS} alternations (the robot "
                    "mostly turns in place?); the closed form may be off, drive more"
                )
        except PlsgraphError as exc:
            reasons.append(f"{method}: {exc}")
            R = None
    t_final = None
    Tb = Tc = None
    if R is not None:
        scale_warn = _scale_warnings(s_v, s_w, base_track.info)
        warnings += scale_warn
        he_base = base_track
        if estimate_odometry_scale and (abs(s_v - 1) > 1e-3 or abs(s_w - 1) > 1e-3):
            # The relative base motions for the hand-eye come from the odometry corrected by the scales.
            he_base = rescale_planar_track(base_track, s_v, s_w)
        Tb, Tc, n_cross = _motion_pairs(camera_track, he_base, pairs.t, td_est, o.hand_eye_interval_s, 400)
        discarded["motion_pairs_across_gaps"] = n_cross
        try:
            t_final, he_diag = planar_hand_eye_translation(Tb, Tc, R)
        except DegenerateMotionError as exc:
            reasons.append(str(exc))
        if t_final is not None and t_xy_vel is not None and np.linalg.norm(t_final - t_xy_vel) > 0.05:
            warnings.append(
                f"the planar hand-eye position {np.round(t_final, 3)} m and the velocity lever arm "
                f"{np.round(t_xy_vel, 3)} m disagree by more than 5 cm; check the time offset and the odometry scale"
            )

    # 4. Every solver for comparison, on the same rows (the headline method's entry carries its translation).
    X, Y, _k = _stack_rows(pairs, t_xy, s_v, s_w) if R is not None else _stack_rows(pairs, np.zeros(2))
    caveat = [] if full_rotation else ["the motion does not determine the full rotation: this answer is arbitrary"]
    row_weights = covariance_weights(camera_track, pairs.t) if use_covariance else None
    for name in ROTATION_METHODS if compare else (method,):
        try:
            rr = _solve_rotation(X, Y, name, row_weights)
            methods[name] = MethodResult(rr.R_base_cam, None, None, list(rr.warnings) + caveat, dict(rr.diagnostics))
        except PlsgraphError as exc:
            methods[name] = MethodResult(None, error=str(exc))
    if compare:
        if Tb is None:
            Tb, Tc, _ = _motion_pairs(camera_track, base_track, pairs.t, td_est, o.hand_eye_interval_s, 400)
        # A pose sequence along the track; OpenCV forms the relative motions itself.
        seq_b = np.concatenate([Tb[:1, 0], Tb[:, 1]])
        seq_c = np.concatenate([Tc[:1, 0], Tc[:, 1]])
        for he in o.hand_eye_methods:
            try:
                rr = closedform.hand_eye(seq_b, seq_c, he)
                methods[f"hand_eye_{he}"] = MethodResult(rr.R_base_cam, rr.t_base_cam, None, list(rr.warnings) + caveat)
            except PlsgraphError as exc:
                methods[f"hand_eye_{he}"] = MethodResult(None, error=str(exc))
    if R is not None:
        methods[method] = MethodResult(
            R,
            None if t_final is None else np.r_[t_final, np.nan],
            None,
            methods[method].warnings,
            dict(methods[method].diagnostics, translation=he_diag),
        )
    if R is None:
        reasons.append("the rotation could not be determined from this motion")

    degenerate = bool(reasons)
    if degenerate:
        msg = "; ".join(reasons)
        log.warning("closed-form calibration degenerate: %s", msg)
        if o.raise_on_degenerate:
            raise DegenerateMotionError(msg)
    n = pairs.t.size  # the refinement may have re-paired at another td
    discarded.update(pairs.discarded)
    if n < 50:
        warnings.append(f"only {n} paired samples; record longer for a stable estimate")
    return ClosedFormResult(
        R_base_cam=R,
        t_xy=t_final,
        t_base_cam=None if t_final is None else np.r_[t_final, np.nan],
        td=float(td_est),
        method=method,
        time_offset=to_res,
        methods=methods,
        vertical_axis_cam=vertical,
        forward_axis_cam=forward,
        observable=observable,
        excitation=excitation,
        n_pairs=int(n),
        discarded=discarded,
        degenerate=degenerate,
        degenerate_reasons=reasons,
        warnings=warnings,
        t_xy_velocity=t_xy_vel,
        odometry_scale=_scale_report(s_v, s_w, base_track.info) if R is not None else {},
        td_at_border=bool(td_at_border),
    )
