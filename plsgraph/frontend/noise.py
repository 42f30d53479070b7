"""Sensor noise in event streams: hot pixels, background activity and mains flicker.

Three handlers, each vectorized over sorted events (no loop per event):

* **Hot pixels** (:func:`hot_pixel_mask`): a pixel whose event count is far above the mean of its eight
  neighbours'. Counts are accumulated over the recording as it streams (:class:`NoiseModel`), so the map
  sharpens with time; a moving edge lights its neighbours along the edge too and is never flagged.
* **Background activity** (:func:`background_activity_filter`): an event is kept only if one of its eight
  neighbours fired within ``dt_s`` of it (before or after). Edges fire in runs of neighbouring pixels; leakage
  and shot noise fire isolated pixels. Used on the long windows of slow motion, where isolated noise events
  would otherwise fill the circles' insides.
* **Flicker** (:func:`flicker_mask`): lighting on a 50 / 60 Hz grid modulates at 100 / 120 Hz; on static
  bright areas pixels fire bursts of alternating polarity every half period (or the same polarity every
  period). A pixel whose intervals mostly look like that is masked.

The masks are applied to the window images (a masked pixel shows no event), which costs one assignment per
window instead of a pass over the events.
"""

from __future__ import annotations

import numpy as np

from ..core.events import EventStream

_T_BITS = 40  # event time (ns, relative to the first event) in the low bits of a (pixel, time) sort key


def pixel_counts(stream: EventStream) -> np.ndarray:
    """Events per pixel (height, width) as int64."""
    w, h = stream.width, stream.height
    pix = stream.y.astype(np.int64) * w + stream.x.astype(np.int64)
    return np.bincount(pix, minlength=w * h).reshape(h, w)


def _neighbour_mean(img: np.ndarray) -> np.ndarray:
    """Mean of the eight neighbours of every pixel (edges padded by replication)."""
    p = np.pad(img.astype(np.float64), 1, mode="edge")
    s = sum(p[1 + dy:p.shape[0] - 1 + dy, 1 + dx:p.shape[1] - 1 + dx]
            for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dx or dy)
    return s / 8.0


def hot_pixel_mask(counts: np.ndarray, duration_s: float, ratio: float = 8.0, min_rate_hz: float = 5.0) -> np.ndarray:
    """Pixels firing at least ``min_rate_hz`` and ``ratio`` times their neighbours' mean rate (boolean image)."""
    c = np.asarray(counts, dtype=np.float64)
    floor = max(1.0, min_rate_hz * max(duration_s, 1e-9))
    return (c >= floor) & (c > ratio * (_neighbour_mean(c) + 1.0))


