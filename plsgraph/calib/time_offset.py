"""Time offset between the camera and the odometry clocks, and the pairing of their motion samples.

Convention: a camera sample stamped t_cam belongs to odometry time t_cam + td.

The offset is found without knowing the extrinsic. A ground robot's base turns about one axis only, so the
camera's angular velocity is one-dimensional too, along an unknown but fixed axis: its principal direction.
The search maximises the Pearson correlation of the signed components along the two principal axes over the
shifts in a user range, first on a coarse grid, then on a fine grid around the best coarse shift, and finally
refines the peak by a parabola through the best fine sample and its neighbours. The rotation-invariant
magnitudes |omega_cam(t)| and |omega_base(t + td)| can be correlated instead (``project=False``). When the
robot hardly turns (driving straight) the linear velocity is used the same way: without rotation the camera
and the base move with the same speed. For comparison the search can also score each shift by the share of
covariance the 3-D angular velocities explain (the motion-correlation approach of the CCA / PLS calibration
line); that score is rotation invariant too, because it uses the singular values of the cross-covariance.

Camera velocities come from the pose track by Savitzky-Golay differentiation on a uniform grid: positions
directly, orientation through the accumulated body-frame rotation increments (their Savitzky-Golay
derivative is the body angular velocity up to second-order commutator terms, exact when the rotation axis is
fixed as under planar motion). Single-frame pose outliers are removed first. The base poses are
differentiated with the same filter, so both sides have the same frequency response.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import interpolate_poses, so3_log
from ..core.tracks import BaseTrack, CameraTrack, gap_indices
from ..errors import DegenerateMotionError, InputError, InsufficientDataError
from ..odometry.wheels import in_gap

log = logging.getLogger(__name__)

SIGNALS = ("auto", "angular", "linear")
METHODS = ("correlation", "explained_covariance")

#: A correlation peak below this (but above ``min_score``) is said in a warning. With the offset inside the search
#: range the peak was 0.98-0.999 on about fifty recordings of the independent generator and 0.84-0.999 on the
#: study's 90 (the lowest with its offset 141 ms off); an offset of 0.8 s searched in +-0.5 s peaked at 0.73.
POOR_CORRELATION = 0.9

#: Below this RMS turn rate (rad/s) the angular signal is considered too weak and "auto" uses the speed.
MIN_TURN_RATE = 0.05
#: Savitzky-Golay window (s) for differentiating poses. Half a second keeps up with a ground robot's turns
#: (the same filter is applied to both sensors, so it attenuates both alike) while averaging PnP noise; with
#: 0.3 s a small board's PnP noise swamped the speed signal of straight driving (docs/odometry_and_time_offset.md).
DEFAULT_WINDOW_S = 0.5
#: Below this RMS speed (m/s) the speed signal is too weak to correlate (the turn rate is used, or none).
MIN_SIGNAL_SPEED = 0.02
#: When the odometry shows no motion but the camera turned at this many times MIN_TURN_RATE against the board, the
#: wheel data are wrong (a frozen encoder, the wrong joints, a wheel radius far too small), not the driving.
CAMERA_MOVED_FACTOR = 3.0


@dataclass(frozen=True)
class CameraVelocities:
    """Camera body velocities on a uniform grid (camera clock): ``omega`` and ``v`` (n, 3) in the camera frame.

    ``valid`` (n,) is False where the grid falls into a gap of the track (the filter window reached over
    missing frames); ``t`` are camera stamps.
    """

    t: np.ndarray
    omega: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    info: dict = field(default_factory=dict)


def savgol_filter(x: np.ndarray, window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0,
                  axis: int = 0) -> np.ndarray:
    """Savitzky-Golay filter of ``x`` along ``axis`` over an odd ``window_length``: each sample becomes the
    ``deriv``-th derivative (per ``delta`` of sample spacing) at the centre of the least-squares polynomial of order
    ``polyorder`` fitted to its window; the first and last half windows take the polynomial fitted to the first and
    last whole window (what scipy.signal.savgol_filter does by default, whose import costs most of a second)."""
    if window_length % 2 != 1 or not 0 <= polyorder < window_length or x.shape[axis] < window_length:
        raise ValueError("savgol_filter: window_length must be odd, > polyorder and <= the length of x")
    y = np.moveaxis(np.asarray(x, dtype=float), axis, 0)
    n, h = y.shape[0], window_length // 2
    flat = y.reshape(n, -1)
    # Least-squares polynomial over the window offsets k = -h..h: coefficients = pinv(V) @ samples, with
    # V[k, j] = k^j. The deriv-th derivative at offset u is sum_j j!/(j-deriv)! u^(j-deriv) coef_j.
    k = np.arange(-h, h + 1, dtype=float)
    pinv = np.linalg.pinv(k[:, None] ** np.arange(polyorder + 1))  # (order + 1, window)

    def derivative_at(u: np.ndarray) -> np.ndarray:  # (len(u), window): weights of the window's samples
        j = np.arange(polyorder + 1)
        fac = np.array([np.prod(np.arange(i - deriv + 1, i + 1)) if i >= deriv else 0.0 for i in j])
        powers = np.where(j >= deriv, u[:, None] ** np.clip(j - deriv, 0, None), 0.0)
        return (powers * fac) @ pinv / delta ** deriv

    out = np.empty_like(flat)
    w = derivative_at(np.zeros(1))[0]
    windows = np.lib.stride_tricks.sliding_window_view(flat, window_length, axis=0)  # (n - 2h, m, window)
    out[h:n - h] = windows @ w
    out[:h] = derivative_at(np.arange(-h, 0, dtype=float)) @ flat[:window_length]
    out[n - h:] = derivative_at(np.arange(1, h + 1, dtype=float)) @ flat[n - window_length:]
    return np.moveaxis(out.reshape(y.shape), 0, axis)


def _window_half(window_s: float, rate: float, polyorder: int) -> int:
    return max(polyorder + 1, int(round(0.5 * window_s * rate)))


def body_velocities(T: np.ndarray, rate: float, half: int, polyorder: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame angular and linear velocity (n, 3) of poses T (n, 4, 4) sampled uniformly at ``rate``.

    Savitzky-Golay derivative over 2 * half + 1 samples: of the positions, then rotated into the body frame,
    and of the accumulated body-frame rotation increments.
    """
    win = 2 * half + 1
    if T.shape[0] < win:
        raise InsufficientDataError(f"{T.shape[0]} poses are fewer than the {win}-sample differentiation window")
    R = T[:, :3, :3]
    inc = so3_log(np.einsum("nji,njk->nik", R[:-1], R[1:]))
    phi = np.vstack([np.zeros(3), np.cumsum(inc, axis=0)])
    d = 1.0 / rate
    omega = savgol_filter(phi, win, polyorder, deriv=1, delta=d, axis=0)
    p_dot = savgol_filter(T[:, :3, 3], win, polyorder, deriv=1, delta=d, axis=0)
    return omega, np.einsum("nji,nj->ni", R, p_dot)


