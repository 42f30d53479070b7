"""Vectorized decoders and encoders for the event encodings of ``event_camera_msgs/msg/EventPacket``.

Layouts follow ros-event-camera's event_camera_codecs (studied, not copied):

``libcaer_cmp`` (DAVIS, 16-bit little-endian words, code in the top 4 bits)
    0 TIME_HIGH (bits 12..23 of the µs offset), 1 TIME_LOW (bits 0..11), 2 ADDR_X (x: 11 bits),
    3 ADDR_Y (y: 11 bits, polarity bit 11) -> one event at the current x and time,
    4 VECT_BASE_Y (y, polarity), 5 VECT_8 (8 valid bits: events at base_y + i, then base_y += 8).
    The time state starts at zero in every packet; event time = ``time_base`` (ns) + offset_us * 1000.
    (The current upstream decoder multiplies ``time_base`` by its time multiplier as well; recorded files,
    e.g. the DAVIS346 sample, carry ``time_base`` in ns with offsets in µs, so that is what is decoded.)
``libcaer`` (8-byte libcaer polarity events)
    uint32 data (x = bits 17..31, y = bits 2..16, polarity bit 1), int32 µs timestamp that rolls over at 2**31;
    event time = ``time_base`` + ts_us * 1000, rollovers inside a packet counted.
``evt3`` (Prophesee EVT 3.0, 16-bit words)
    0 ADDR_Y (y), 2 ADDR_X (x, polarity) -> event, 3 VECT_BASE_X, 4 VECT_12, 5 VECT_8, 6 TIME_LOW,
    8 TIME_HIGH, 10 EXT_TRIGGER, 14 OTHERS, 7/15 CONTINUED. Sensor time in µs with 24 bits; TIME_HIGH going
    backwards by more than 10 steps is a rollover (+2**24 µs). State (time, y, vector base) carries over from
    packet to packet, and nothing is decoded before the first TIME_HIGH followed by a TIME_LOW.
    The time is the sensor's clock, not the host clock; see :class:`Evt3Decoder`.
``mono`` (8-byte words)
    bits 0..31 time offset (ns) from ``time_base``, 32..47 x, 48..62 y, 63 polarity.
``evt2`` (Prophesee EVT 2.0, 32-bit little-endian words, type in the top 4 bits; Metavision ``.raw`` files)
    0 CD_OFF / 1 CD_ON (bits 22..27 time LSBs, 11..21 x, 0..10 y), 8 EV_TIME_HIGH (bits 0..27: time >> 6),
    10 EXT_TRIGGER, 14 OTHERS, 15 CONTINUED. Sensor time in µs with 34 bits; nothing is decoded before the
    first EV_TIME_HIGH. Not an EventPacket encoding: only :mod:`plsgraph.io.prophesee` uses it.

All decoders work on whole packets with numpy (no Python loop over words or events) and return
``(t_ns int64, x uint16, y uint16, p int8 in {+1, -1})``. Events outside the sensor are dropped and counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import RecordingError

SUPPORTED_ENCODINGS = ("libcaer_cmp", "libcaer", "evt3", "mono")

_EMPTY_T = np.zeros(0, np.int64)
_EMPTY_U16 = np.zeros(0, np.uint16)
_EMPTY_I8 = np.zeros(0, np.int8)


@dataclass
class DecodeStats:
    """What a decoder saw besides events: dropped events, unknown word codes, triggers."""

    outside_sensor: int = 0
    unknown_codes: int = 0
    triggers: int = 0
    odd_bytes: int = 0
    before_time: int = 0  # events before the first time word (no valid time yet), dropped
    time_backwards: int = 0  # time words stepping back without being a rollover (damage or jitter)


def _state_at(mask: np.ndarray, values: np.ndarray, default: int, at: np.ndarray) -> np.ndarray:
    """Value of the last state word (``mask``) at or before each position in ``at``; ``default`` before any.

    ``values`` holds the values of the masked words in order. A running count of state words indexes a
    table [default, v0, v1, ...], which is cheaper than forward-filling every word.
    """
    table = np.empty(values.size + 1, np.int64)
    table[0] = default
    table[1:] = values
    if at.size * 8 < mask.size:  # few positions (vector words): the count by bisection, not over every word
        return table[np.searchsorted(np.flatnonzero(mask), at, side="right")]
    return table[np.cumsum(mask, dtype=np.int32 if mask.size < 2**31 else np.int64)[at]]


class _StateAtWords:
    """``state_at(mask, values, default)``: :func:`_state_at` (mask, values, default, at) where ``at`` are the
    positions of one kind of word (``is_at``; e.g. EVT3's x addresses, one per event), the same numbers with less
    work on long packets. One running count of the ``at`` words serves every state, and each state's values are
    repeated over the runs of ``at`` words between its state words, instead of being looked up through a running
    count of each state's own words. ``dtype``: the values' type (small ones are copied faster)."""

    def __init__(self, is_at: np.ndarray, at: np.ndarray):
        self.is_at = is_at
        self.at = at
        self._count: np.ndarray | None = None  # the running count of at-words, made on first use

    def __call__(self, mask: np.ndarray, values: np.ndarray, default: int, dtype=np.int64,
                 where: np.ndarray | None = None) -> np.ndarray:
        """The state at every at-word; ``where``: np.flatnonzero(mask), when the caller has it."""
        where = np.flatnonzero(mask) if where is None else where
        table = np.empty(where.size + 1, dtype)
        table[0] = default
        table[1:] = values
        if where.size == 0:
            return np.repeat(table, self.at.size)
        if where.size * 64 < mask.size:  # a rare state word (time high): bisection over the at-words is cheaper
            before = np.searchsorted(self.at, where)
        else:
            if self._count is None:
                self._count = np.cumsum(self.is_at, dtype=np.int32 if mask.size < 2**31 else np.int64)
            before = self._count[where]  # at-words up to each state word, i.e. before it (it is not one of them)
        runs = np.empty(where.size + 1, np.int64)  # at-words before the first state word, between two, after the last
        runs[0] = before[0]
        np.subtract(before[1:], before[:-1], out=runs[1:-1])
        runs[-1] = self.at.size - before[-1]
        return np.repeat(table, runs)


def _masked(w: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``w[mask]``, the same values; np.extract is several times faster than boolean indexing on word arrays."""
    return np.extract(mask, w)


def _empty() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return _EMPTY_T, _EMPTY_U16, _EMPTY_U16, _EMPTY_I8


def _whole_records(blob, size: int, stats: DecodeStats) -> int:
    """Number of whole ``size``-byte records in ``blob``; a trailing partial record is counted as odd bytes."""
    stats.odd_bytes += len(blob) % size
    return len(blob) // size


def _words16(blob, stats: DecodeStats) -> np.ndarray:
    """The blob's whole little-endian 16-bit words as native uint16 (a read-only view where byte orders agree)."""
    n = _whole_records(blob, 2, stats)
    w = np.frombuffer(blob, dtype="<u2", count=n)
    return w if w.dtype == np.uint16 else w.astype(np.uint16)


def _vector_events(
    w: np.ndarray,
    code: np.ndarray,
    base_code: int,
    vect_codes: dict[int, int],
    base_state: int,
    pol_state: int,
    active: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Expand vector words (bitmasks of events along one axis) into (word index, coordinate, polarity).

    ``vect_codes`` maps a vector code to its number of valid bits; each vector word advances the base by
    its width, and a base word resets it. Returns also the base and polarity state after the packet.
    """
    is_base = code == base_code
    widths = np.zeros(w.size, np.int64)
    for c, wdt in vect_codes.items():
        widths[code == c] = wdt
    if active is not None:
        is_base &= active
        widths[~active] = 0
    vi = np.flatnonzero(widths)
    bases = _masked(w, is_base)
    base_vals = (bases & 0x7FF).astype(np.int64)
    pol_vals = ((bases >> 11) & 1).astype(np.int64)
    cw = np.cumsum(widths)  # total vector width up to and including each word
    ends = np.array([w.size - 1])
    at = np.concatenate([vi, ends])
    base_at = _state_at(is_base, base_vals, base_state, at)
    pol_at = _state_at(is_base, pol_vals, pol_state, at)
    # Width accumulated since the last base word: cw now minus cw at that base word.
    base_idx = np.flatnonzero(is_base)
    cw_at_base = _state_at(is_base, cw[base_idx], 0, at)
    end_base = int(base_at[-1] + cw[-1] - cw_at_base[-1])
    end_pol = int(pol_at[-1])
    if vi.size == 0:
        z = np.zeros(0, np.int64)
        return z, z, z, end_base, end_pol
    start = base_at[:-1] + cw[vi] - widths[vi] - cw_at_base[:-1]
    valid = (w[vi] & 0xFFF).astype(np.int64)
    valid &= np.where(widths[vi] == 8, 0xFF, 0xFFF)
    bits = (valid[:, None] >> np.arange(12)) & 1
    rows, cols = np.nonzero(bits)  # row-major: word order, then bit order, as a sequential decoder emits
    return vi[rows], start[rows] + cols, pol_at[:-1][rows], end_base, end_pol


def _finish(
    order_key: np.ndarray,
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    stats: DecodeStats,
    need_sort: bool,
):
    if need_sort:
        o = np.argsort(order_key, kind="stable")
        t, x, y, p = t[o], x[o], y[o], p[o]
    inside = (x < width) & (y < height) & (x >= 0) & (y >= 0)
    if not np.all(inside):
        stats.outside_sensor += int(np.count_nonzero(~inside))
        t, x, y, p = t[inside], x[inside], y[inside], p[inside]
    return (
        t.astype(np.int64, copy=False),
        x.astype(np.uint16),
        y.astype(np.uint16),
        np.where(p > 0, 1, -1).astype(np.int8),
    )


def finish_events(t, x, y, p, width: int, height: int, stats: DecodeStats):
    """Drop events outside the sensor (counted in ``stats``) and convert to the EventStream dtypes."""
    return _finish(None, np.asarray(t), np.asarray(x), np.asarray(y), np.asarray(p), width, height, stats, False)


@dataclass
class LibcaerCmpDecoder:
    """Stateful ``libcaer_cmp`` decoder (x address and vector base carry over between packets)."""

    width: int
    height: int
    ex: int = 0
    base_y: int = 0
    pol: int = 0
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, blob, time_base_ns: int):
        w = _words16(blob, self.stats)
        if w.size == 0:
            return _empty()
        code = w >> 12
        counts = np.bincount(code, minlength=16)
        self.stats.unknown_codes += int(counts[7:].sum())
        is_hi, is_lo, is_x = code == 0, code == 1, code == 2
        x_vals = (_masked(w, is_x) & 0x7FF).astype(np.int64)
        ex0 = self.ex
        if x_vals.size:
            self.ex = int(x_vals[-1])
        is_y = code == 3
        iy = np.flatnonzero(is_y)
        has_vect = counts[4] or counts[5]
        if has_vect:
            vi, vy, vp, self.base_y, self.pol = _vector_events(w, code, 4, {5: 8}, self.base_y, self.pol, None)
            # The states at every word that makes events (y addresses and vectors, in word order) by runs, then
            # split into the y words' and the vectors' (the order the events are put in below).
            is_ev = is_y | (code == 5)
            ev_at = np.flatnonzero(is_ev)
            state_at = _StateAtWords(is_ev, ev_at)
            of_y = is_y[ev_at]
        else:
            state_at = _StateAtWords(is_y, iy)
        # The time state restarts at zero in every packet; x carries over from the previous one.
        t_us = state_at(is_hi, (_masked(w, is_hi) & 0xFFF).astype(np.int64) << 12, 0) | state_at(
            is_lo, _masked(w, is_lo) & 0xFFF, 0, np.uint16
        )
        xs = state_at(is_x, x_vals, ex0)
        if has_vect:
            # A vector word makes one event per set bit (vi holds its word index once for each, in word order).
            k = np.searchsorted(ev_at[~of_y], vi)
            t_us = np.concatenate([t_us[of_y], t_us[~of_y][k]])
            xs = np.concatenate([xs[of_y], xs[~of_y][k]])
        t_ns = int(time_base_ns) + t_us * 1000
        wy = w[iy]
        y1 = (wy & 0x7FF).astype(np.int64)
        p1 = ((wy >> 11) & 1).astype(np.int64)
        if not has_vect:
            return _finish(None, t_ns, xs, y1, p1, self.width, self.height, self.stats, False)
        return _finish(
            np.concatenate([iy * 16, vi * 16 + 1]),
            t_ns,
            xs,
            np.concatenate([y1, vy]),
            np.concatenate([p1, vp]),
            self.width,
            self.height,
            self.stats,
            True,
        )


@dataclass
class LibcaerDecoder:
    """``libcaer`` polarity events (8 bytes each); stateless between packets like the reference."""

    width: int
    height: int
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, blob, time_base_ns: int):
        n = _whole_records(blob, 8, self.stats)
        if n == 0:
            return _empty()
        a = np.frombuffer(blob, dtype=np.dtype([("d", "<u4"), ("ts", "<i4")]), count=n)
        d = a["d"].astype(np.int64)
        ts = a["ts"].astype(np.int64)
        # A later timestamp smaller than its predecessor means the 31-bit µs counter wrapped.
        wraps = np.concatenate([[0], np.cumsum(np.diff(ts) < 0)])
        t_ns = int(time_base_ns) + (ts + (wraps << 31)) * 1000
        return _finish(
            None, t_ns, (d >> 17) & 0x7FFF, (d >> 2) & 0x7FFF, (d >> 1) & 1, self.width, self.height, self.stats, False
        )


@dataclass
class MonoDecoder:
    """``mono`` 8-byte events: ns offset from ``time_base``."""

    width: int
    height: int
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, blob, time_base_ns: int):
        n = _whole_records(blob, 8, self.stats)
        if n == 0:
            return _empty()
        q = np.frombuffer(blob, dtype="<u8", count=n)
        t_ns = int(time_base_ns) + (q & np.uint64(0xFFFFFFFF)).astype(np.int64)
        x = ((q >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.int64)
        y = ((q >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.int64)
        p = (q >> np.uint64(63)).astype(np.int64)
        return _finish(None, t_ns, x, y, p, self.width, self.height, self.stats, False)


@dataclass
class Evt3Decoder:
    """Stateful EVT 3.0 decoder. Returns sensor time in ns (µs resolution) since the sensor's clock origin."""

    width: int
    height: int
    time_high: int = 0  # rollover bits and the last TIME_HIGH, as (rollovers << 24) | (high << 12)
    time_low: int = 0
    valid: bool = False
    ey: int = 0
    base_x: int = 0
    pol: int = 0
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, blob, time_base_ns: int = 0):
        w = _words16(blob, self.stats)
        if w.size == 0:
            return _empty()
        code = w >> 12
        is_hi = code == 8
        is_lo = code == 6
        start = 0
        if not self.valid:
            hi_idx = np.flatnonzero(is_hi)
            lo_after = np.flatnonzero(is_lo[hi_idx[0] :]) if hi_idx.size else hi_idx
            if lo_after.size == 0:
                # No valid time yet: only the time words count, and their state carries to the next packet.
                self._advance_time(w, is_hi, is_lo, np.zeros(0, np.int64))
                return _empty()
            start = int(hi_idx[0] + lo_after[0] + 1)
            self.valid = True
        is_y = code == 0
        is_x = code == 2
        if start:
            is_y[:start] = False  # words before the first valid time are skipped, as the reference does
            is_x[:start] = False
        # Events, addresses and time words are nearly all of a packet: the other codes are counted (unknown words,
        # triggers, vectors) only when there are any.
        n_common = sum(int(np.count_nonzero(m[start:])) for m in (is_y, is_x, is_lo, is_hi))
        has_vect = False
        if n_common < w.size - start:
            counts = np.bincount(code[start:], minlength=16)
            self.stats.unknown_codes += int(counts[[1, 9, 11, 12, 13]].sum())
            self.stats.triggers += int(counts[10])
            has_vect = bool(counts[4] or counts[5])
            if counts[3] and not has_vect:
                # A vector base without vectors (they follow in the next packet): it is the state they start from.
                last = int(w[start + np.flatnonzero(code[start:] == 3)[-1]])
                self.base_x, self.pol = last & 0x7FF, (last >> 11) & 1
        ix = np.flatnonzero(is_x)
        if has_vect:
            active = np.arange(w.size) >= start
            vi, vx, vp, self.base_x, self.pol = _vector_events(w, code, 3, {4: 12, 5: 8}, self.base_x, self.pol, active)
            at = np.concatenate([ix, vi])
        else:
            at = ix
        low_before = self.time_low
        if has_vect:
            state_at = lambda mask, values, default, dtype=np.int64: _state_at(mask, values, default, at)  # noqa: E731
        else:  # the events are the x words: their states (time, y) come cheaper by runs (the same numbers)
            state_at = _StateAtWords(is_x, ix)
        il = None if has_vect else np.flatnonzero(is_lo)
        hi_at = self._advance_time(w, is_hi, is_lo, at, state_at, il)
        if has_vect:
            t_ns = (hi_at | state_at(is_lo, _masked(w, is_lo) & 0xFFF, low_before)) * 1000
            y_vals = _masked(w, is_y) & 0x7FF
            ys = state_at(is_y, y_vals, self.ey)
        else:  # the state words' positions once, for their values and their runs
            iy = np.flatnonzero(is_y)
            t_ns = (hi_at | state_at(is_lo, w[il] & 0xFFF, low_before, np.uint16, where=il)) * 1000
            y_vals = w[iy] & 0x7FF
            ys = state_at(is_y, y_vals, self.ey, np.uint16, where=iy)
        if y_vals.size:
            self.ey = int(y_vals[-1])
        wx = w[ix]
        if not has_vect:
            # Addresses are 11-bit (never negative): only the sensor's far edges bound them.
            x1 = wx & 0x7FF
            inside = (x1 < self.width) & (ys < self.height)
            p1 = ((wx >> 10) & 2).astype(np.int8) - 1  # polarity bit 11 -> +1 / -1
            if not inside.all():
                self.stats.outside_sensor += int(inside.size - np.count_nonzero(inside))
                t_ns, x1, ys, p1 = t_ns[inside], x1[inside], ys[inside], p1[inside]
            return t_ns, x1.astype(np.uint16, copy=False), ys.astype(np.uint16, copy=False), p1
        x1 = (wx & 0x7FF).astype(np.int64)
        p1 = ((wx >> 11) & 1).astype(np.int64)
        return _finish(
            np.concatenate([ix * 16, vi * 16 + 1]),
            t_ns,
            np.concatenate([x1, vx]),
            ys,
            np.concatenate([p1, vp]),
            self.width,
            self.height,
            self.stats,
            True,
        )

    def _advance_time(self, w: np.ndarray, is_hi: np.ndarray, is_lo: np.ndarray, at: np.ndarray,
                      state_at=None, lo_idx: np.ndarray | None = None) -> np.ndarray:
        """High time bits (with rollovers) at positions ``at``; updates the carried time state. ``state_at(mask,
        values, default)``: :func:`_state_at` at ``at`` (or what gives the same); ``lo_idx``: the time-low words'
        positions (np.flatnonzero(is_lo)) when the caller has them."""
        h = (_masked(w, is_hi) & 0xFFF).astype(np.int64)
        if h.size:
            prev = np.empty_like(h)
            prev[0] = (self.time_high >> 12) & 0xFFF
            prev[1:] = h[:-1]
            # A high time stepping back by more than 10 is a rollover; small steps back are jitter.
            rolls = (self.time_high >> 24) + np.cumsum((h < prev) & (prev - h > 10))
            full = (rolls << 24) | (h << 12)
            hi_at = _state_at(is_hi, full, self.time_high, at) if state_at is None else \
                state_at(is_hi, full, self.time_high)
            self.time_high = int(full[-1])
        else:
            hi_at = np.full(at.size, self.time_high, np.int64)
        if lo_idx is None:
            lo_idx = np.flatnonzero(is_lo)
        if lo_idx.size:
            self.time_low = int(w[lo_idx[-1]] & 0xFFF)
        return hi_at


@dataclass
class Evt2Decoder:
    """Stateful EVT 2.0 decoder (32-bit words). Returns sensor time in ns (µs resolution).

    The time-high state carries over between blocks. A time-high word below its predecessor is a rollover
    of the 28-bit counter only when the step back is more than half the range; a smaller step back cannot
    be a rollover (damage, or words out of order) and is counted instead.
    """

    width: int
    height: int
    time_high: int = -1  # (rollovers << 28) | last EV_TIME_HIGH; -1 before the first one
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, blob, time_base_ns: int = 0):
        n = _whole_records(blob, 4, self.stats)
        if n == 0:
            return _empty()
        w = np.frombuffer(blob, dtype="<u4", count=n)
        typ = (w >> 28).astype(np.uint8)
        is_hi = typ == 8
        is_cd = typ <= 1
        n_cd = int(np.count_nonzero(is_cd))
        if n_cd + int(np.count_nonzero(is_hi)) < n:  # other words than events and time: count them
            counts = np.bincount(typ, minlength=16)
            self.stats.triggers += int(counts[10])
            self.stats.unknown_codes += int(counts[[2, 3, 4, 5, 6, 7, 9, 11, 12, 13]].sum())
        cd = np.flatnonzero(is_cd)
        h = (_masked(w, is_hi) & 0x0FFFFFFF).astype(np.int64)
        hi_at = np.full(cd.size, self.time_high, np.int64)
        if h.size:
            prev = np.empty_like(h)
            prev[0] = self.time_high & 0x0FFFFFFF if self.time_high >= 0 else h[0]
            prev[1:] = h[:-1]
            step_back = h < prev
            roll = step_back & (prev - h > 1 << 27)
            self.stats.time_backwards += int(np.count_nonzero(step_back & ~roll))
            base = (self.time_high >> 28) if self.time_high >= 0 else 0
            full = ((base + np.cumsum(roll)) << 28) | h
            hi_at = _state_at(is_hi, full, self.time_high, cd)
            self.time_high = int(full[-1])
        valid = hi_at >= 0
        if not np.all(valid):
            self.stats.before_time += int(np.count_nonzero(~valid))
            cd, hi_at = cd[valid], hi_at[valid]
        wc = w[cd]
        t_ns = ((hi_at << 6) | ((wc >> 22) & 0x3F).astype(np.int64)) * 1000
        # 11-bit addresses (never negative): only the sensor's far edges bound them; the type is the polarity.
        x = ((wc >> 11) & 0x7FF).astype(np.uint16)
        y = (wc & 0x7FF).astype(np.uint16)
        p = typ[cd].astype(np.int8) * 2 - 1
        inside = (x < self.width) & (y < self.height)
        if not inside.all():
            self.stats.outside_sensor += int(inside.size - np.count_nonzero(inside))
            t_ns, x, y, p = t_ns[inside], x[inside], y[inside], p[inside]
        return t_ns, x, y, p