def _pixel_time_order(stream: EventStream) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pixel index, relative time) per event and the order sorting events by pixel, then time."""
    pix = stream.y.astype(np.int64) * stream.width + stream.x.astype(np.int64)
    t = (stream.t - (stream.t[0] if len(stream) else 0)).astype(np.int64)
    key = (pix << _T_BITS) | np.minimum(t, (1 << _T_BITS) - 1)
    order = np.argsort(key, kind="stable")
    return pix, key, order


def background_activity_filter(stream: EventStream, dt_s: float = 0.005) -> np.ndarray:
    """Boolean keep-mask (len(stream),): events with an event of one of their 8 neighbours within ``dt_s``."""
    n = len(stream)
    if n == 0:
        return np.zeros(0, dtype=bool)
    w, h = stream.width, stream.height
    pix, key, order = _pixel_time_order(stream)
    skey = key[order]
    t = key & ((1 << _T_BITS) - 1)
    dt = int(dt_s * 1e9)
    x, y = stream.x.astype(np.int64), stream.y.astype(np.int64)
    keep = np.zeros(n, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if not (dx or dy):
                continue
            ok = (x + dx >= 0) & (x + dx < w) & (y + dy >= 0) & (y + dy < h) & ~keep
            if not np.any(ok):
                continue
            nb = pix[ok] + dx + dy * w
            q = (nb << _T_BITS) | t[ok]
            j = np.searchsorted(skey, q)
            hit = np.zeros(q.size, dtype=bool)
            for jj in (j - 1, j):  # the neighbour's last event before and first event after
                valid = (jj >= 0) & (jj < n)
                kk = skey[np.clip(jj, 0, n - 1)]
                hit |= valid & ((kk >> _T_BITS) == nb) & (np.abs((kk & ((1 << _T_BITS) - 1)) - t[ok]) <= dt)
            keep[np.flatnonzero(ok)[hit]] = True
    return keep


def flicker_mask(stream: EventStream, freqs_hz: tuple[float, ...] = (100.0, 120.0), tol: float = 0.2,
                 min_intervals: int = 6, min_share: float = 0.5) -> np.ndarray:
    """Pixels (boolean image) whose events mostly come at the flicker's rhythm.

    An interval between two consecutive events of one pixel is flicker-like when the polarity flips after
    about half a flicker period or stays after about a whole period (within ``tol`` of it). A pixel is
    masked when at least ``min_intervals`` of its intervals, and ``min_share`` of them, are flicker-like.
    """
    w, h = stream.width, stream.height
    out = np.zeros((h, w), dtype=bool)
    if len(stream) < 2:
        return out
    pix, key, order = _pixel_time_order(stream)
    sp = pix[order]
    st = (key[order] & ((1 << _T_BITS) - 1)).astype(np.float64) * 1e-9
    pol = np.asarray(stream.p)[order] > 0
    same_pix = sp[1:] == sp[:-1]
    dt = np.diff(st)
    flip = pol[1:] != pol[:-1]
    like = np.zeros(dt.size, dtype=bool)
    for f in freqs_hz:
        half, full = 0.5 / f, 1.0 / f
        like |= flip & (np.abs(dt - half) <= tol * half)
        like |= ~flip & (np.abs(dt - full) <= tol * full)
    like &= same_pix
    n_like = np.bincount(sp[1:][like], minlength=w * h)
    n_int = np.bincount(sp[1:][same_pix], minlength=w * h)
    m = (n_like >= min_intervals) & (n_like >= min_share * np.maximum(n_int, 1))
    return m.reshape(h, w)


class NoiseModel:
    """Hot-pixel and flicker masks of one sensor, updated as the recording streams past.

    ``update(stream)`` adds a stretch of events: its per-pixel counts go into the running totals (hot pixels
    are judged on everything seen so far), and flicker is looked for in its first ``flicker_sample_s``
    (a sort of that sample only; flicker does not come and go within a recording). ``mask`` is the union.
    """

    def __init__(self, width: int, height: int, *, hot_ratio: float = 8.0, hot_min_rate_hz: float = 5.0,
                 flicker: bool = True, flicker_sample_s: float = 0.25):
        self.width, self.height = width, height
        self.hot_ratio, self.hot_min_rate_hz = hot_ratio, hot_min_rate_hz
        self.flicker, self.flicker_sample_s = flicker, flicker_sample_s
        self.counts = np.zeros((height, width), dtype=np.int64)
        self.duration_s = 0.0
        self.hot = np.zeros((height, width), dtype=bool)
        self.flickering = np.zeros((height, width), dtype=bool)
        self.mask = np.zeros((height, width), dtype=bool)

    def update(self, stream: EventStream) -> NoiseModel:
        if len(stream) == 0:
            return self
        self.counts += pixel_counts(stream)
        self.duration_s += max(0.0, (stream.t_last - stream.t_first) * 1e-9)
        self.hot = hot_pixel_mask(self.counts, self.duration_s, self.hot_ratio, self.hot_min_rate_hz)
        if self.flicker:
            sample = stream.slice_time(stream.t_first, stream.t_first + int(self.flicker_sample_s * 1e9))
            self.flickering = flicker_mask(sample) & ~self.hot
        self.mask = self.hot | self.flickering
        return self

    @classmethod
    def from_stream(cls, stream: EventStream, **kw) -> NoiseModel:
        return cls(stream.width, stream.height, **kw).update(stream)
