"""Sensor noise the detectors should not see: hot pixels.

A hot pixel fires on its own, at a steady rate (tens to thousands of events per second), whatever the scene
does. In a count image it is a single bright point that can outshine a whole circle, and in the blob detector a
false candidate. It is told apart from scene activity by two things together: it fires far more than the pixels
around it (a moving edge, a rim or a texture lights up at least two of its neighbours as well), and it fires all
the time (an edge passes a pixel and moves on). Both are measured on each streamed span, so a pixel that turns
hot or stops being hot is followed, and memory follows the span.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..core.events import EventStream
from .surfaces import pixel_index

#: Lowest event rate (Hz) of a pixel called hot: well above background activity (0.1-2 Hz per pixel).
HOT_MIN_RATE_HZ = 20.0
#: A hot pixel fires at least this many times as often as the second busiest of its 8 neighbours (plus one).
HOT_FACTOR = 5.0
#: ... and has events in every one of this many equal parts of the span.
HOT_SEGMENTS = 4
#: Spans shorter than this (s) are too short to tell a hot pixel from a passing edge: nothing is masked.
HOT_MIN_SPAN_S = 0.5


def hot_pixel_mask(stream: EventStream, min_rate_hz: float = HOT_MIN_RATE_HZ, factor: float = HOT_FACTOR,
                   segments: int = HOT_SEGMENTS) -> np.ndarray:
    """(height, width) bool: the pixels of ``stream`` that fire like hot pixels (see the module's text)."""
    h, w = stream.height, stream.width
    mask = np.zeros((h, w), dtype=bool)
    if len(stream) == 0:
        return mask
    span_s = (int(stream.t_last) - int(stream.t_first)) * 1e-9
    if span_s < HOT_MIN_SPAN_S:
        return mask
    pix = pixel_index(stream)
    counts = np.bincount(pix, minlength=h * w).astype(np.float32).reshape(h, w)
    # The second busiest of the 8 neighbours: a rim or a line has two busy neighbours at least, a hot pixel none
    # (or one, when two hot pixels touch).
    pad = cv2.copyMakeBorder(counts, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0.0)
    ring = np.stack([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                     if dy or dx], axis=-1)
    second = np.partition(ring, 6, axis=-1)[..., 6]
    cand = (counts >= min_rate_hz * span_s) & (counts > factor * (second + 1.0))
    if not cand.any():
        return mask
    # Persistence: events in every part of the span.
    sel = cand.ravel()[pix]
    edges = np.linspace(int(stream.t_first), int(stream.t_last) + 1, segments + 1)
    part = np.clip(np.searchsorted(edges, stream.t[sel], side="right") - 1, 0, segments - 1)
    seen = np.zeros((h * w, segments), dtype=bool)
    seen[pix[sel], part] = True
    mask.ravel()[:] = seen.all(axis=1)
    return mask


def drop_pixels(stream: EventStream, mask: np.ndarray) -> EventStream:
    """``stream`` without the events of the pixels set in ``mask`` (height, width); the stream itself if none."""
    if not mask.any() or len(stream) == 0:
        return stream
    keep = ~mask.ravel()[pixel_index(stream)]
    return EventStream(stream.t[keep], stream.x[keep], stream.y[keep], stream.p[keep], stream.width, stream.height)