def pose_outliers(
    T: np.ndarray,
    half: int,
    sigma: float = 5.0,
    iterations: int = 3,
    min_rot_rad: float = np.radians(0.3),
    min_pos_m: float = 0.005,
) -> np.ndarray:
    """Mask of poses (n, 4, 4) that stick out of a smooth trajectory (single-frame spikes in rotation or position).

    Positions and the accumulated body-frame rotation increments are compared with their Savitzky-Golay
    smoothing over 2 * half + 1 frames; a pose whose residual exceeds ``sigma`` robust standard deviations
    (1.4826 MAD) on either, and at least ``min_rot_rad`` / ``min_pos_m`` (so that noise-free tracks, whose MAD
    is rounding dust, keep every pose), is an outlier. Outliers are replaced by their neighbours' interpolation
    and the test repeated, because one spike also bends the smoothing around it.
    """
    n = T.shape[0]
    win = 2 * half + 1
    bad = np.zeros(n, dtype=bool)
    if n < win + 2:
        return bad
    idx = np.arange(n)
    for _ in range(iterations):
        good = np.flatnonzero(~bad)
        # Interpolate the good poses back onto every index, so the filter runs on an evenly indexed sequence.
        Tg = interpolate_poses(idx.astype(float).clip(good[0], good[-1]), good.astype(float), T[good])
        R = Tg[:, :3, :3]
        phi = np.vstack([np.zeros(3), np.cumsum(so3_log(np.einsum("nji,njk->nik", R[:-1], R[1:])), axis=0)])
        # The residuals of the measured (not the interpolated) poses against the smooth curve.
        R_meas = T[:, :3, :3]
        phi_meas = phi + so3_log(np.einsum("nji,njk->nik", R, R_meas))
        res_r = np.linalg.norm(phi_meas - savgol_filter(phi, win, 2, axis=0), axis=1)
        res_p = np.linalg.norm(T[:, :3, 3] - savgol_filter(Tg[:, :3, 3], win, 2, axis=0), axis=1)
        new = np.zeros(n, dtype=bool)
        for r, floor in ((res_r, min_rot_rad), (res_p, min_pos_m)):
            ref = r[~bad]
            scale = 1.4826 * np.median(np.abs(ref - np.median(ref)))
            new |= r > max(np.median(ref) + sigma * scale, floor)
        if np.array_equal(new, bad):
            break
        bad = new
    return bad


