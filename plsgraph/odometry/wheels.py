"""Wheel odometry of a differential-drive robot, and the helpers that turn it into a BaseTrack.

Differential drive (PLS-Calib Eqs. 3-4): each wheel's ground speed is r times its joint rate,
v = (v_R + v_L) / 2 and omega = (v_R - v_L) / b with wheel radius r and track width b (distance
between the wheels). The planar pose is integrated exactly under the usual assumption that speed and
turn rate are constant over one sample step, so each step is a circular arc.

Data problems are reported, not hidden: steps much longer than the typical one (gaps) and steps
implying an impossible speed (jumps, e.g. an encoder reset) are listed in ``BaseTrack.info`` with a
warning. A jump step contributes no motion to the integration (the true motion over it is unknown).
Unsorted or duplicated stamps are rejected.
"""

from __future__ import annotations

import logging

import numpy as np

from ..core.geometry import interpolate_poses, make_T, rot_z
from ..core.tracks import BaseTrack, gap_indices
from ..errors import InputError, InsufficientDataError

log = logging.getLogger(__name__)

# Jackal defaults (Clearpath Jackal: 0.098 m wheel radius, 0.37 m between the wheel centres).
JACKAL_WHEEL_RADIUS = 0.098
JACKAL_TRACK_WIDTH = 0.37


def _check_stream(name: str, t: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InsufficientDataError(f"{name}: need at least 2 samples, got {t.size}")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{name}: timestamps contain NaN or inf")
    d = np.diff(t)
    if np.any(d < 0):
        first = int(np.argmax(d < 0)) + 1
        raise InputError(f"{name}: timestamps are not sorted (first at index {first}); sort by stamp")
    if np.any(d == 0):
        first = int(np.argmax(d == 0)) + 1
        raise InputError(f"{name}: duplicated timestamps (first at index {first}); drop duplicates")
    out = [t]
    for a in arrays:
        a = np.asarray(a, dtype=float)
        if a.shape[0] != t.size:
            raise InputError(f"{name}: {a.shape[0]} values for {t.size} timestamps")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name}: values contain NaN or inf; drop or repair those messages")
        out.append(a)
    return tuple(out)


def find_gaps(t: np.ndarray, gap_factor: float = 5.0) -> np.ndarray:
    """Steps longer than ``gap_factor`` times the median step, as (k, 2) [t_start, t_end] rows."""
    big = gap_indices(t, gap_factor)
    return np.stack([t[big], t[big + 1]], axis=1) if big.size else np.zeros((0, 2))


