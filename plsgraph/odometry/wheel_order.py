"""Are the wheels what the joint names say? Swapped or reversed wheels, checked against what the camera sees.

A differential drive gives v = r (w_R + w_L) / 2 and omega = r (w_R - w_L) / b. Two wiring mistakes are common:

* **swapped** (``--left-joint`` names the right wheel, or a driver lists them the other way round): v is right,
  omega has the wrong sign. The closed form then finds the rotation that maps the camera's turns onto turns the
  other way: the camera comes out upside down (rolled 180 deg), a mirrored solution that fits the rotations
  perfectly. Magnitudes (|omega|, speed) cannot tell it; only the sign can.
* **one wheel reversed** (its joint axis points the other way, as on many robots' left wheel): v and omega swap
  roles, v' = omega b / 2, omega' = 2 v / b (up to sign). The magnitudes then no longer match the camera's.

:func:`check_wheel_order` re-integrates the base track under four hypotheses (as given, swapped, left reversed,
right reversed) and scores each by the correlation of its |omega_z| and speed with the camera's |omega| and speed
(:mod:`plsgraph.calib.clock`, over the allowed clock offsets). "As given" and "swapped" have the same magnitudes,
as do the two "reversed" ones: the magnitudes choose the pair, which needs a clear margin (``MIN_MARGIN``).
Within the pair the sign decides: under planar motion the camera's angular velocity lies along one axis, the
base's vertical seen from the camera, and its component along that axis must equal the base yaw rate with a
positive sign and a scale near 1. Which way that axis points is fixed by one assumption: the camera is mounted
upright (its image "down" axis has a downward component in the base frame), unless the user says it is upside
down. A camera rolled by about 90 deg (portrait) leaves the sign undecided, and so does motion without turns.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calib.clock import DEFAULT_RATE_HZ, ClockAlignment, RateSignals, align_signals, base_rate_signals
from ..calib.time_offset import _principal_axis, base_velocities_on_grid, camera_velocities_on_grid
from ..core.tracks import BaseTrack, CameraTrack
from ..errors import PlsgraphError
from .wheels import base_track_from_wheels

log = logging.getLogger(__name__)

HYPOTHESES = ("as_given", "swapped", "left_reversed", "right_reversed")
DESCRIPTION = {
    "as_given": "the wheel joints as named",
    "swapped": "left and right wheel joints swapped",
    "left_reversed": "the left wheel's joint counts backwards",
    "right_reversed": "the right wheel's joint counts backwards",
}
#: The magnitude pairs: members of a pair have identical |omega| and speed.
PAIRS = (("as_given", "swapped"), ("left_reversed", "right_reversed"))
#: Correlation margin by which the winning pair must beat the other.
MIN_MARGIN = 0.1
#: |component of the camera's image-down axis along the base's vertical| needed to tell upright from upside down.
MIN_UP_COMPONENT = 0.25
#: A swapped or reversed hypothesis must also fit: its magnitude correlation at least this.
MIN_SCORE = 0.5
#: The sign is read from the camera's turn rate against the base's yaw rate: their correlation must reach this (0.97-1.0
#: on recordings that turn; about 0.2 on a straight drive, whose turns are noise and whose sign means nothing).
MIN_TURN_CORRELATION = 0.5


@dataclass(frozen=True)
class WheelSignals:
    """The cleaned wheel values a base track is integrated from: ``left``/``right`` angles (rad) or rates (rad/s)
    at odometry times ``t`` (s), with the nominal geometry."""

    t: np.ndarray
    left: np.ndarray
    right: np.ndarray
    kind: str
    wheel_radius: float
    track_width: float
    wrapped: bool = True  # the angles may have been unwrapped from one turn (see base_track_from_wheels)

    def under(self, hypothesis: str) -> tuple[np.ndarray, np.ndarray]:
        """(left, right) as they would be under ``hypothesis``."""
        lft, rgt = self.left, self.right
        return {
            "as_given": (lft, rgt),
            "swapped": (rgt, lft),
            "left_reversed": (-lft, rgt),
            "right_reversed": (lft, -rgt),
        }[hypothesis]

    def base_track(self, hypothesis: str = "as_given") -> BaseTrack:
        lft, rgt = self.under(hypothesis)
        # Quiet: a hypothesis's gaps and jumps are not the recording's (a reversed wheel turns driving into
        # turning, which can pass for a jump); the chosen track's warnings are told by whoever uses it.
        return base_track_from_wheels(self.t, lft, rgt, self.wheel_radius, self.track_width, kind=self.kind,
                                      quiet=True, wrapped=self.wrapped)


@dataclass(frozen=True)
class WheelOrderCheck:
    """What the data say about the wheels.

    ``hypothesis`` is the one the data support (``as_given`` when undecided); ``decided`` whether the evidence is
    clear; ``scores`` each hypothesis's magnitude correlation; ``margin`` the winning pair's lead; ``up_component``
    the camera's image-down axis along the base vertical under the chosen hypothesis (negative: upright);
    ``turn_scale`` the camera's turn rate about that axis over the odometry's (near 1 when all is right);
    ``alignment`` the chosen hypothesis's clock alignment; ``base_track`` its re-integrated track.
    """

    hypothesis: str
    decided: bool
    scores: dict[str, float]
    margin: float
    up_component: float
    turn_scale: float
    turn_correlation: float
    message: str
    alignment: ClockAlignment | None = field(default=None, repr=False)
    base_track: BaseTrack | None = field(default=None, repr=False)

    @property
    def wrong(self) -> bool:
        """The data clearly say the wheels are not as named."""
        return self.decided and self.hypothesis != "as_given"

    def to_dict(self) -> dict[str, Any]:
        return {
            "hypothesis": self.hypothesis, "description": DESCRIPTION[self.hypothesis], "decided": self.decided,
            "scores": dict(self.scores), "margin": self.margin, "up_component": self.up_component,
            "turn_scale": self.turn_scale, "turn_correlation": self.turn_correlation, "message": self.message,
        }


def _turn_sign(cv: Any, base: BaseTrack, offset: float, rate: float) -> tuple[float, float, float, np.ndarray]:
    """(slope, correlation, up component, axis) of the camera's turn rate about its principal axis against the base
    yaw rate at t_cam + offset; the axis sign is chosen so that the slope is positive."""
    half = int(cv.info["half"])
    tq = cv.t + offset
    inside = cv.valid & (tq >= base.t[0]) & (tq <= base.t[-1])
    if inside.sum() < 10:
        raise PlsgraphError("too few camera samples overlap the odometry")
    _, w = base_velocities_on_grid(base, np.clip(tq, base.t[0], base.t[-1]), rate, half)
    wz = w[inside, 2]
    om = cv.omega[inside]
    axis, _ = _principal_axis(om)
    s = om @ axis
    den = float(np.sum(wz * wz))
    if den <= 0:
        raise PlsgraphError("the odometry does not turn")
    k = float(np.sum(s * wz) / den)
    corr = float(np.corrcoef(s, wz)[0, 1]) if np.std(s) > 0 and np.std(wz) > 0 else 0.0
    sign = 1.0 if k >= 0 else -1.0
    up = sign * axis  # the base's vertical, seen from the camera
    return abs(k), abs(corr), float(up[1]), up


def check_wheel_order(
    camera_track: CameraTrack,
    wheels: WheelSignals,
    window_s: tuple[float, float] | None = None,
    upside_down_camera: bool = False,
    rate_hz: float = DEFAULT_RATE_HZ,
) -> WheelOrderCheck:
    """Which of the four wheel hypotheses the camera's motion supports (see the module notes).

    ``window_s`` limits the clock offsets c (t_odom = t_cam + c) considered; None allows any overlap (two clocks).
    """
    cv = camera_velocities_on_grid(camera_track, rate=rate_hz)
    cam = RateSignals(float(cv.t[0]), float(rate_hz), np.linalg.norm(cv.omega, axis=1), np.linalg.norm(cv.v, axis=1),
                      cv.valid.copy())
    tracks: dict[str, BaseTrack] = {}
    aligns: dict[str, ClockAlignment] = {}
    scores: dict[str, float] = {}
    why = ""
    for pair in PAIRS:  # both members of a pair have the same magnitudes: score the first, reuse for the second
        first = pair[0]
        tracks[first] = wheels.base_track(first)
        try:
            aligns[first] = align_signals(cam, base_rate_signals(tracks[first], rate_hz), window_s, strict=False)
            scores[first] = scores[pair[1]] = float(aligns[first].score)
        except PlsgraphError as exc:
            log.info("wheel hypothesis %s: %s", first, exc)
            scores[first] = scores[pair[1]] = float("nan")
            why = str(exc)
    a, b = scores["as_given"], scores["left_reversed"]
    if not np.isfinite(a) and not np.isfinite(b):
        return WheelOrderCheck("as_given", False, scores, float("nan"), float("nan"), float("nan"), float("nan"),
                               "the wheel order could not be checked: the camera's and the odometry's motions could "
                               f"not be aligned ({why})", None, tracks.get("as_given"))
    best_pair = PAIRS[0] if (np.nan_to_num(a, nan=-1.0) >= np.nan_to_num(b, nan=-1.0)) else PAIRS[1]
    margin = float(abs(np.nan_to_num(a, nan=-1.0) - np.nan_to_num(b, nan=-1.0)))
    lead = best_pair[0]
    align = aligns[lead]
    try:
        k, corr, up_y, _ = _turn_sign(cv, tracks[lead], align.offset_s, rate_hz)
    except PlsgraphError as exc:
        return WheelOrderCheck("as_given", False, scores, margin, float("nan"), float("nan"), float("nan"),
                               f"the wheel order could not be checked: {exc}", align, tracks["as_given"])
    want = 1.0 if upside_down_camera else -1.0  # sign of the image-down axis's component along the base vertical
    mount = "upside down" if upside_down_camera else "upright"
    if margin < MIN_MARGIN or scores[lead] < MIN_SCORE:
        msg = (f"the wheel order could not be checked: the wheels as named correlate {a:.2f} with the camera's motion, "
               f"with one wheel reversed {b:.2f} (need a margin of {MIN_MARGIN} and {MIN_SCORE})")
        return WheelOrderCheck("as_given", False, scores, margin, up_y, k, corr, msg, aligns.get("as_given"),
                               tracks["as_given"])
    if corr < MIN_TURN_CORRELATION:
        msg = (f"the wheel order's sign could not be checked: the camera's turns and the odometry's correlate only "
               f"{corr:.2f} (need {MIN_TURN_CORRELATION}): the robot hardly turns, so a swapped pair of wheels would "
               "go unseen")
        if lead != "as_given":
            msg += f"; and one wheel looks reversed ({b:.2f} against {a:.2f} as named), which one is unclear"
        return WheelOrderCheck("as_given", False, scores, margin, up_y, k, corr, msg, aligns["as_given"],
                               tracks["as_given"])
    if abs(up_y) < MIN_UP_COMPONENT:
        msg = (f"the wheel order's sign could not be checked: the camera's image-down axis is nearly level "
               f"(component along the base vertical {up_y:+.2f}), so a swapped pair of wheels would go unseen")
        if lead != "as_given":
            msg += f"; and one wheel looks reversed ({b:.2f} against {a:.2f} as named), which one is unclear"
        return WheelOrderCheck("as_given", False, scores, margin, up_y, k, corr, msg, aligns["as_given"],
                               tracks["as_given"])
    chosen = lead if np.sign(up_y) == want else best_pair[1]
    if chosen != lead:
        up_y = -up_y
        tracks[chosen] = wheels.base_track(chosen)
    if chosen == "as_given":
        msg = (f"wheel order checked: the wheels as named fit the camera's motion (correlation {scores[chosen]:.2f}, "
               f"turn-rate scale {k:.2f}, camera {mount})")
    else:
        msg = (f"the wheel joints do not match the camera's motion as named: {DESCRIPTION[chosen]} fits it "
               f"(turn-rate/speed correlation {scores[chosen]:.2f}, as named {scores['as_given']:.2f}")
        if chosen == "swapped":
            other = "upright" if upside_down_camera else "upside down (--upside-down-camera)"
            msg += (f"; as named, the robot turns the other way than an {mount} camera sees it turn. If the camera "
                    f"is in fact mounted {other}, the wheels as named are right: calibrate again with that")
        msg += ")"
    return WheelOrderCheck(chosen, True, scores, margin, up_y, k, corr, msg, align, tracks[chosen])


def orientation_problem(R_base_cam: np.ndarray, upside_down_camera: bool = False) -> str | None:
    """A problem when the camera comes out mounted the other way up than the user said (a mirrored solution)."""
    down_z = float(np.asarray(R_base_cam)[2, 1])  # the camera's image-down axis, vertical component in the base
    if not upside_down_camera and down_z > 0.5:
        return ("the camera comes out upside down (its image 'down' axis points up in the base frame): the wheels are "
                "probably swapped or reversed (check --left-joint/--right-joint), which mirrors the whole solution; "
                "if the camera really is mounted upside down, pass --upside-down-camera")
    if upside_down_camera and down_z < -0.5:
        return ("--upside-down-camera was given but the camera comes out upright: the wheels are probably swapped or "
                "reversed, or the flag is wrong")
    return None
