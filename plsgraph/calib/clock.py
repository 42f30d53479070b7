"""Coarse alignment of two clocks: the camera's and the odometry's, when they may differ by seconds to hours.

The fine time-offset search (:mod:`plsgraph.calib.time_offset`) only looks ±``td_range`` around zero. When the
events and the odometry come from different files (an AEDAT4 or Prophesee ``.raw`` recording beside a ROS bag)
their clocks may be unrelated: a ``.raw`` file counts microseconds from the sensor's start, a ROS bag carries
Unix time. This module finds the clock difference ``c`` (``t_odom ≈ t_cam + c``) first, over every offset the two
recordings allow, so that the fine search only has to find the rest.

What is compared does not depend on the unknown extrinsic: the camera's turn-rate magnitude |omega_cam| against
the base's |omega_z| (a rotation does not change the size of an angular velocity), and the camera's speed |v_cam|
against the base's |v| (equal up to the lever arm's omega x t, a few cm/s). Both are sampled on uniform grids at
``rate_hz`` (25 Hz by default) over each recording's whole span, each relative to its own first sample, so two
clocks hours apart never meet in one float subtraction. The masked normalized cross-correlation over *all*
overlaps (FFT, O(n log n): an hour at 25 Hz is 90 000 samples) skips the camera's detection gaps and the
odometry's gaps; each signal's Pearson correlation is computed over exactly the samples that overlap at that lag,
and lags whose overlap is shorter than half the shorter recording's valid samples are not considered (a few
overlapping seconds correlate well by chance). The two signals' curves are averaged.

Confidence: the peak's correlation (``score``), the best correlation outside the peak's lobe over the peak
(``second_peak_ratio``; a robot that drives the same figure eight again and again gives several equal peaks) and
the two peaks' ``separation`` in standard errors (Fisher z, one independent sample per lobe width). An alignment
with ``score < MIN_SCORE``, or with ``second_peak_ratio > MAX_SECOND_PEAK_RATIO`` and ``separation <
MIN_SEPARATION``, is ambiguous:
:func:`align_clocks` raises :class:`plsgraph.errors.ClockAlignmentError` (the command exits 2) with the
numbers and what to do (vary the motion, or give the difference with ``--clock-offset``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..core.tracks import BaseTrack, CameraTrack
from ..errors import ClockAlignmentError, InsufficientDataError
from .time_offset import (
    DEFAULT_WINDOW_S,
    MIN_SIGNAL_SPEED,
    MIN_TURN_RATE,
    _lobe_stats,
    _window_half,
    base_velocities_on_grid,
    camera_velocities_on_grid,
    main_lobe,
)

log = logging.getLogger(__name__)

#: Grid rate (Hz) of the coarse correlation: the 0.5 s differentiation window leaves nothing above ~4 Hz.
DEFAULT_RATE_HZ = 25.0
#: Below this peak correlation the two recordings do not show the same motion at any offset.
MIN_SCORE = 0.5
#: Above this ratio of the best other peak to the main peak the alignment is ambiguous, unless the two peaks are
#: still MIN_SEPARATION standard errors apart (Fisher z of the two correlations, over the independent samples
#: of the overlap): a 0.99 peak beside a 0.81 one (quasi-periodic simulated driving) is not ambiguous.
MAX_SECOND_PEAK_RATIO = 0.8
MIN_SEPARATION = 4.0
#: Overlap needed at a lag: this share of the shorter recording's valid samples (and at least MIN_OVERLAP_S).
MIN_OVERLAP_SHARE = 0.5
MIN_OVERLAP_S = 3.0


@dataclass(frozen=True)
class RateSignals:
    """Turn-rate magnitude and speed (n,) on a uniform grid ``t0 + i / rate`` of one sensor's clock."""

    t0: float
    rate: float
    turn: np.ndarray
    speed: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.turn.size)


@dataclass(frozen=True)
class ClockAlignment:
    """The clock difference ``offset_s`` (t_odom ≈ t_cam + offset_s) and how sure it is.

    ``offsets_s`` / ``values`` are the correlation curve (decimated to at most 4000 points, for the report);
    ``signals`` the signals averaged (``turn``, ``speed``); ``overlap_s`` the valid overlap at the peak;
    ``separation`` how many standard errors the peak's correlation stands above the best other peak's.
    """

    offset_s: float
    score: float
    second_peak_ratio: float
    separation: float
    peak_width_s: float
    overlap_s: float
    rate_hz: float
    signals: tuple[str, ...]
    searched_s: tuple[float, float]
    offsets_s: np.ndarray = field(repr=False)
    values: np.ndarray = field(repr=False)
    ok: bool = True
    reason: str = ""

    def to_dict(self) -> dict:
        return {
            "offset_s": self.offset_s, "score": self.score, "second_peak_ratio": self.second_peak_ratio,
            "separation": self.separation, "peak_width_s": self.peak_width_s, "overlap_s": self.overlap_s,
            "rate_hz": self.rate_hz,
            "signals": list(self.signals), "searched_s": list(self.searched_s), "ok": self.ok, "reason": self.reason,
        }