def camera_velocities_on_grid(
    track: CameraTrack,
    window_s: float = DEFAULT_WINDOW_S,
    polyorder: int = 2,
    rate: float | None = None,
    gap_factor: float = 2.5,
    outlier_sigma: float | None = 5.0,
    min_gap_s: float = 0.2,
) -> CameraVelocities:
    """Angular and linear velocity of the camera in its own frame on a uniform grid, for pairing with the base.

    The track is resampled onto a uniform grid so that exactly the same filter can be applied to the base poses
    (``base_velocities_on_grid``), and single-frame pose outliers are dropped first.

    The board does not move, so the body velocity of T_board_cam is the camera's velocity relative to the
    world, expressed in the camera frame. ``window_s`` is the Savitzky-Golay window (s); ``rate`` the grid
    rate (default: the median frame rate). Grid samples closer than half a window to a hole in the track
    (a step longer than ``gap_factor`` times the median and than ``min_gap_s``) are marked invalid; shorter
    holes (a few frames without a detection) are bridged by pose interpolation, whose error over 0.2 s of
    ordinary driving (about 1 m/s^2) stays near a millimetre. Poses that jump away from their
    neighbours by more than ``outlier_sigma`` robust standard deviations (a PnP flip, a misdetection) are
    dropped first (``info["outliers"]``); None keeps every pose.
    """
    t = track.t
    if t.size < 5:
        raise InsufficientDataError(f"camera track: need at least 5 poses to differentiate, got {t.size}")
    dt_med = float(np.median(np.diff(t)))
    outliers = np.zeros(t.size, dtype=bool)
    if outlier_sigma is not None:
        outliers = pose_outliers(track.T_board_cam, _window_half(window_s, 1.0 / dt_med, polyorder), outlier_sigma)
        if outliers.any():
            track = CameraTrack(t[~outliers], track.T_board_cam[~outliers])
            t = track.t
    rate = 1.0 / dt_med if rate is None else float(rate)
    n = int(np.floor((t[-1] - t[0]) * rate)) + 1
    tg = t[0] + np.arange(n) / rate
    tg = tg[tg <= t[-1]]
    half = _window_half(window_s, rate, polyorder)
    omega, v = body_velocities(track.poses_at(tg), rate, half, polyorder)
    # Validity: no hole in the original track within half a window of a grid sample.
    holes = gap_indices(t, gap_factor, min_gap_s)
    valid = np.ones(tg.size, dtype=bool)
    reach = half / rate
    for k in holes:
        valid &= ~((tg > t[k] - reach) & (tg < t[k + 1] + reach))
    valid[:half] = False  # the filter's edge polynomials are extrapolations
    valid[-half:] = False
    info = {
        "window_s": (2 * half + 1) / rate,
        "half": half,
        "polyorder": polyorder,
        "rate": rate,
        "holes": int(holes.size),
        "outliers": int(outliers.sum()),
        "outlier_mask": outliers,
    }
    return CameraVelocities(tg, omega, v, valid, info)


