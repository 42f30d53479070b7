"""Sensor noise the detectors should not see: hot pixels and pixels flickering with the lights.

A hot pixel fires on its own, at a steady rate (tens to thousands of events per second), whatever the scene
does. In a count image it is a single bright point that can outshine a whole circle, and in the blob detector a
false candidate. It is told apart from scene activity by two things together: it fires far more than the pixels
around it (a moving edge, a rim or a texture lights up at least two of its neighbours as well), and it fires all
the time (an edge passes a pixel and moves on). Both are measured on each streamed span, so a pixel that turns
hot or stops being hot is followed, and memory follows the span.

Lamps on AC mains flicker at twice the mains frequency (100 Hz on 50 Hz grids, 120 Hz on 60 Hz ones); pixels
that see them, or the bright surfaces they light, fire in step with it, in clusters as large as the lit area, so
the hot-pixel test (which wants a pixel busier than its neighbours) misses them. What gives them away is their
timing: a flickering pixel's events of one polarity fall at one phase of the flicker period, cycle after cycle,
while an edge that passes makes bursts at whatever phases the motion gives. :func:`flicker_mask` measures, per
pixel and polarity, how strongly the events lock to the phase of each mains harmonic (the length of the mean of
their phase vectors), and takes the pixels that lock strongly, over enough events, in every part of the span.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..core.events import EventStream

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
    blocks = _blocks(len(stream))
    counts = np.zeros(h * w, dtype=np.int64)
    for a, b in blocks:
        counts += np.bincount(_pixels(stream, a, b), minlength=h * w)
    counts = counts.astype(np.float32).reshape(h, w)
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
    edges = np.linspace(int(stream.t_first), int(stream.t_last) + 1, segments + 1)
    seen = np.zeros((h * w, segments), dtype=bool)
    for a, b in blocks:
        pix = _pixels(stream, a, b)
        sel = cand.ravel()[pix]
        if not sel.any():
            continue
        part = np.clip(np.searchsorted(edges, stream.t[a:b][sel], side="right") - 1, 0, segments - 1)
        seen[pix[sel], part] = True
    mask.ravel()[:] = seen.all(axis=1)
    return mask


#: Events handled at once by the noise tests (hot pixels, flicker, dropping pixels): their temporaries stay a few
#: megabytes, reused by the allocator, however long the span. Whole-span temporaries (a dozen arrays of 10-15 M events
#: on a busy span) made the kernel map and zero a gigabyte of fresh memory per span, which took longer than the
#: arithmetic.
NOISE_BLOCK_EVENTS = 1 << 20


def _blocks(n: int) -> list[tuple[int, int]]:
    return [(a, min(a + NOISE_BLOCK_EVENTS, n)) for a in range(0, n, NOISE_BLOCK_EVENTS)]


def _pixels(stream: EventStream, a: int, b: int) -> np.ndarray:
    """:func:`.surfaces.pixel_index` of the events a..b."""
    pix = np.multiply(stream.y[a:b], stream.width, dtype=np.intp, casting="unsafe")
    np.add(pix, stream.x[a:b], out=pix, casting="unsafe")
    return pix


#: Flicker frequencies looked for (Hz): twice the 50 and 60 Hz mains.
FLICKER_HZ = (100.0, 120.0)
#: A flickering pixel's events of one polarity lock to the flicker's phase: their mean phase vector is at least this
#: long (0..1; 0.9 and more on simulated lamps) ...
FLICKER_LOCKING = 0.5
#: ... and its length r over N events passes the Rayleigh test: N r^2 at least this. Events at random phases give
#: N r^2 about 1, and exceed 12 with probability exp(-12) = 6e-6.
FLICKER_RAYLEIGH = 12.0
#: Fewest events of one polarity for a pixel to be judged.
FLICKER_MIN_EVENTS = 10
#: The phase sums take the steady pixels' events out of each block when they are fewer than this share of the span's
#: events, and every event otherwise (the same sums; see flicker_events).
FLICKER_PICK_SHARE = 0.5
#: Events of a flickering pixel and polarity within this phase (rad) of its mean phase are taken for flicker.
FLICKER_GATE_RAD = np.pi / 3


def flicker_events(stream: EventStream, freqs_hz: tuple[float, ...] = FLICKER_HZ, locking: float = FLICKER_LOCKING,
                   segments: int = HOT_SEGMENTS) -> tuple[np.ndarray, float | None, int]:
    """The events of ``stream`` that flicker with the lights (see the module's text): a bool per event, the flicker
    frequency (Hz; None when nothing flickers) and the number of flickering pixels.

    A pixel and polarity whose events lock to the flicker's phase loses only the events within
    ``FLICKER_GATE_RAD`` of that phase: an edge that passes a lamp-lit pixel fires at other phases too, and those
    events stay (two thirds of them, for an edge at a random phase).

    Cost: every event is touched a few times (its pixel and polarity, its part of the span, the phase sums), in
    blocks of :data:`NOISE_BLOCK_EVENTS`; the sums' cosines and sines in single precision of the phase within its
    cycle (reduced in double precision first; the mean phases move by less than 1e-6 rad, nothing next to the locking
    test's tolerance, though an event within that of the gate, or a pixel exactly at a threshold, can come out the
    other way than in double precision). The stream is in time order, so each part of the span is a slice of it."""
    n = len(stream)
    none = np.zeros(n, dtype=bool)
    if n == 0:
        return none, None, 0
    h, w = stream.height, stream.width
    t0 = int(stream.t_first)
    span_s = (int(stream.t_last) - t0) * 1e-9
    if span_s < HOT_MIN_SPAN_S:
        return none, None, 0
    n_keys = 2 * h * w
    t = np.asarray(stream.t)
    blocks = _blocks(n)
    # One key per pixel and polarity (one phase sum each), in int32: the only array as long as the span.
    key = np.empty(n, dtype=np.int32)
    counts = np.zeros(n_keys, dtype=np.int64)
    for a, b in blocks:
        kb = key[a:b]
        np.multiply(stream.y[a:b], w, out=kb, dtype=np.int32, casting="unsafe")
        np.add(kb, stream.x[a:b], out=kb, casting="unsafe")
        kb *= 2
        kb += np.asarray(stream.p[a:b]) > 0
        counts += np.bincount(kb, minlength=n_keys)
    judged = counts >= FLICKER_MIN_EVENTS
    if not judged.any():
        return none, None, 0
    # Persistence: events in every part of the span (a lamp flickers all the time; an edge passes).
    steady = judged.copy()
    edges = _part_edges(t, t0, span_s, segments)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        seen = np.zeros(n_keys, dtype=bool)
        for a in range(lo, hi, NOISE_BLOCK_EVENTS):
            seen[key[a:min(a + NOISE_BLOCK_EVENTS, hi)]] = True
        steady &= seen
    # Phase sums of the steady pixels (the others cannot lock), for every frequency in one pass over the events. When
    # most events are steady pixels' (a busy scene), every event goes into the sums: a key's sum is the same either
    # way (its own events, in their order), and picking the steady ones out would cost more than the few others.
    pick = int(counts[steady].sum()) < FLICKER_PICK_SHARE * n
    sums = np.zeros((len(freqs_hz), 2, n_keys))
    cyc = np.empty(min(n, NOISE_BLOCK_EVENTS))
    whole = np.empty_like(cyc)
    ang = np.empty(cyc.size, dtype=np.float32)
    for a, b in blocks:
        kb = key[a:b]
        if pick:
            idx = np.flatnonzero(steady[kb])
            if idx.size == 0:
                continue
            ks = kb[idx]
            d = t[a:b][idx] - t0
        else:
            ks, d = kb, t[a:b] - t0
        m = d.size
        c, fl, an = cyc[:m], whole[:m], ang[:m]
        for j, f in enumerate(freqs_hz):
            np.multiply(d, f * 1e-9, out=c)  # cycles of the flicker since the span's start
            np.floor(c, out=fl)
            c -= fl
            c *= 2.0 * np.pi
            an[...] = c
            sums[j, 0] += np.bincount(ks, np.cos(an), minlength=n_keys)
            sums[j, 1] += np.bincount(ks, np.sin(an), minlength=n_keys)
    best = (0, None, None, None)  # (pixels, frequency, locked keys, their mean phase)
    for j, f in enumerate(freqs_hz):
        c, s = sums[j]
        r = np.hypot(c, s) / np.maximum(counts, 1)
        locked = steady & (r >= locking) & (counts * r * r >= FLICKER_RAYLEIGH)
        n_pix = int(np.count_nonzero(locked.reshape(h * w, 2).any(axis=1)))
        if n_pix > best[0]:
            best = (n_pix, float(f), locked, np.arctan2(s, c))
    n_pix, f, locked, phase = best
    if not n_pix:
        return none, None, 0
    out = none.copy()
    for a, b in blocks:
        kb = key[a:b]
        on = np.flatnonzero(locked[kb])
        if on.size == 0:
            continue
        tt = (t[a:b][on] - t0).astype(np.float64) * 1e-9
        dphi = np.angle(np.exp(1j * ((2.0 * np.pi * f) * tt - phase[kb[on]])))
        out[a + on[np.abs(dphi) < FLICKER_GATE_RAD]] = True
    return out, f, n_pix


#: Most events :func:`flicker_census` tests: a longer stream is tested on the events of a sample of its pixels.
FLICKER_CENSUS_EVENTS = 500_000


def flicker_census(stream: EventStream, budget: int | None = None) -> tuple[float, float | None, int]:
    """How much of ``stream`` flickers with the lights, for the front end's report and warning (nothing is dropped):
    the share of its events :func:`flicker_events` flags, the flicker frequency (Hz; None when nothing flickers) and
    the number of flickering pixels.

    A stream of at most ``budget`` events (default :data:`FLICKER_CENSUS_EVENTS`) is tested whole. A longer one is
    tested on every event of about one pixel in k (k = events / budget, rounded up; the pixels picked by a
    multiplicative hash, spread over the image without a pattern a lit area could line up with). Each sampled pixel
    has all its events, so it is judged as in the whole test (its parts of the span and the span's length are the
    sample's, which spans the stream); the share is that of the sampled pixels' events and the pixel count is scaled
    up by the sample's size, an estimate. A lamp lighting fewer than about k pixels can go unseen: it carries too
    few of the events to matter to the warning. The test then costs one cheap pass over the events plus a fixed
    amount, instead of one that grows with the event rate (0.75 s of a processor for 10 s at 2 M events/s, beside
    the detector's workers)."""
    n = len(stream)
    budget = FLICKER_CENSUS_EVENTS if budget is None else int(budget)
    if n <= budget:
        flagged, hz, n_pix = flicker_events(stream)
        return (float(flagged.mean()) if n else 0.0), hz, n_pix
    h, w = stream.height, stream.width
    k = -(-n // max(budget, 1))
    ids = np.arange(h * w, dtype=np.uint64)
    picked = ((ids * np.uint64(2654435761)) & np.uint64(0xFFFFFFFF)) < np.uint64((1 << 32) // k)
    n_picked = int(np.count_nonzero(picked))
    if n_picked == 0:
        return 0.0, None, 0
    idx = np.concatenate([a + np.flatnonzero(picked[_pixels(stream, a, b)]) for a, b in _blocks(n)])
    sample = EventStream(stream.t[idx], stream.x[idx], stream.y[idx], stream.p[idx], w, h)
    if len(sample) == 0:
        return 0.0, None, 0
    flagged, hz, n_pix = flicker_events(sample)
    return float(flagged.mean()), hz, int(round(n_pix * (h * w) / n_picked))


def _part_edges(t: np.ndarray, t0: int, span_s: float, segments: int) -> list[int]:
    """Indices into the sorted times ``t`` where each of ``segments`` equal parts of the span (from ``t0``) starts, and
    the end: an event at ``t0 + d`` ns is in part min(int(d 1e-9 * segments / span_s), segments - 1)."""
    scale = segments / max(span_s, 1e-9)
    edges = [0]
    for part in range(1, segments):
        d = int(np.ceil(part / scale * 1e9))  # the first offset of the part, to within rounding
        while d > 0 and int(float(d - 1) * 1e-9 * scale) >= part:
            d -= 1
        while int(float(d) * 1e-9 * scale) < part:
            d += 1
        edges.append(int(np.searchsorted(t, t0 + d, side="left")))
    edges.append(t.size)
    return edges


def drop_events(stream: EventStream, drop: np.ndarray) -> EventStream:
    """``stream`` without the events set in ``drop`` (one bool per event); the stream itself if none."""
    if not drop.any():
        return stream
    keep = ~drop
    return EventStream(stream.t[keep], stream.x[keep], stream.y[keep], stream.p[keep], stream.width, stream.height)


def drop_pixels(stream: EventStream, mask: np.ndarray) -> EventStream:
    """``stream`` without the events of the pixels set in ``mask`` (height, width); the stream itself if none."""
    if not mask.any() or len(stream) == 0:
        return stream
    keep = np.empty(len(stream), dtype=bool)
    bad = mask.ravel()
    for a, b in _blocks(len(stream)):
        np.logical_not(bad[_pixels(stream, a, b)], out=keep[a:b])
    return EventStream(stream.t[keep], stream.x[keep], stream.y[keep], stream.p[keep], stream.width, stream.height)
