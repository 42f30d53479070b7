"""Wheel joint states as drivers publish them -> a base track: the cleaning between the message and the
differential-drive model (which joints are the wheels, unwrapping, one joint per message, repeated stamps,
rate-only drivers)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.tracks import BaseTrack
from ..errors import InputError
from .wheels import base_track_from_wheels


@dataclass(frozen=True)
class JointCleaning:
    """What :func:`wheel_track_from_joints` found and set aside."""

    wheel_joints: dict[str, list[str]]
    kind: str  # "position" or "velocity"
    discarded: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    #: The cleaned wheel values the track was integrated from (for re-integration under another wheel order).
    signals: Any = None


#: Joint states stamped closer than this (s, median) come at a rate (10 kHz) no wheel driver publishes at.
MIN_JOINT_INTERVAL_S = 1e-4


def fill_unwrapped(t: np.ndarray, x: np.ndarray, unwrap: bool) -> np.ndarray:
    """One joint's values on every stamp: its finite samples (unwrapped if asked), linearly interpolated in
    between; NaN outside its own first and last sample."""
    m = np.isfinite(x)
    out = np.full(t.size, np.nan)
    if np.count_nonzero(m) < 2:
        out[m] = x[m]
        return out
    xs = np.unwrap(x[m]) if unwrap else x[m]
    inside = (t >= t[m][0]) & (t <= t[m][-1])
    out[inside] = np.interp(t[inside], t[m], xs)
    return out


def looks_wrapped(x: np.ndarray) -> bool:
    """Whether a joint's angles may be wrapped into one turn (every finite value within [-pi, pi], or [0, 2 pi]):
    only then are they unwrapped. A cumulative encoder beyond that range is left as it is, so that a step longer
    than half a turn (a gap in the messages while the wheel turned) keeps its size."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return False
    eps = 1e-6
    lo, hi = float(v.min()), float(v.max())
    return (lo >= -np.pi - eps and hi <= np.pi + eps) or (lo >= -eps and hi <= 2 * np.pi + eps)


def wheel_track_from_joints(
    joints: Any,
    wheel_radius: float,
    track_width: float,
    left_joint: str | None = None,
    right_joint: str | None = None,
    quiet: bool = False,
) -> tuple[BaseTrack, JointCleaning]:
    """BaseTrack from a ``JointStates`` container: the wheel joints picked by name (or given), angles unwrapped
    per joint, each joint filled onto every stamp, repeated stamps dropped, wheel rates integrated when the
    driver publishes no angles. ``quiet``: the track's warnings (gaps, jumps) are not logged, only returned in its
    ``info["warnings"]`` (the pipeline logs them once it knows the wheel order is right)."""
    try:
        lc, rc = joints.wheel_columns(left_joint, right_joint)
    except InputError as exc:
        raise InputError(f"{exc}; name them with --left-joint/--right-joint") from exc
    names = {"left": [joints.names[i] for i in lc], "right": [joints.names[i] for i in rc]}
    discarded: dict[str, int] = {}
    warnings: list[str] = []
    stray = sorted(joints.stray_columns())
    if stray and left_joint is None and right_joint is None:
        warnings.append("joints named in only a few messages were not taken for wheels: "
                        + ", ".join(repr(joints.names[i]) for i in stray[:6]))
    t = joints.t.astype(np.float64) * 1e-9
    # Per joint, before the sides are averaged: unwrap angles that a driver reports in [-pi, pi) (a wrap of one
    # wheel of a pair would move the average by only ~pi, below what unwrapping catches), and fill each joint
    # onto every stamp, as drivers that publish each wheel in its own message leave the others NaN.
    wrapped = [looks_wrapped(joints.position[:, c]) for c in lc + rc]
    pos = np.column_stack([fill_unwrapped(t, joints.position[:, c], unwrap=w) for c, w in zip(lc + rc, wrapped,
                                                                                                strict=True)])
    vel = np.column_stack([fill_unwrapped(t, joints.velocity[:, c], unwrap=False) for c in lc + rc])
    nl = len(lc)
    left, right = pos[:, :nl].mean(axis=1), pos[:, nl:].mean(axis=1)
    left_rate, right_rate = vel[:, :nl].mean(axis=1), vel[:, nl:].mean(axis=1)
    keep = np.r_[True, np.diff(joints.t) > 0]  # a driver that republishes a state repeats its stamp
    if not np.all(keep):
        discarded["joint_states_repeated_stamp"] = int(np.count_nonzero(~keep))
        if np.count_nonzero(keep) < 2 <= keep.size:
            raise InputError(f"all {keep.size} joint state messages carry the same header stamp "
                             f"({int(joints.t[0])} ns): the driver does not stamp them, so the wheel motion has no "
                             "time; fix the driver's stamps (or record nav_msgs/Odometry)")
    kind = "position"
    a, b = left, right
    if np.count_nonzero(np.isfinite(left) & np.isfinite(right)) < 2 and np.any(np.isfinite(left_rate)):
        kind, a, b = "velocity", left_rate, right_rate  # some drivers publish only wheel rates
        warnings.append("the joint states carry no wheel angles; integrated the wheel rates instead")
    # A message in which no wheel joint has a value is not a sample (each joint's filling above is for drivers that
    # publish the wheels in messages of their own): dropped, a run of them is a gap like missing messages, not a
    # straight line drawn across it.
    raw = (joints.position if kind == "position" else joints.velocity)[:, lc + rc]
    ok = keep & np.isfinite(a) & np.isfinite(b) & np.any(np.isfinite(raw), axis=1)
    if np.count_nonzero(keep & ~ok):
        discarded["joint_states_without_wheel_values"] = int(np.count_nonzero(keep & ~ok))
    any_wrapped = kind == "position" and any(wrapped)
    track = base_track_from_wheels(t[ok], a[ok], b[ok], wheel_radius=wheel_radius, track_width=track_width,
                                   kind=kind, quiet=quiet, wrapped=any_wrapped)
    n_jumps = len(track.info.get("jumps", []))
    if kind == "position" and n_jumps > 0.5 * max(1, ok.sum() - 1):
        dt = float(np.median(np.diff(t[ok]))) if ok.sum() > 1 else 0.0
        if 0.0 < dt < MIN_JOINT_INTERVAL_S:
            # The angles may be fine: steps that are ordinary per message look fast when the messages are stamped
            # microseconds apart, the stamps in another unit than the nanoseconds they are read as.
            raise InputError(
                f"the joint states are stamped {1e6 * dt:.3g} us apart (median), {1.0 / dt:,.0f} messages per second, "
                f"which no wheel driver publishes, and {n_jumps} of {ok.sum() - 1} wheel steps are implausibly fast "
                "at that rate: the header stamps are likely in another unit than nanoseconds (milliseconds or "
                "microseconds), or scaled; fix the stamps"
            )
        raise InputError(
            f"{n_jumps} of {ok.sum() - 1} wheel steps are implausibly large: the joint positions do not look like "
            "wheel angles in radians (encoder ticks?); convert them or check --wheel-radius. If a warning says the "
            "joint states' stamps go backwards, the stamps are wrong instead (messages sorted by a scrambled stamp)"
        )
    from .wheel_order import WheelSignals

    signals = WheelSignals(t[ok], a[ok], b[ok], kind, wheel_radius, track_width, wrapped=any_wrapped)
    return track, JointCleaning(names, kind, discarded, warnings, signals)
