"""Image representations of event streams: count frames, time surfaces, the paper's polarity-aware surface
and a leaky polarity integrator.

Every representation is computed from a slice of an :class:`~plsgraph.core.events.EventStream` without a Python
loop per event: per-pixel "last event" quantities come from ``np.maximum.at`` over the event index (events
are sorted by time, so the largest index at a pixel is its most recent event), sums from ``np.bincount``.

Images are float32 arrays of shape (height, width). Ranges:

===================  =====================================================  ===========================
kind                 value                                                  range
===================  =====================================================  ===========================
``count``            number of events at the pixel                          [0, inf)
``polarity_sum``     sum of polarities (ON +1, OFF -1)                       (-inf, inf)
``time_surface``     paper Eq. (1), exp(-(t_ref - T_last) / tau)             [0, 1]; [-1, 1] if signed
``polarity_aware``   paper Eq. (2), exp(-|p_i - p_prev| / alpha), blurred    [0, 1]; [-1, 1] if signed
``leaky``            sum_k p_k C exp(-(t_ref - t_k) / tau)                   about [-C n, C n]
===================  =====================================================  ===========================

Pixels without events are 0 in every representation.

Sign conventions for circle detection (white board, black circles): as a dark circle moves, pixels it
covers get OFF events (leading edge) and pixels it uncovers ON events (trailing edge). Hence

* ``leaky`` (intensity-like): the circles' current positions are negative, i.e. **dark on a light
  background** after :func:`to_uint8` (0 maps to mid-grey); this suits OpenCV's default blob detector
  (``blobColor = 0``) directly.
* ``count``, ``time_surface`` (unsigned) and ``polarity_aware`` (unsigned): circle rims are **bright on a
  dark background**; use ``to_uint8(img, invert=True)`` to get dark blobs on a light background.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np

from ..core.events import EventStream
from ..errors import InputError

log = logging.getLogger(__name__)

KINDS = ("count", "polarity_sum", "time_surface", "polarity_aware", "leaky")
TIME_SURFACE_POLARITIES = ("on", "off", "any", "signed")
PREVIOUS_READINGS = ("pixel", "stream")

#: Default look-back of :func:`surface_at` for the kinds without a decay constant.
DEFAULT_WINDOW_NS = 20_000_000
#: Decaying kinds look back this many decay constants by default (exp(-5) = 0.7 % is dropped).
DECAY_LOOKBACK = 5.0


def pixel_index(stream: EventStream) -> np.ndarray:
    """Flat pixel index y * width + x of every event (intp)."""
    # One new array and no temporaries; "unsafe" casting converts any coordinate dtype as astype(np.intp) did.
    pix = np.multiply(stream.y, stream.width, dtype=np.intp, casting="unsafe")
    np.add(pix, stream.x, out=pix, casting="unsafe")
    return pix


def _until(stream: EventStream, t_ref_ns: int | None) -> tuple[EventStream, int]:
    """Events with t <= t_ref and the reference time (the last event's time if not given)."""
    if t_ref_ns is None:
        return stream, stream.t_last
    t_ref_ns = int(t_ref_ns)
    i1 = int(np.searchsorted(stream.t, t_ref_ns, side="right"))
    return (stream if i1 == len(stream) else stream.slice_index(0, i1)), t_ref_ns


def _check_positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"surfaces: {name} must be a positive finite number, got {value}")
    return value


def _last_index(pix: np.ndarray, n_pixels: int) -> np.ndarray:
    """Index of the most recent event at each pixel, -1 where none (events sorted by time)."""
    last = np.full(n_pixels, -1, dtype=np.intp)
    np.maximum.at(last, pix, np.arange(pix.size, dtype=np.intp))
    return last


def count_image(stream: EventStream, signed: bool = False, polarity: str | None = None) -> np.ndarray:
    """Event count per pixel, or with ``signed`` the sum of polarities (ON - OFF); ``polarity`` "on" / "off" counts
    only that polarity's events."""
    pix = pixel_index(stream)
    n = stream.width * stream.height
    if polarity not in (None, "on", "off"):
        raise InputError(f"count_image: polarity must be 'on', 'off' or None, got {polarity!r}")
    if signed:
        img = np.bincount(pix, weights=stream.p.astype(np.float64), minlength=n)
    elif polarity is not None:
        img = np.bincount(pix[(stream.p > 0) == (polarity == "on")], minlength=n)
    else:
        img = np.bincount(pix, minlength=n)
    return img.astype(np.float32).reshape(stream.height, stream.width)