def camera_rate_signals(track: CameraTrack, rate: float = DEFAULT_RATE_HZ,
                        window_s: float = DEFAULT_WINDOW_S) -> RateSignals:
    """|omega| and |v| of the camera on a uniform grid of its clock (invalid in detection gaps)."""
    cv = camera_velocities_on_grid(track, window_s=window_s, rate=rate)
    return RateSignals(float(cv.t[0]), float(rate), np.linalg.norm(cv.omega, axis=1), np.linalg.norm(cv.v, axis=1),
                       cv.valid.copy())


def base_rate_signals(base: BaseTrack, rate: float = DEFAULT_RATE_HZ,
                      window_s: float = DEFAULT_WINDOW_S) -> RateSignals:
    """|omega_z| and |v| of the base on a uniform grid of its clock, differentiated like the camera's poses."""
    from ..odometry.wheels import in_gap

    n = int(np.floor((base.t[-1] - base.t[0]) * rate)) + 1
    if n < 10:
        raise InsufficientDataError(f"the odometry spans only {base.t[-1] - base.t[0]:.2f} s")
    tg = base.t[0] + np.arange(n) / rate
    half = _window_half(window_s, rate, 2)
    v, w = base_velocities_on_grid(base, tg, rate, half)
    valid = ~in_gap(base, tg, margin=half / rate)
    valid[:half] = False
    valid[-half:] = False
    return RateSignals(float(tg[0]), float(rate), np.abs(w[:, 2]), np.linalg.norm(v, axis=1), valid)


def _xcorr(x: np.ndarray, y: np.ndarray, nfft: int) -> np.ndarray:
    """c[m] = sum_i x[i] y[i + k] with k = m - (len(x) - 1), for every k with any overlap."""
    from scipy.fft import irfft, rfft  # here: loading scipy (0.1 s) stays off the way to the front end

    n = x.size + y.size - 1
    return irfft(rfft(x[::-1], nfft) * rfft(y, nfft), nfft)[:n]