def arc_increments(ds: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """Body-frame displacement (n, 2) of a step along a circular arc of length ds turning by dtheta."""
    small = np.abs(dtheta) < 1e-9
    th = np.where(small, 1.0, dtheta)
    # sin(x)/x and (1 - cos x)/x with their Taylor limits near zero.
    a = np.where(small, 1.0 - dtheta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, dtheta / 2.0, (1.0 - np.cos(th)) / th)
    return np.stack([ds * a, ds * b], axis=1)


def integrate_planar(
    ds: np.ndarray, dtheta: np.ndarray, x0: float = 0.0, y0: float = 0.0, theta0: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integrate per-step arc lengths and heading changes exactly (one arc per step).

    Returns x, y, theta with one more sample than the increments, starting at (x0, y0, theta0).
    """
    ds = np.asarray(ds, dtype=float)
    dtheta = np.asarray(dtheta, dtype=float)
    theta = theta0 + np.r_[0.0, np.cumsum(dtheta)]
    local = arc_increments(ds, dtheta)
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    dx = c * local[:, 0] - s * local[:, 1]
    dy = s * local[:, 0] + c * local[:, 1]
    return x0 + np.r_[0.0, np.cumsum(dx)], y0 + np.r_[0.0, np.cumsum(dy)], theta


def _rates_at_samples(t: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Rates at the samples from per-step increments ``d``: the time-weighted mean of the two adjacent steps."""
    dt = np.diff(t)
    r = d / dt
    out = np.empty(t.size)
    if r.size == 1:
        return np.full(t.size, r[0])
    # Linear extrapolation of the step rates (which belong to the step midpoints) to the two end samples.
    out[0] = r[0] - (r[1] - r[0]) * dt[0] / (dt[0] + dt[1])
    out[-1] = r[-1] + (r[-1] - r[-2]) * dt[-1] / (dt[-1] + dt[-2])
    out[1:-1] = (r[:-1] * dt[1:] + r[1:] * dt[:-1]) / (dt[:-1] + dt[1:])
    return out


def diff_drive(
    left: np.ndarray,
    right: np.ndarray,
    wheel_radius: float = JACKAL_WHEEL_RADIUS,
    track_width: float = JACKAL_TRACK_WIDTH,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward speed (or arc length) and turn rate (or heading change) from wheel rates (or angles).

    Works the same on joint rates (rad/s -> m/s, rad/s) and on joint angle increments (rad -> m, rad).
    """
    if wheel_radius <= 0 or track_width <= 0:
        raise InputError(f"wheel_radius and track_width must be positive, got {wheel_radius}, {track_width}")
    vl = wheel_radius * np.asarray(left, dtype=float)
    vr = wheel_radius * np.asarray(right, dtype=float)
    return 0.5 * (vr + vl), (vr - vl) / track_width


#: Wheel messages stamped closer than this share of the median step to the next one are taken for stamps given on
#: arrival in a burst (the wheels' angles are cumulative, so merging such a message into the next loses no motion).
BUNCHED_STEP = 0.25


def _unbunched(t: np.ndarray, left: np.ndarray, right: np.ndarray, wheel_radius: float, track_width: float,
               max_speed: float, max_yaw_rate: float) -> np.ndarray:
    """Which wheel-angle samples to keep: a sample stamped within :data:`BUNCHED_STEP` of the typical step before the
    next kept one is dropped when the motion from it to the next is one a median step allows (a larger one is an
    encoder reset or a jump, left to the jump test). Receive-time stamps bunch up like that when messages arrive in
    bursts; taken as they are, a step of 1 us carrying 20 ms of driving implies an impossible speed."""
    n = t.size
    keep = np.ones(n, dtype=bool)
    if n < 3:
        return keep
    dt = np.diff(t)
    # The typical step: the median of the longer half of the steps, or the mean step if smaller. Bursts that make up
    # half the steps or more pull the plain median down to a burst's step (then nothing would be merged); the mean
    # is the messages' real interval however they bunch (a long gap raises it, the longer half's median does not).
    step = min(float(np.median(np.sort(dt)[dt.size // 2:])), float(np.mean(dt)))
    if not step > 0 or not np.any(dt < BUNCHED_STEP * step):
        return keep
    ds, dth = diff_drive(np.diff(left), np.diff(right), wheel_radius, track_width)
    plausible = (np.abs(ds) <= max_speed * step) & (np.abs(dth) <= max_yaw_rate * step)
    for i in np.flatnonzero((dt < BUNCHED_STEP * step) & plausible):
        keep[i] = False  # sample i merges into sample i + 1: the step before it now ends at i + 1
    return keep


def _gaps_under_half_turn(t: np.ndarray, left: np.ndarray, right: np.ndarray, gaps: np.ndarray) -> bool:
    """Whether no wheel can have turned half a turn in any gap (at the wheel rates beside it): joint angles are
    unwrapped per joint before they get here, which takes 2 pi off a wheel that turned more than pi in a gap."""
    rate = np.abs(np.diff(np.stack([left, right]), axis=1)) / np.diff(t)  # (2, steps)
    for a, b in np.asarray(gaps).reshape(-1, 2):
        k = int(np.searchsorted(t, a))  # the gap's step
        beside = np.r_[rate[:, max(k - 1, 0):k].ravel(), rate[:, k + 1:k + 2].ravel()]
        if not beside.size or beside.max() * (b - a) >= np.pi:
            return False
    return True


def base_track_from_wheels(
    t: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    wheel_radius: float = JACKAL_WHEEL_RADIUS,
    track_width: float = JACKAL_TRACK_WIDTH,
    kind: str = "position",
    gyro: tuple[np.ndarray, np.ndarray] | None = None,
    gap_factor: float = 5.0,
    max_speed: float = 3.0,
    max_yaw_rate: float = 6.0,
    quiet: bool = False,
    wrapped: bool = True,
) -> BaseTrack:
    """BaseTrack from left/right wheel joint angles (``kind="position"``, rad) or rates (``"velocity"``, rad/s).

    ``gyro`` = (t_gyro, omega) with omega (n,) yaw rates or (n, 3) base-frame rates in the odometry
    clock replaces the wheels as the source of heading and turn rate (wheels slip most when turning).
    Steps longer than ``gap_factor`` times the median are reported as gaps; steps faster than
    ``max_speed`` (m/s) or ``max_yaw_rate`` (rad/s) as jumps (they add no motion). Both go to
    ``info["gaps"]`` / ``info["jumps"]`` and ``info["warnings"]``, and are logged unless ``quiet``.
    ``wrapped``: the angles may have been unwrapped from one turn, so a wheel that turned half a turn or more in a gap
    lost whole turns there (the gap's net motion is then unknown, ``info["net_motion_known"]``); False for cumulative
    encoder angles.
    """
    t, left, right = _check_stream("wheel odometry", t, left, right)
    if left.ndim != 1 or right.ndim != 1:
        raise InputError("wheel odometry: left and right must be 1-D arrays of joint values")
    if kind == "position":
        ds, dth = diff_drive(np.diff(left), np.diff(right), wheel_radius, track_width)
    elif kind == "velocity":
        v, w = diff_drive(left, right, wheel_radius, track_width)
        dt = np.diff(t)
        ds, dth = 0.5 * (v[1:] + v[:-1]) * dt, 0.5 * (w[1:] + w[:-1]) * dt  # trapezoid over each step
    else:
        raise InputError(f"kind must be 'position' or 'velocity', got {kind!r}")
    warnings: list[str] = []
    if kind == "position":
        keep = _unbunched(t, left, right, wheel_radius, track_width, max_speed, max_yaw_rate)
        if not keep.all():
            n_merged = int(t.size - keep.sum())
            warnings.append(
                f"{n_merged} wheel message(s) stamped within {BUNCHED_STEP:g} of a step of the next (stamped on "
                "arrival, in bursts); each was merged into the next, whose wheel angles hold its motion"
            )
            t, left, right = t[keep], left[keep], right[keep]
            ds, dth = diff_drive(np.diff(left), np.diff(right), wheel_radius, track_width)
    dt = np.diff(t)
    jump = (np.abs(ds) / dt > max_speed) | (np.abs(dth) / dt > max_yaw_rate)
    jumps = t[1:][jump]
    if jump.any():
        warnings.append(
            f"{int(jump.sum())} odometry step(s) imply more than {max_speed} m/s or {max_yaw_rate} rad/s "
            f"(first at t={jumps[0]:.3f} s); treated as resets that add no motion"
        )
        ds = np.where(jump, 0.0, ds)
        dth = np.where(jump, 0.0, dth)
    gaps = find_gaps(t, gap_factor)
    if gaps.size:
        longest = int(np.argmax(gaps[:, 1] - gaps[:, 0]))
        warnings.append(
            f"{len(gaps)} gap(s) in odometry longer than {gap_factor}x the median step "
            f"(longest {gaps[longest, 1] - gaps[longest, 0]:.3f} s at t={gaps[longest, 0]:.3f} s)"
        )
    w_src = "wheels"
    if gyro is not None:
        tg, wg = _check_stream("gyro", gyro[0], gyro[1])
        wz = wg[:, 2] if wg.ndim == 2 else wg
        if tg[0] > t[0] or tg[-1] < t[-1]:
            warnings.append("gyro does not cover the whole odometry span; its end values are held outside it")
        # Heading from the trapezoidal integral of the gyro, sampled at the odometry stamps.
        cum = np.r_[0.0, np.cumsum(0.5 * (wz[1:] + wz[:-1]) * np.diff(tg))]
        lo, hi = cum[0] + wz[0] * (t[0] - tg[0]), cum[-1] + wz[-1] * (t[-1] - tg[-1])
        dth = np.diff(np.interp(t, tg, cum, left=lo, right=hi))
        w_src = "gyro"
    x, y, theta = integrate_planar(ds, dth)
    n = t.size
    v = np.zeros((n, 3))
    omega = np.zeros((n, 3))
    v[:, 0] = _rates_at_samples(t, ds)
    omega[:, 2] = _rates_at_samples(t, dth) if gyro is None else np.interp(t, tg, wz)
    for msg in [] if quiet else warnings:
        log.warning(msg)
    info = {
        "source": f"wheels ({kind}), heading from {w_src}",
        "wheel_radius": wheel_radius,
        "track_width": track_width,
        "gaps": gaps,
        "jumps": jumps,
        "warnings": warnings,
        # Wheel angles are cumulative: the motion across a gap in the messages is known as a whole (its path is
        # not). Integrated wheel rates say nothing about a gap.
        "net_motion_known": kind == "position" and (not wrapped or _gaps_under_half_turn(t, left, right, gaps)),
    }
    return BaseTrack(t, make_T(rot_z(theta), np.stack([x, y, np.zeros(n)], axis=1)), v, omega, info=info)


def base_track_from_odometry(
    t: np.ndarray,
    position: np.ndarray,
    quat_xyzw: np.ndarray,
    linear: np.ndarray | None = None,
    angular: np.ndarray | None = None,
    gap_factor: float = 5.0,
    max_speed: float = 3.0,
    jump_tol: float = 0.05,
) -> BaseTrack:
    """BaseTrack from odometry messages (nav_msgs/Odometry): pose (position, x y z w quaternion) and twist.

    The twist is taken as expressed in the base (child) frame, as nav_msgs/Odometry specifies. Without
    a twist the velocities are differentiated from the poses. Poses that move further than the twist
    allows (by more than ``jump_tol`` m plus 20 %) or faster than ``max_speed`` are reported as jumps.
    """
    t, position, quat_xyzw = _check_stream("odometry", t, position, quat_xyzw)
    if position.shape != (t.size, 3) or quat_xyzw.shape != (t.size, 4):
        raise InputError("odometry: position must be (n, 3) and quat_xyzw (n, 4)")
    norms = np.linalg.norm(quat_xyzw, axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        raise InputError("odometry: orientation quaternions are not unit length; check the x, y, z, w order")
    from scipy.spatial.transform import Rotation  # here: scipy.spatial takes 0.2 s to load

    R = Rotation.from_quat(quat_xyzw).as_matrix()
    T = make_T(R, position)
    dt = np.diff(t)
    dp = np.diff(position, axis=0)
    dp_body = np.einsum("nji,nj->ni", R[:-1], dp)  # step expressed in the base frame at its start
    drot = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:])).as_rotvec()
    n = t.size

    def rates(d: np.ndarray) -> np.ndarray:
        return np.stack([_rates_at_samples(t, d[:, k]) for k in range(3)], axis=1)

    v = rates(dp_body) if linear is None else _check_stream("odometry twist", t, linear)[1]
    omega = rates(drot) if angular is None else _check_stream("odometry twist", t, angular)[1]
    if v.shape != (n, 3) or omega.shape != (n, 3):
        raise InputError("odometry: linear and angular twists must be (n, 3)")
    warnings: list[str] = []
    step = np.linalg.norm(dp, axis=1)
    expected = 0.5 * (np.linalg.norm(v[1:], axis=1) + np.linalg.norm(v[:-1], axis=1)) * dt
    jump = (step / dt > max_speed) | (step > 1.2 * expected + jump_tol)
    jumps = t[1:][jump]
    if jump.any():
        warnings.append(
            f"{int(jump.sum())} odometry pose jump(s) not explained by the twist (first at t={jumps[0]:.3f} s)"
        )
    gaps = find_gaps(t, gap_factor)
    if gaps.size:
        warnings.append(f"{len(gaps)} gap(s) in odometry longer than {gap_factor}x the median step")
    for msg in warnings:
        log.warning(msg)
    info = {"source": "odometry messages", "gaps": gaps, "jumps": jumps, "warnings": warnings,
            "net_motion_known": True}  # poses: the motion across a gap in the messages is their difference
    return BaseTrack(t, T, v, omega, info=info)


def resample(track: BaseTrack, t_new: np.ndarray) -> BaseTrack:
    """The track at new times inside its span: poses by SE(3) interpolation, velocities linearly."""
    t_new = np.asarray(t_new, dtype=float)
    try:
        T = interpolate_poses(t_new, track.t, track.T_world_base)
    except ValueError as exc:
        raise InputError(f"resample: {exc}; keep the query times inside the track") from exc
    v, w = velocity_at(track, t_new)
    info = dict(track.info, resampled_from=len(track))
    return BaseTrack(t_new, T, v, w, info=info)


def velocity_at(track: BaseTrack, t_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Base-frame linear and angular velocity (m, 3) at arbitrary times inside the track (linear interpolation)."""
    tq = np.atleast_1d(np.asarray(t_query, dtype=float))
    if tq.size and (tq.min() < track.t[0] - 1e-9 or tq.max() > track.t[-1] + 1e-9):
        raise InputError(
            f"velocity_at: times [{tq.min():.3f}, {tq.max():.3f}] outside the track "
            f"[{track.t[0]:.3f}, {track.t[-1]:.3f}]"
        )
    v = np.stack([np.interp(tq, track.t, track.v[:, k]) for k in range(3)], axis=1)
    w = np.stack([np.interp(tq, track.t, track.omega[:, k]) for k in range(3)], axis=1)
    return v, w


def in_gap(track: BaseTrack, t_query: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Mask of query times that fall inside a reported gap or within ``margin`` s of a jump."""
    tq = np.asarray(t_query, dtype=float)
    bad = np.zeros(tq.shape, dtype=bool)
    for a, b in np.asarray(track.info.get("gaps", np.zeros((0, 2)))).reshape(-1, 2):
        bad |= (tq > a - margin) & (tq < b + margin)
    jumps = np.asarray(track.info.get("jumps", np.zeros(0))).ravel()
    if jumps.size:
        bad |= np.min(np.abs(tq[..., None] - jumps), axis=-1) <= max(margin, 1e-9) + np.median(np.diff(track.t))
    return bad


def rescale_planar_track(track: BaseTrack, speed_scale: float = 1.0, turn_scale: float = 1.0) -> BaseTrack:
    """The planar track re-integrated with its arc lengths times ``speed_scale`` and turns times ``turn_scale``.

    Corrects a wheel radius (speed) or an effective track width (turn rate: b_eff = b / turn_scale) after the
    fact. Each step's arc length and heading change are recovered exactly from consecutive poses (the inverse
    of the arc integration), scaled and integrated again from the first pose; velocities are scaled alike.
    """
    if not (speed_scale > 0 and turn_scale > 0):
        raise InputError(f"rescale_planar_track: scales must be positive, got {speed_scale}, {turn_scale}")
    T = track.T_world_base
    theta = np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
    dth = np.diff(theta)
    dp = np.diff(T[:, :2, 3], axis=0)
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    along = c * dp[:, 0] + s * dp[:, 1]  # the step in the base frame at its start
    across = -s * dp[:, 0] + c * dp[:, 1]
    small = np.abs(dth) < 1e-9
    th = np.where(small, 1.0, dth)
    sinc = np.where(small, 1.0 - dth**2 / 6.0, np.sin(th) / th)
    vers = np.where(small, dth / 2.0, (1.0 - np.cos(th)) / th)
    # Least-squares arc length from both components of the chord (exact for a true arc step).
    ds = (along * sinc + across * vers) / (sinc**2 + vers**2)
    x, y, th_new = integrate_planar(speed_scale * ds, turn_scale * dth, T[0, 0, 3], T[0, 1, 3], theta[0])
    n = len(track)
    poses = make_T(rot_z(th_new), np.stack([x, y, np.full(n, T[0, 2, 3])], axis=1))
    info = dict(track.info, speed_scale=float(speed_scale), turn_scale=float(turn_scale))
    return BaseTrack(track.t, poses, track.v * speed_scale, track.omega * turn_scale, info=info)