def time_surface(
    stream: EventStream, t_ref_ns: int | None = None, tau_s: float = 0.03, polarity: str = "any"
) -> np.ndarray:
    """Classic time surface, paper Eq. (1): exp(-(t_ref - T_last(u, p)) / tau).

    ``polarity``: ``"on"`` or ``"off"`` give the per-polarity surfaces S(u, +1), S(u, -1) of Eq. (1);
    ``"any"`` uses the last event regardless of polarity; ``"signed"`` multiplies that value by the last
    event's polarity (range [-1, 1]). Only events with t <= t_ref count; t_ref defaults to the last event.
    """
    if polarity not in TIME_SURFACE_POLARITIES:
        raise InputError(f"time_surface: polarity must be one of {TIME_SURFACE_POLARITIES}, got {polarity!r}")
    tau_s = _check_positive("tau_s", tau_s)
    s, t_ref = _until(stream, t_ref_ns)
    n = s.width * s.height
    if polarity in ("on", "off"):
        # One pass over both polarities (index 2 u + [p > 0]) is cheaper than compacting one polarity first.
        key = pixel_index(s) * 2 + (s.p > 0)
        last = _last_index(key, 2 * n)[(1 if polarity == "on" else 0) :: 2]
    else:
        last = _last_index(pixel_index(s), n)
    has = last >= 0
    img = np.zeros(n, dtype=np.float32)
    age_s = (t_ref - s.t[last[has]]).astype(np.float64) * 1e-9
    val = np.exp(-age_s / tau_s)
    if polarity == "signed":
        val *= s.p[last[has]]
    img[has] = val
    return img.reshape(s.height, s.width)


def time_surface_pair(stream: EventStream, t_ref_ns: int | None = None, tau_s: float = 0.03) -> np.ndarray:
    """Both per-polarity time surfaces of Eq. (1) in one pass: (2, height, width), [0] OFF, [1] ON."""
    tau_s = _check_positive("tau_s", tau_s)
    s, t_ref = _until(stream, t_ref_ns)
    n = s.width * s.height
    last = _last_index(pixel_index(s) * 2 + (s.p > 0), 2 * n)
    has = last >= 0
    img = np.zeros(2 * n, dtype=np.float32)
    img[has] = np.exp(-((t_ref - s.t[last[has]]).astype(np.float64) * 1e-9) / tau_s)
    # Key 2 u + [p > 0] interleaves the channels per pixel; split them into two images.
    return np.ascontiguousarray(img.reshape(s.height, s.width, 2).transpose(2, 0, 1))


def polarity_aware_surface(
    stream: EventStream,
    alpha: float = 0.1,
    blur_ksize: int = 5,
    blur_sigma: float = 0.7,
    previous: str = "pixel",
    lone: str = "keep",
    signed: bool = False,
) -> np.ndarray:
    """Polarity-aware surface, paper Eq. (2): S(u) = exp(-|p_i - p_{i-1}| / alpha), then a Gaussian blur.

    For each pixel u, i is its most recent event. The paper does not say which event i - 1 is:

    * ``previous="pixel"`` (default, our reading): the previous event *at the same pixel*. A pixel whose
      last two events share a polarity (an edge passing by) gets 1, one whose polarity flipped (an edge
      that came and went, flicker) gets exp(-2 / alpha) ~ 0.
    * ``previous="stream"``: the event just before i in the stream (usually another pixel). The first
      event of the stream has no predecessor and is treated as ``lone``.

    ``lone`` says what a pixel with a single event (no predecessor) shows: ``"keep"`` counts it as
    unchanged polarity (1), ``"drop"`` as 0, which suppresses isolated noise events.
    Polarities are +-1, so |p_i - p_{i-1}| is 0 or 2; with alpha = 0.1 a {0, 1} polarity coding would give
    exp(-10) instead of exp(-20) for a flip, equally negligible. ``signed`` multiplies by the last
    polarity (range [-1, 1]). ``blur_ksize=0`` skips the blur. Values lie in [0, 1].
    """
    import cv2

    if previous not in PREVIOUS_READINGS:
        raise InputError(f"polarity_aware_surface: previous must be one of {PREVIOUS_READINGS}, got {previous!r}")
    if lone not in ("keep", "drop"):
        raise InputError(f"polarity_aware_surface: lone must be 'keep' or 'drop', got {lone!r}")
    alpha = _check_positive("alpha", alpha)
    if blur_ksize and (blur_ksize < 0 or blur_ksize % 2 == 0):
        raise InputError(f"polarity_aware_surface: blur_ksize must be odd and positive (or 0), got {blur_ksize}")
    n = stream.width * stream.height
    pix = pixel_index(stream)
    p = stream.p
    last = _last_index(pix, n)
    has = last >= 0
    i_last = last[has]
    if previous == "pixel":
        # The most recent event among those that are not the last at their pixel is the one before the last.
        not_last = last[pix] != np.arange(pix.size)
        prev = np.full(n, -1, dtype=np.intp)
        np.maximum.at(prev, pix[not_last], np.flatnonzero(not_last))
        i_prev = prev[has]
    else:
        i_prev = i_last - 1
    found = i_prev >= 0
    dp = np.zeros(i_last.size, dtype=np.float64)
    dp[found] = np.abs(p[i_last[found]].astype(np.int16) - p[i_prev[found]].astype(np.int16))
    val = np.exp(-dp / alpha)
    if lone == "drop":
        val[~found] = 0.0
    if signed:
        val *= p[i_last]
    img = np.zeros(n, dtype=np.float32)
    img[has] = val
    img = img.reshape(stream.height, stream.width)
    if blur_ksize:
        img = cv2.GaussianBlur(img, (blur_ksize, blur_ksize), blur_sigma)
    return img