def masked_ncc(
    a: np.ndarray, ma: np.ndarray, b: np.ndarray, mb: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pearson correlation of a[i] with b[i + k] over the samples valid in both, for every lag k.

    Returns (k, r, n_overlap). Six FFT correlations give the overlap counts, sums and sums of squares per lag
    (the masked normalized cross-correlation of Padfield, 2012, in one dimension).
    """
    ma, mb = ma.astype(float), mb.astype(float)
    a = np.where(ma > 0, a, 0.0)
    b = np.where(mb > 0, b, 0.0)
    # Standardize first: keeps the sums of squares small, so the per-lag differences do not cancel badly.
    if ma.sum() > 1:
        a = np.where(ma > 0, (a - a[ma > 0].mean()) / (a[ma > 0].std() or 1.0), 0.0)
    if mb.sum() > 1:
        b = np.where(mb > 0, (b - b[mb > 0].mean()) / (b[mb > 0].std() or 1.0), 0.0)
    from scipy.fft import next_fast_len

    nfft = next_fast_len(a.size + b.size - 1, real=True)
    n = np.rint(_xcorr(ma, mb, nfft))
    sa, sb = _xcorr(a, mb, nfft), _xcorr(ma, b, nfft)
    saa, sbb = _xcorr(a * a, mb, nfft), _xcorr(ma, b * b, nfft)
    sab = _xcorr(a, b, nfft)
    ns = np.maximum(n, 1.0)
    cov = sab - sa * sb / ns
    va = np.maximum(saa - sa * sa / ns, 0.0)
    vb = np.maximum(sbb - sb * sb / ns, 0.0)
    den = np.sqrt(va * vb)
    ok = (n >= 3) & (den > 1e-9 * ns)
    r = np.where(ok, cov / np.where(ok, den, 1.0), 0.0)
    k = np.arange(r.size) - (a.size - 1)
    return k, np.clip(r, -1.0, 1.0), n


def correlation_curve(cam: RateSignals, base: RateSignals,
                      window_s: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """Offsets c (s, t_odom = t_cam + c), the averaged correlation at each, the overlap (s), and the signals used.

    Only lags with enough overlap (and inside ``window_s`` = (c_min, c_max), if given) are returned.
    """
    if abs(cam.rate - base.rate) > 1e-9:
        raise ValueError("camera and base signals must share a rate")
    rate = cam.rate
    used: list[str] = []
    curves = []
    n_ov = None
    cam_turn = cam.turn[cam.valid]
    cam_speed = cam.speed[cam.valid]
    for name, x, y, strong in (
        ("turn", cam.turn, base.turn, cam_turn.size and np.sqrt(np.mean(cam_turn**2)) >= MIN_TURN_RATE),
        ("speed", cam.speed, base.speed, cam_speed.size and np.sqrt(np.mean(cam_speed**2)) >= MIN_SIGNAL_SPEED),
    ):
        if not strong:
            continue
        k, r, n_ov = masked_ncc(x, cam.valid, y, base.valid)
        curves.append(r)
        used.append(name)
    if not curves:
        raise InsufficientDataError(
            "the camera hardly moves (turn rate and speed both below the correlation thresholds): the clocks "
            "cannot be aligned; record the robot driving and turning with the board in view"
        )
    r = np.mean(curves, axis=0)
    # Grids start at different instants of different clocks; only their difference enters, in one subtraction.
    offsets = (base.t0 - cam.t0) + k / rate
    need = max(MIN_OVERLAP_S * rate, MIN_OVERLAP_SHARE * min(int(cam.valid.sum()), int(base.valid.sum())))
    keep = n_ov >= need
    if window_s is not None:
        keep &= (offsets >= window_s[0]) & (offsets <= window_s[1])
    return offsets[keep], r[keep], n_ov[keep] / rate, tuple(used)


def alignment_from_curve(offsets: np.ndarray, values: np.ndarray, overlap_s: np.ndarray, rate: float,
                         signals: tuple[str, ...]) -> ClockAlignment:
    """The peak of a correlation curve (refined by a parabola) and its confidence."""
    if offsets.size < 3:
        raise InsufficientDataError(
            "the camera and odometry recordings do not overlap long enough at any clock offset "
            f"(need {MIN_OVERLAP_S:.0f} s and half of the shorter one)" if offsets.size == 0 else
            f"only {offsets.size} clock offset(s) left to compare at {rate:g} Hz (the range searched, or the overlap "
            "the recordings need, leaves too few to find a correlation peak in)"
        )
    i = int(np.argmax(values))
    off = float(offsets[i])
    if 0 < i < values.size - 1:
        y0, y1, y2 = values[i - 1], values[i], values[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            off += float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) / rate
    width, ratio = _lobe_stats(offsets, values, i)
    score = float(values[i])
    j = _second_peak_index(offsets, values, i)
    second = float(values[j]) if j != i else 0.0
    # Independent samples in the overlap: one per main-lobe width (the signals are smooth over about that long).
    n_eff = max(float(overlap_s[i]) / max(width, 2.0 / rate), 4.0)
    z = np.arctanh(np.clip([score, max(second, 0.0)], -0.999999, 0.999999))
    separation = float((z[0] - z[1]) * np.sqrt(n_eff - 3.0))
    ok, reason = True, ""
    if score < MIN_SCORE:
        ok, reason = False, (f"the best correlation of the camera's and the odometry's turn rate/speed is only "
                             f"{score:.2f} (need {MIN_SCORE}): the two files may not show the same drive")
    elif ratio > MAX_SECOND_PEAK_RATIO and separation < MIN_SEPARATION:
        ok, reason = False, (f"the clock difference is ambiguous: {off:.3f} s correlates {score:.2f}, but "
                             f"{offsets[j]:.3f} s almost as well ({second:.2f}, ratio {ratio:.2f}, "
                             f"{separation:.1f} standard errors apart, need {MIN_SEPARATION:.0f}); repeated motion "
                             "looks the same at several offsets")
    step = max(1, offsets.size // 4000)
    return ClockAlignment(off, score, float(ratio), separation, float(width), float(overlap_s[i]), float(rate),
                          signals, (float(offsets[0]), float(offsets[-1])), offsets[::step].copy(),
                          values[::step].copy(), ok, reason)


def _second_peak_index(offsets: np.ndarray, values: np.ndarray, i: int) -> int:
    """Index of the highest value outside the main lobe around ``i``."""
    a, b = main_lobe(values, i, i)
    masked = values.copy()
    masked[a : b + 1] = -np.inf
    return int(np.argmax(masked))


def align_clocks(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    rate_hz: float = DEFAULT_RATE_HZ,
    window_s: tuple[float, float] | None = None,
    strict: bool = True,
) -> ClockAlignment:
    """The clock difference c (t_odom ≈ t_cam + c) over every offset the recordings allow (or ``window_s``).

    ``strict`` raises :class:`ClockAlignmentError` when the alignment is ambiguous (see the module notes);
    otherwise the result carries ``ok=False`` and the ``reason``.
    """
    cam = camera_rate_signals(camera_track, rate_hz)
    base = base_rate_signals(base_track, rate_hz)
    return align_signals(cam, base, window_s, strict)


def align_signals(cam: RateSignals, base: RateSignals, window_s: tuple[float, float] | None = None,
                  strict: bool = True) -> ClockAlignment:
    """:func:`align_clocks` on signals already on their grids."""
    offsets, values, overlap, used = correlation_curve(cam, base, window_s)
    res = alignment_from_curve(offsets, values, overlap, cam.rate, used)
    log.info("clock alignment: c = %.4f s, score %.3f, second peak ratio %.2f", res.offset_s, res.score,
             res.second_peak_ratio)
    if strict and not res.ok:
        raise ClockAlignmentError(
            res.reason + "; make sure both files hold the same drive, vary speed and turns while recording, or "
            "give the approximate clock difference with --clock-offset SECONDS (t_odom = t_cam + SECONDS)"
        )
    return res