def base_velocities_on_grid(
    base: BaseTrack, t_odom: np.ndarray, rate: float, half: int, polyorder: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Base (v, omega) at uniformly spaced odometry times, differentiated exactly like the camera poses.

    Using the same Savitzky-Golay filter on both sides gives both the same frequency response, so the
    smoothing scales both signals alike and shifts neither. Grid ends closer than ``half`` samples to the
    track's ends are evaluated on the clamped poses.
    """
    pad = np.arange(1, half + 1) / rate
    t_ext = np.r_[t_odom[0] - pad[::-1], t_odom, t_odom[-1] + pad]
    T = base.poses_at(np.clip(t_ext, base.t[0], base.t[-1]))
    omega, v = body_velocities(T, rate, half, polyorder)
    return v[half:-half], omega[half:-half]


@dataclass(frozen=True)
class TimeOffsetResult:
    """Estimated ``td`` (s, t_odom = t_cam + td) with the curve it came from.

    ``projected`` tells whether signed principal-axis components (rather than magnitudes) were correlated.
    ``score`` is the curve value at the peak (a correlation or an explained-covariance share in [0, 1]);
    ``shifts`` / ``values`` the fine-and-coarse curve for plotting (sorted by shift); ``sharpness`` the
    negative curvature of the parabola at the peak (1/s^2, larger = better determined); ``peak_width_s``
    the width of the main lobe at half its height above the curve's median; ``second_peak_ratio`` the
    highest other local maximum over the peak (near 1 = ambiguous); ``at_range_edge`` is True when the
    best shift lies on the border of the search range, so the true offset may be outside it; ``ok`` is
    False whenever the estimate must not be trusted, and ``warnings`` says why.
    """

    td: float
    score: float
    method: str
    signal: str
    projected: bool
    shifts: np.ndarray
    values: np.ndarray
    sharpness: float
    peak_width_s: float
    second_peak_ratio: float
    at_range_edge: bool
    n_samples: int
    ok: bool
    warnings: list[str] = field(default_factory=list)


def _pearson_rows(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Correlation of each row of A (k, n) with b (n,)."""
    A = A - A.mean(axis=1, keepdims=True)
    b = b - b.mean()
    den = np.sqrt(np.sum(A * A, axis=1) * np.sum(b * b))
    return np.where(den > 0, (A @ b) / np.where(den > 0, den, 1.0), 0.0)


def _explained_cov_rows(Y: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Share of covariance the best rotation explains, for each shift: ||C||_* / sqrt(tr Sxx tr Syy).

    Y (k, n, 3) base angular velocities per shift, X (n, 3) camera angular velocities. For Y = X R^T the
    nuclear norm of the cross-covariance equals tr Sxx and the score is 1.
    """
    Xc = X - X.mean(axis=0)
    Yc = Y - Y.mean(axis=1, keepdims=True)
    C = np.einsum("ni,knj->kij", Xc, Yc)
    nuc = np.linalg.svd(C, compute_uv=False).sum(axis=1)
    den = np.sqrt(np.sum(Xc * Xc) * np.sum(Yc * Yc, axis=(1, 2)))
    return np.where(den > 0, nuc / np.where(den > 0, den, 1.0), 0.0)


def _principal_axis(A: np.ndarray) -> tuple[np.ndarray, float]:
    """Dominant direction of samples A (n, 3) (second moment about zero) and the spread sqrt(l2 / l1) across it."""
    evals, evecs = np.linalg.eigh(A.T @ A)
    if not evals[-1] > 0:
        return evecs[:, -1], 1.0
    return evecs[:, -1], float(np.sqrt(max(evals[-2], 0.0) / evals[-1]))


def main_lobe(values: np.ndarray, lo: int, hi: int) -> tuple[int, int]:
    """Indices of the minima that bound the lobe holding ``values[lo:hi + 1]``: walk down both flanks while the
    curve keeps falling. Everything outside is "another peak"."""
    a = lo
    while a > 0 and values[a - 1] <= values[a]:
        a -= 1
    b = hi
    while b < values.size - 1 and values[b + 1] <= values[b]:
        b += 1
    return a, b


def _lobe_stats(shifts: np.ndarray, values: np.ndarray, i_peak: int) -> tuple[float, float]:
    """Width of the main lobe at half height above the median, and the best other local maximum / peak."""
    base = float(np.median(values))
    peak = float(values[i_peak])
    half = base + 0.5 * (peak - base)
    lo = i_peak
    while lo > 0 and values[lo - 1] > half and values[lo - 1] <= values[lo] + 1e-12:
        lo -= 1
    hi = i_peak
    while hi < values.size - 1 and values[hi + 1] > half and values[hi + 1] <= values[hi] + 1e-12:
        hi += 1
    width = float(shifts[hi] - shifts[lo])
    a, b = main_lobe(values, lo, hi)
    others = np.r_[values[:a], values[b + 1 :]]
    if others.size == 0 or peak <= 0:
        return width, 0.0 if peak > 0 else 1.0
    return width, float(max(others.max(), 0.0) / peak)


def seconds_short_of(have: float, need: float) -> str:
    """``have`` seconds (less than ``need``) written to the digits that tell them from ``need``: 2.996 s is not
    "3.00 s" when 3 s are needed."""
    for digits in (2, 3, 4, 6):
        text = f"{have:.{digits}f}"
        if float(text) < need:
            return text
    return f"{have:.9f}"


def estimate_time_offset(
    camera: CameraTrack | CameraVelocities,
    base: BaseTrack,
    td_range: tuple[float, float] = (-0.5, 0.5),
    method: str = "correlation",
    signal: str = "auto",
    coarse_step: float | None = None,
    fine_step: float | None = None,
    window_s: float = DEFAULT_WINDOW_S,
    min_overlap_s: float = 3.0,
    min_score: float = 0.5,
    max_second_peak_ratio: float = 0.9,
    project: bool | None = None,
) -> TimeOffsetResult:
    """Time offset td (t_odom = t_cam + td) searched in ``td_range`` (s).

    ``method``: "correlation" (Pearson correlation of the angular-rate or speed magnitudes) or
    "explained_covariance" (3-D angular velocities, rotation-invariant explained covariance).
    ``signal``: "angular", "linear" or "auto" (angular unless the robot hardly turns). ``project``: correlate
    the signed components along each side's principal axis instead of magnitudes (default: when the base
    signal is one-dimensional, as for a ground robot). Steps default to
    a third of the camera sample period (coarse) and a tenth of that (fine). The result is flagged not
    ``ok`` when the peak is weak (< ``min_score``), ambiguous (second peak ratio above
    ``max_second_peak_ratio``) or on the border of the range.
    """
    if method not in METHODS:
        raise InputError(f"unknown time-offset method {method!r}; use one of {', '.join(METHODS)}")
    if signal not in SIGNALS:
        raise InputError(f"unknown signal {signal!r}; use one of {', '.join(SIGNALS)}")
    lo, hi = float(td_range[0]), float(td_range[1])
    if not hi > lo:
        raise InputError(f"td_range must be (low, high) with low < high, got {td_range}")
    cv = camera if isinstance(camera, CameraVelocities) else camera_velocities_on_grid(camera, window_s=window_s)
    # A fixed set of camera samples for every shift, so the curve compares like with like.
    reach = cv.info.get("window_s", window_s)  # keep the base filter clear of the odometry's ends
    keep = cv.valid & (cv.t + lo >= base.t[0] + reach) & (cv.t + hi <= base.t[-1] - reach)
    dt_c = float(np.median(np.diff(cv.t)))
    if np.count_nonzero(keep) * dt_c < min_overlap_s:
        span_c = (cv.t[0], cv.t[-1])
        inside = cv.valid & (cv.t + lo >= base.t[0] + reach) & (cv.t + hi <= base.t[-1] - reach)
        overlap = (cv.t + lo >= base.t[0] + reach) & (cv.t + hi <= base.t[-1] - reach)
        have = seconds_short_of(np.count_nonzero(inside) * dt_c, min_overlap_s)
        raise InsufficientDataError(
            f"only {have} s of camera velocity samples fall inside the odometry "
            f"for every td in {td_range} (camera track [{span_c[0]:.2f}, {span_c[1]:.2f}] s, "
            f"odometry [{base.t[0]:.2f}, {base.t[-1]:.2f}] s, {np.count_nonzero(overlap) * dt_c:.1f} s of overlap, "
            f"{np.count_nonzero(cv.valid)} of {cv.t.size} camera samples usable, the rest in detection gaps); "
            f"need {min_overlap_s:g} s: record longer with the board in view, or narrow the td search range"
        )
    tc = cv.t[keep]
    w_c, v_c = cv.omega[keep], cv.v[keep]
    # Base velocities filtered like the camera's, on a fine uniform odometry grid we can shift by interpolation.
    rate_b = 1.0 / float(np.median(np.diff(base.t)))
    tb = np.arange(base.t[0], base.t[-1], 1.0 / rate_b)
    half_b = _window_half(cv.info.get("window_s", window_s), rate_b, cv.info.get("polyorder", 2))
    vb_all, wb_all = base_velocities_on_grid(base, tb, rate_b, half_b, cv.info.get("polyorder", 2))
    warnings: list[str] = []
    turn_rms = float(np.sqrt(np.mean(wb_all[:, 2] ** 2 + np.sum(wb_all[:, :2] ** 2, axis=1))))
    speed_rms = float(np.sqrt(np.mean(np.sum(vb_all**2, axis=1))))
    used = signal
    if signal == "auto":
        used = "angular" if turn_rms >= MIN_TURN_RATE else "linear"
    if method == "explained_covariance" and used != "angular":
        raise DegenerateMotionError(
            f"explained_covariance needs rotation (RMS turn rate {turn_rms:.3f} rad/s); use method='correlation'"
        )
    if used == "angular" and turn_rms < MIN_TURN_RATE:
        raise DegenerateMotionError(
            f"the robot hardly turns (RMS turn rate {turn_rms:.3f} rad/s < {MIN_TURN_RATE}); the angular signal "
            "cannot fix the time offset. Turn while recording or use signal='linear'"
        )
    if used == "linear" and speed_rms < MIN_SIGNAL_SPEED:
        cam_turn = float(np.sqrt(np.mean(np.sum(w_c**2, axis=1)))) if w_c.size else 0.0
        if cam_turn >= CAMERA_MOVED_FACTOR * MIN_TURN_RATE:
            raise DegenerateMotionError(
                f"the wheel odometry shows no motion (RMS turn rate {turn_rms:.3f} rad/s, speed {speed_rms:.3f} m/s) "
                f"while the camera turned (RMS {cam_turn:.3f} rad/s against the board): the wheel angles do not "
                "follow the wheels (a frozen encoder, the wrong joints: --left-joint/--right-joint) or "
                "--wheel-radius/--track-width are far too small"
            )
        raise DegenerateMotionError(
            f"the robot neither turns (RMS {turn_rms:.3f} rad/s) nor drives (RMS speed {speed_rms:.3f} m/s); "
            "the time offset is unobservable. Record while driving and turning"
        )

    src_b, src_c = (wb_all, w_c) if used == "angular" else (vb_all, v_c)
    ax_b, spread_b = _principal_axis(src_b)
    projected = method == "correlation" and (project if project is not None else spread_b < 0.1)
    if projected:
        # The base moves along one axis (z for turning, x for driving), so the camera signal is one axis too,
        # whatever the extrinsic: its principal direction. Correlating the signed components along those
        # axes drops the camera noise across the axis and the |.| bias a magnitude carries.
        ax_c, _ = _principal_axis(src_c)
        sig_b, sig_c = src_b @ ax_b, src_c @ ax_c
    else:
        sig_b, sig_c = np.linalg.norm(src_b, axis=1), np.linalg.norm(src_c, axis=1)

    def curve(shifts: np.ndarray) -> np.ndarray:
        tq = (tc[None, :] + shifts[:, None]).ravel()
        if method == "explained_covariance":
            Y = np.stack([np.interp(tq, tb, wb_all[:, k]) for k in range(3)], axis=-1)
            return _explained_cov_rows(Y.reshape(shifts.size, tc.size, 3), w_c)
        B = np.interp(tq, tb, sig_b).reshape(shifts.size, tc.size)
        return _pearson_rows(B, sig_c)

    dt_c = float(np.median(np.diff(cv.t)))
    coarse = coarse_step if coarse_step else min(dt_c / 3.0, (hi - lo) / 20.0)
    fine = fine_step if fine_step else coarse / 10.0
    s_coarse = np.arange(lo, hi + 0.5 * coarse, coarse)
    s_coarse = s_coarse[s_coarse <= hi + 1e-12]
    c_coarse = curve(s_coarse)
    if projected and -c_coarse.min() > c_coarse.max():
        sig_c = -sig_c  # the principal axes' signs are arbitrary: take the sign that makes the peak positive
        c_coarse = -c_coarse
    i0 = int(np.argmax(c_coarse))
    s_fine = np.arange(max(lo, s_coarse[i0] - 2 * coarse), min(hi, s_coarse[i0] + 2 * coarse) + 0.5 * fine, fine)
    s_fine = s_fine[s_fine <= hi + 1e-12]
    c_fine = curve(s_fine)
    j = int(np.argmax(c_fine))
    td = float(s_fine[j])
    sharp = 0.0
    if 0 < j < s_fine.size - 1:
        y0, y1, y2 = c_fine[j - 1], c_fine[j], c_fine[j + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            td = float(s_fine[j] + 0.5 * fine * (y0 - y2) / den)
            sharp = float(-den / fine**2)
    score = float(np.max(c_fine))
    shifts = np.r_[s_coarse, s_fine]
    values = np.r_[c_coarse, c_fine]
    order = np.argsort(shifts, kind="stable")
    shifts, values = shifts[order], values[order]
    width, ratio = _lobe_stats(s_coarse, c_coarse, i0)
    edge = bool(td - lo < 1.5 * coarse or hi - td < 1.5 * coarse)
    if edge:
        warnings.append(
            f"time offset {td:+.4f} s lies on the border of the search range [{lo}, {hi}] s: the true offset may be "
            "outside it; widen --td-range (td_range; at most 10 s; clocks further apart: --clock-align always or "
            "--clock-offset)"
        )
    if score < min_score:
        warnings.append(f"weak peak: {method} score {score:.2f} < {min_score}; the time offset is poorly determined")
    elif method == "correlation" and score < POOR_CORRELATION and not edge:
        warnings.append(
            f"the time offset's best shift in [{lo}, {hi}] s matches the camera's "
            f"{'speeds' if used == 'linear' else 'turns'} to the odometry's with a "
            f"correlation of only {score:.2f} (a recording whose clocks are within the range gives 0.95 or more): the "
            "clocks may differ by more than the range (widen --td-range, td_range), or the odometry does not follow "
            "the robot's motion"
        )
    if ratio > max_second_peak_ratio:
        warnings.append(
            f"ambiguous peak: another shift scores {ratio:.2f} of the best; periodic motion or too short a recording"
        )
    if used == "linear" and signal == "auto":
        warnings.append("the robot hardly turns; the time offset comes from the speed profile alone")
    for msg in warnings:
        log.warning(msg)
    ok = not edge and score >= min_score and ratio <= max_second_peak_ratio
    return TimeOffsetResult(
        td=td,
        score=score,
        method=method,
        signal=used,
        projected=bool(projected),
        shifts=shifts,
        values=values,
        sharpness=sharp,
        peak_width_s=width,
        second_peak_ratio=ratio,
        at_range_edge=edge,
        n_samples=int(tc.size),
        ok=ok,
        warnings=warnings,
    )


@dataclass(frozen=True)
class PairedSamples:
    """Camera and base motion paired on the camera grid (camera clock ``t``; odometry time is t + td).

    ``omega_cam``, ``v_cam`` (n, 3) in the camera frame; ``omega_base``, ``v_base`` (n, 3) in the base frame.
    ``discarded`` counts the grid samples dropped and why.
    """

    t: np.ndarray
    td: float
    omega_cam: np.ndarray
    v_cam: np.ndarray
    omega_base: np.ndarray
    v_base: np.ndarray
    discarded: dict = field(default_factory=dict)


def pair_samples(
    camera: CameraTrack | CameraVelocities, base: BaseTrack, td: float, window_s: float = DEFAULT_WINDOW_S
) -> PairedSamples:
    """Pair camera and base velocities at common instants within the overlap of both streams (given td)."""
    cv = camera if isinstance(camera, CameraVelocities) else camera_velocities_on_grid(camera, window_s=window_s)
    t_odom = cv.t + td
    reach = cv.info["half"] / cv.info["rate"]  # the base filter must not reach past the odometry's ends
    outside = (t_odom < base.t[0] + reach) | (t_odom > base.t[-1] - reach)
    gap = np.zeros_like(outside)
    gap[~outside] = in_gap(base, t_odom[~outside], margin=0.5 * cv.info.get("window_s", window_s))
    keep = cv.valid & ~outside & ~gap
    discarded = {
        "camera_gap_or_edge": int(np.count_nonzero(~cv.valid)),
        "outside_odometry": int(np.count_nonzero(cv.valid & outside)),
        "odometry_gap_or_jump": int(np.count_nonzero(cv.valid & ~outside & gap)),
    }
    if np.count_nonzero(keep) < 10:
        raise InsufficientDataError(
            f"only {int(np.count_nonzero(keep))} camera samples fall inside the odometry (td = {td:+.3f} s, "
            f"discarded {discarded}); the streams do not overlap in time"
        )
    # The base is differentiated on the camera grid shifted by td, with the camera's filter.
    idx = np.flatnonzero(~outside)
    vb, wb = base_velocities_on_grid(base, t_odom[idx[0] : idx[-1] + 1], cv.info["rate"], cv.info["half"],
                                     cv.info["polyorder"])
    sel = keep[idx[0] : idx[-1] + 1]
    return PairedSamples(cv.t[keep], float(td), cv.omega[keep], cv.v[keep], wb[sel], vb[sel], discarded)