def leaky_integrator(
    stream: EventStream, t_ref_ns: int | None = None, tau_s: float | None = 0.05, contrast: float = 0.2
) -> np.ndarray:
    """Per-pixel sum of signed contrast steps with exponential forgetting: sum_k p_k C exp(-(t_ref - t_k) / tau).

    An intensity-like (high-pass filtered log intensity) image: recently darkened pixels are negative.
    ``tau_s=None`` integrates without decay. Only events with t <= t_ref count.
    """
    contrast = _check_positive("contrast", contrast)
    s, t_ref = _until(stream, t_ref_ns)
    w = s.p.astype(np.float64) * contrast
    if tau_s is not None:
        tau_s = _check_positive("tau_s", tau_s)
        w *= np.exp((s.t - t_ref).astype(np.float64) * (1e-9 / tau_s))
    img = np.bincount(pixel_index(s), weights=w, minlength=s.width * s.height)
    return img.astype(np.float32).reshape(s.height, s.width)


def surface(stream: EventStream, kind: str, t_ref_ns: int | None = None, **params) -> np.ndarray:
    """Representation ``kind`` (one of :data:`KINDS`) of all events of ``stream`` up to ``t_ref_ns``.

    ``params`` go to the representation's function (``tau_s``, ``polarity``, ``alpha``, ``contrast``, ...).
    """
    if kind == "count":
        return count_image(_until(stream, t_ref_ns)[0], **params)
    if kind == "polarity_sum":
        return count_image(_until(stream, t_ref_ns)[0], signed=True, **params)
    if kind == "time_surface":
        return time_surface(stream, t_ref_ns, **params)
    if kind == "polarity_aware":
        return polarity_aware_surface(_until(stream, t_ref_ns)[0], **params)
    if kind == "leaky":
        return leaky_integrator(stream, t_ref_ns, **params)
    raise InputError(f"surfaces: unknown kind {kind!r}; use one of {', '.join(KINDS)}")


def _default_window_ns(kind: str, params: dict) -> int:
    if kind == "time_surface":
        return int(DECAY_LOOKBACK * params.get("tau_s", 0.03) * 1e9)
    if kind == "leaky" and params.get("tau_s", 0.05) is not None:
        return int(DECAY_LOOKBACK * params.get("tau_s", 0.05) * 1e9)
    return DEFAULT_WINDOW_NS


def _slice_before(stream: EventStream, t_query_ns: int, window_ns: int | None, count: int | None) -> EventStream:
    """Events in (t_query - window, t_query], or the last ``count`` events with t <= t_query."""
    i1 = int(np.searchsorted(stream.t, t_query_ns, side="right"))
    if count is not None:
        return stream.slice_index(max(0, i1 - int(count)), i1)
    i0 = int(np.searchsorted(stream.t, t_query_ns - window_ns, side="right"))
    return stream.slice_index(i0, i1)


def surface_at(
    stream: EventStream,
    t_query_ns: int,
    kind: str = "polarity_aware",
    window_ns: int | None = None,
    count: int | None = None,
    **params,
) -> np.ndarray:
    """Representation at an arbitrary time from the events just before it.

    Uses the events in (t_query - window_ns, t_query], or the last ``count`` events up to t_query.
    Without either, the window is 5 tau for the decaying kinds (``time_surface``, ``leaky``) and
    :data:`DEFAULT_WINDOW_NS` (20 ms) for the others. Decaying kinds are evaluated at t_query itself.
    """
    if window_ns is not None and count is not None:
        raise InputError("surface_at: give window_ns or count, not both")
    if count is not None and count <= 0:
        raise InputError(f"surface_at: count must be positive, got {count}")
    if window_ns is None and count is None:
        window_ns = _default_window_ns(kind, params)
    elif window_ns is not None and window_ns <= 0:
        raise InputError(f"surface_at: window_ns must be positive, got {window_ns}")
    s = _slice_before(stream, int(t_query_ns), window_ns, count)
    return surface(s, kind, int(t_query_ns), **params)