def make_decoder(encoding: str, width: int, height: int):
    """Decoder object for an EventPacket ``encoding``; raises RecordingError for an unknown one."""
    enc = encoding.strip().lower()
    if enc == "libcaer_cmp":
        return LibcaerCmpDecoder(width, height)
    if enc == "libcaer":
        return LibcaerDecoder(width, height)
    if enc == "evt3":
        return Evt3Decoder(width, height)
    if enc == "mono":
        return MonoDecoder(width, height)
    raise RecordingError(
        f"event packets use the encoding {encoding!r}, which plsgraph cannot decode; "
        f"supported: {', '.join(SUPPORTED_ENCODINGS)}. Convert the recording (e.g. with event_camera_tools)."
    )


# ----------------------------------------------------------------------------------------------- encoders


def _interleave(counts: np.ndarray, columns: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Lay out per-event optional words: ``columns`` are (present mask, word) in emission order."""
    total = int(counts.sum())
    out = np.empty(total, np.uint16)
    pos = np.cumsum(counts) - counts  # first word of each event
    for present, word in columns:
        out[pos[present]] = word[present]
        pos = pos + present
    return out


def encode_libcaer_cmp(t_offset_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> bytes:
    """One ``libcaer_cmp`` packet; ``t_offset_us`` (µs after the packet's time_base) must be < 2**24."""
    t = np.asarray(t_offset_us, np.int64)
    n = t.size
    if n == 0:
        return b""
    if t.min() < 0 or t.max() >= 1 << 24 or np.any(np.diff(t) < 0):
        raise RecordingError("libcaer_cmp: packet offsets must be sorted and within [0, 2**24) µs")
    x = np.asarray(x, np.int64)
    y = np.asarray(y, np.int64)
    pol = (np.asarray(p) > 0).astype(np.int64)
    hi, lo = t >> 12, t & 0xFFF
    first = np.zeros(n, bool)
    first[0] = True
    new_hi = first | np.concatenate([[False], hi[1:] != hi[:-1]])
    new_lo = new_hi | np.concatenate([[False], lo[1:] != lo[:-1]])
    new_x = first | np.concatenate([[False], x[1:] != x[:-1]])
    always = np.ones(n, bool)
    counts = new_hi.astype(np.int64) + new_lo + new_x + 1
    words = _interleave(
        counts,
        [
            (new_hi, (0 << 12) | hi),
            (new_lo, (1 << 12) | lo),
            (new_x, (2 << 12) | x),
            (always, (3 << 12) | (pol << 11) | y),
        ],
    )
    return words.astype("<u2").tobytes()


def encode_evt3(
    t_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, prev_high: int | None = None
) -> tuple[bytes, int]:
    """EVT 3.0 words for events at absolute sensor times ``t_us`` (µs, may exceed 2**24: wraps like hardware).

    Like a sensor, a TIME_HIGH word is written for every 4096 µs period between events (so a decoder sees
    each rollover). ``prev_high`` is the absolute high period (t_us >> 12) last written by the previous
    packet; returns the bytes and the new ``prev_high``.
    """
    t = np.asarray(t_us, np.int64)
    n = t.size
    if n == 0:
        return b"", -1 if prev_high is None else prev_high
    if t.min() < 0 or np.any(np.diff(t) < 0):
        raise RecordingError("evt3: event times must be non-negative and sorted")
    x = np.asarray(x, np.int64)
    y = np.asarray(y, np.int64)
    pol = (np.asarray(p) > 0).astype(np.int64)
    hi = t >> 12
    before = np.concatenate([[hi[0] - 1 if prev_high is None or prev_high < 0 else prev_high], hi[:-1]])
    if prev_high is not None and prev_high > hi[0]:
        raise RecordingError("evt3: packet starts before the previous one ended")
    n_hi = hi - before  # TIME_HIGH words before each event (0 if same period)
    lo = t & 0xFFF
    first = np.zeros(n, bool)
    first[0] = True
    new_lo = first | (n_hi > 0) | np.concatenate([[False], lo[1:] != lo[:-1]])
    new_y = first | np.concatenate([[False], y[1:] != y[:-1]])
    counts = n_hi + new_lo + new_y + 1
    total = int(counts.sum())
    out = np.empty(total, np.uint16)
    start = np.cumsum(counts) - counts
    # High words: event i owns n_hi[i] of them at start[i] .. start[i] + n_hi[i] - 1, periods before[i]+1 ..
    owner = np.repeat(np.arange(n), n_hi)
    k = np.arange(owner.size) - np.repeat(np.cumsum(n_hi) - n_hi, n_hi)
    out[start[owner] + k] = (8 << 12) | ((before[owner] + 1 + k) & 0xFFF)
    pos = start + n_hi
    for present, word in (
        (new_lo, (6 << 12) | lo),
        (new_y, (0 << 12) | y),
        (np.ones(n, bool), (2 << 12) | (pol << 11) | x),
    ):
        out[pos[present]] = word[present]
        pos = pos + present
    return out.astype("<u2").tobytes(), int(hi[-1])


def encode_evt2(
    t_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, prev_high: int = -1
) -> tuple[bytes, int]:
    """EVT 2.0 words for events at sensor times ``t_us`` (µs, sorted, below 2**34): an EV_TIME_HIGH word
    whenever ``t_us >> 6`` changes (like a sensor, at least one per 64 µs period that holds events).
    ``prev_high`` is the last time-high value written before; returns the bytes and the new value."""
    t = np.asarray(t_us, np.int64)
    n = t.size
    if n == 0:
        return b"", prev_high
    if t.min() < 0 or t.max() >= 1 << 34 or np.any(np.diff(t) < 0):
        raise RecordingError("evt2: event times must be sorted and within [0, 2**34) µs")
    hi = t >> 6
    new_hi = np.concatenate([[hi[0] != prev_high], hi[1:] != hi[:-1]])
    counts = new_hi.astype(np.int64) + 1
    cd = (
        ((np.asarray(p) > 0).astype(np.int64) << 28)
        | ((t & 0x3F) << 22)
        | (np.asarray(x, np.int64) << 11)
        | np.asarray(y, np.int64)
    )
    total = int(counts.sum())
    out = np.empty(total, np.uint32)
    pos = np.cumsum(counts) - counts
    out[pos[new_hi]] = (8 << 28) | (hi[new_hi] & 0x0FFFFFFF)
    out[pos + new_hi] = cd
    return out.astype("<u4").tobytes(), int(hi[-1])


def encode_libcaer(t_offset_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> bytes:
    """``libcaer`` polarity events (8 bytes each); offsets in µs from the packet's time_base, wrapping at 2**31."""
    t = np.asarray(t_offset_us, np.int64)
    if t.size and (t.min() < 0 or np.any(np.diff(t) < 0) or t.max() - t.min() >= 1 << 31):
        raise RecordingError("libcaer: packet offsets must be sorted, non-negative and span less than 2**31 µs")
    d = (np.asarray(x, np.int64) << 17) | (np.asarray(y, np.int64) << 2) | ((np.asarray(p) > 0).astype(np.int64) << 1)
    a = np.empty(t.size, dtype=np.dtype([("d", "<u4"), ("ts", "<i4")]))
    a["d"] = d | 1  # bit 0: libcaer's "valid" flag
    a["ts"] = t & 0x7FFFFFFF
    return a.tobytes()


def encode_mono(t_offset_ns: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> bytes:
    """``mono`` 8-byte events; offsets in ns from the packet's time_base must be < 2**32."""
    t = np.asarray(t_offset_ns, np.int64)
    if t.size and (t.min() < 0 or t.max() >= 1 << 32):
        raise RecordingError("mono: packet offsets must lie in [0, 2**32) ns")
    q = (
        t.astype(np.uint64)
        | (np.asarray(x, np.uint64) << np.uint64(32))
        | (np.asarray(y, np.uint64) << np.uint64(48))
        | ((np.asarray(p) > 0).astype(np.uint64) << np.uint64(63))
    )
    return q.astype("<u8").tobytes()