def surfaces_at(stream: EventStream, t_query_ns: np.ndarray, kind: str = "polarity_aware", **kw) -> np.ndarray:
    """Stack (n, height, width) of :func:`surface_at` at each query time."""
    tq = np.asarray(t_query_ns, dtype=np.int64).ravel()
    out = np.empty((tq.size, stream.height, stream.width), dtype=np.float32)
    for k, t in enumerate(tq):
        out[k] = surface_at(stream, int(t), kind, **kw)
    return out


def windows(
    stream: EventStream,
    kind: str = "polarity_aware",
    duration_ns: int | None = None,
    count: int | None = None,
    step: int | None = None,
    **params,
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (t_ref_ns, image) over consecutive windows of fixed duration or fixed event count.

    Exactly one of ``duration_ns`` (windows [t0 + k step, t0 + k step + duration), t_ref = window end)
    or ``count`` (windows of ``count`` events starting every ``step`` events, t_ref = last event's time).
    ``step`` defaults to the window size (no overlap); a smaller step gives overlapping windows.
    Duration windows without events are skipped. Count windows are all full, except that a stream with
    fewer than ``count`` events gives one window holding all of them; the events after the last full
    count window are not yielded.
    """
    if (duration_ns is None) == (count is None):
        raise InputError("windows: give exactly one of duration_ns or count")
    if len(stream) == 0:
        return
    if duration_ns is not None:
        duration_ns = int(duration_ns)
        step_ns = duration_ns if step is None else int(step)
        if duration_ns <= 0 or step_ns <= 0:
            raise InputError(f"windows: duration_ns and step must be positive, got {duration_ns}, {step_ns}")
        starts = np.arange(stream.t_first, stream.t_last + 1, step_ns, dtype=np.int64)
        i0s = np.searchsorted(stream.t, starts, side="left")
        i1s = np.searchsorted(stream.t, starts + duration_ns, side="left")
        for t0, i0, i1 in zip(starts, i0s, i1s, strict=True):
            if i1 > i0:
                t_ref = int(t0) + duration_ns
                # t_ref lies just past the window; events at exactly t_ref belong to the next one.
                yield t_ref, surface(stream.slice_index(int(i0), int(i1)), kind, t_ref, **params)
    else:
        count = int(count)
        step_n = count if step is None else int(step)
        if count <= 0 or step_n <= 0:
            raise InputError(f"windows: count and step must be positive, got {count}, {step_n}")
        for i0 in range(0, max(1, len(stream) - count + 1), step_n):
            s = stream.slice_index(i0, min(i0 + count, len(stream)))
            yield s.t_last, surface(s, kind, s.t_last, **params)


def to_uint8(
    image: np.ndarray, value_range: tuple[float, float] | None = None, invert: bool = False
) -> np.ndarray:
    """8-bit image for OpenCV detectors.

    ``value_range`` (lo, hi) maps linearly onto 0..255 (clipped). By default: (0, 1) for images within
    [0, 1]; (-1, 1) for images within [-1, 1]; otherwise a robust range from the 99.5th percentile of
    |value| over nonzero pixels, symmetric around 0 (so 0 is mid-grey) when the image has negative values.
    ``invert`` flips bright and dark (e.g. to make event rims dark blobs on a light background).
    """
    img = np.asarray(image, dtype=np.float32)
    if value_range is None:
        lo, hi = float(img.min(initial=0.0)), float(img.max(initial=0.0))
        if lo >= 0.0 and hi <= 1.0:
            value_range = (0.0, 1.0)
        elif lo >= -1.0 and hi <= 1.0:
            value_range = (-1.0, 1.0)
        else:
            nz = np.abs(img[img != 0])
            m = float(np.percentile(nz, 99.5)) if nz.size else 1.0
            m = m if m > 0 else 1.0
            value_range = (-m, m) if lo < 0 else (0.0, m)
    lo, hi = map(float, value_range)
    if not hi > lo:
        raise InputError(f"to_uint8: value_range must have hi > lo, got {value_range}")
    out = np.clip((img - lo) * (255.0 / (hi - lo)), 0.0, 255.0)
    if invert:
        out = 255.0 - out
    return (out + 0.5).astype(np.uint8)
