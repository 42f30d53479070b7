"""Vectorized event codecs against deliberately slow word-by-word reference decoders, on random word streams."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.errors import RecordingError
from plsgraph.io.event_codecs import (
    Evt2Decoder,
    Evt3Decoder,
    LibcaerCmpDecoder,
    LibcaerDecoder,
    MonoDecoder,
    encode_evt3,
    encode_libcaer_cmp,
    make_decoder,
)


def _as_arrays(events):
    a = np.array(events, dtype=np.int64).reshape(-1, 4)
    return a[:, 0], a[:, 1], a[:, 2], a[:, 3]


def _check(out, ref):
    t, x, y, p = out
    rt, rx, ry, rp = _as_arrays(ref)
    np.testing.assert_array_equal(t, rt)
    np.testing.assert_array_equal(x, rx)
    np.testing.assert_array_equal(y, ry)
    np.testing.assert_array_equal(p, rp)


class SlowCmp:
    """libcaer_cmp, one word at a time; x and vector state persist across packets, time does not."""

    def __init__(self, w, h):
        self.w, self.h, self.ex, self.by, self.pol = w, h, 0, 0, 0

    def decode(self, words, tb):
        out, hi, lo = [], 0, 0
        for wd in words:
            c = wd >> 12
            if c == 0:
                hi = (wd & 0xFFF) << 12
            elif c == 1:
                lo = wd & 0xFFF
            elif c == 2:
                self.ex = wd & 0x7FF
            elif c == 3:
                y = wd & 0x7FF
                if self.ex < self.w and y < self.h:
                    out.append((tb + (hi | lo) * 1000, self.ex, y, 1 if wd & 0x800 else -1))
            elif c == 4:
                self.by, self.pol = wd & 0x7FF, (wd >> 11) & 1
            elif c == 5:
                for i in range(8):
                    if wd & (1 << i) and self.ex < self.w and self.by + i < self.h:
                        out.append((tb + (hi | lo) * 1000, self.ex, self.by + i, 1 if self.pol else -1))
                self.by += 8
        return out


class SlowEvt3:
    """EVT 3.0, one word at a time, with the rollover rule and the wait for a first valid time."""

    def __init__(self, w, h):
        self.w, self.h = w, h
        self.high = self.low = self.ey = self.bx = self.pol = 0
        self.valid = False

    def _hi(self, v):
        last = (self.high >> 12) & 0xFFF
        if v < last and last - v > 10:
            self.high += 1 << 24
        self.high = (self.high & ~((1 << 24) - 1)) | (v << 12)

    def decode(self, words):
        out, i = [], 0
        seen_hi = False
        while not self.valid and i < len(words):
            c, v = words[i] >> 12, words[i] & 0xFFF
            if c == 6:
                self.low = v
                if seen_hi:
                    self.valid = True
            elif c == 8:
                self._hi(v)
                seen_hi = True
            i += 1
        for wd in words[i:]:
            c, v = wd >> 12, wd & 0xFFF
            t = (self.high | self.low) * 1000
            if c == 0:
                self.ey = wd & 0x7FF
            elif c == 2:
                x = wd & 0x7FF
                if x < self.w and self.ey < self.h:
                    out.append((t, x, self.ey, 1 if wd & 0x800 else -1))
            elif c == 3:
                self.bx, self.pol = wd & 0x7FF, (wd >> 11) & 1
            elif c in (4, 5):
                n = 12 if c == 4 else 8
                for k in range(n):
                    if v & (1 << k) and self.bx + k < self.w and self.ey < self.h:
                        out.append((t, self.bx + k, self.ey, 1 if self.pol else -1))
                self.bx += n
            elif c == 6:
                self.low = v
            elif c == 8:
                self._hi(v)
        return out


def _random_words(rng, n, codes, probs, xmax=400):
    c = rng.choice(codes, size=n, p=probs)
    rest = rng.integers(0, 1 << 12, size=n)
    # Keep addresses mostly inside a small sensor so events survive the bounds check.
    addr = (c == 2) | (c == 3) | (c == 0)
    rest = np.where(addr, (rest & 0x800) | rng.integers(0, xmax, size=n), rest)
    return ((c << 12) | rest).astype(np.uint16)


@pytest.mark.parametrize("seed", range(6))
def test_libcaer_cmp_matches_slow_reference(seed):
    rng = np.random.default_rng(seed)
    w, h = 346, 260
    fast, slow = LibcaerCmpDecoder(w, h), SlowCmp(w, h)
    for k in range(4):  # several packets: x and vector state carry over
        words = _random_words(rng, 3000, [0, 1, 2, 3, 4, 5, 6], [0.05, 0.2, 0.2, 0.35, 0.05, 0.1, 0.05])
        tb = 1_700_000_000_000_000_000 + k * 10_000_000
        _check(fast.decode(words.tobytes(), tb), slow.decode(words.tolist(), tb))
    assert fast.stats.outside_sensor > 0  # random addresses beyond 346 x 260 are dropped, not wrapped


@pytest.mark.parametrize("seed", range(3))
def test_libcaer_cmp_with_rare_vectors_as_a_davis_sends_them_matches_slow_reference(seed):
    # A real DAVIS346's packets hold a vector word or two among tens of thousands: their states are found by
    # bisection, the events' by runs between state words (the same numbers as word by word).
    rng = np.random.default_rng(50 + seed)
    w, h = 346, 260
    fast, slow = LibcaerCmpDecoder(w, h), SlowCmp(w, h)
    for k in range(4):
        words = _random_words(rng, 20_000, [0, 1, 2, 3, 4, 5], [0.0005, 0.26, 0.37, 0.3685, 0.0005, 0.0005])
        tb = 1_700_000_000_000_000_000 + k * 10_000_000
        _check(fast.decode(words.tobytes(), tb), slow.decode(words.tolist(), tb))


@pytest.mark.parametrize("seed", range(6))
def test_evt3_matches_slow_reference(seed):
    rng = np.random.default_rng(100 + seed)
    w, h = 640, 480
    fast, slow = Evt3Decoder(w, h), SlowEvt3(w, h)
    total = 0
    for _ in range(4):
        words = _random_words(
            rng, 3000, [0, 2, 3, 4, 5, 6, 8, 10, 14, 7], [0.15, 0.35, 0.05, 0.05, 0.05, 0.15, 0.1, 0.03, 0.04, 0.03]
        )
        ref = slow.decode(words.tolist())
        total += len(ref)
        _check(fast.decode(words.tobytes()), ref)
    assert total > 1000


def test_evt3_of_only_event_and_time_words_matches_slow_reference():
    # What sensors mostly send (no vectors, triggers or unknown words) takes a shorter path; addresses beyond a small
    # sensor are dropped there too.
    rng = np.random.default_rng(7)
    fast, slow = Evt3Decoder(300, 200), SlowEvt3(300, 200)
    for _ in range(5):
        words = _random_words(rng, 4000, [0, 2, 6, 8], [0.3, 0.45, 0.2, 0.05])
        _check(fast.decode(words.tobytes()), slow.decode(words.tolist()))
    assert fast.stats.outside_sensor > 0 and fast.stats.unknown_codes == 0


@pytest.mark.parametrize("probs", [
    [0.37, 0.37, 0.2598, 0.0002],  # as the simulator writes them: a y word per event, time high rare
    [0.0, 0.6, 0.399, 0.001],  # no y word at all: every event at the row carried over
    [0.5, 0.0, 0.45, 0.05],  # no event at all
    [0.3, 0.7, 0.0, 0.0],  # no time word: the time carried over
])
def test_evt3_states_taken_by_runs_match_slow_reference(probs):
    # The shorter path takes each event's row and time by runs of events between state words (a time high rare
    # enough is placed by bisection): packets without one kind of word, or with the first valid time inside, too.
    rng = np.random.default_rng(int(1000 * probs[0] + 10 * probs[1]))
    fast, slow = Evt3Decoder(300, 200), SlowEvt3(300, 200)
    first = np.array([(8 << 12) | 5, (6 << 12) | 7], dtype=np.uint16)
    for k in range(5):
        words = _random_words(rng, 6000, [0, 2, 6, 8], probs)
        if k == 0:  # the first valid time comes part way into the first packet
            words = np.concatenate([_random_words(rng, 50, [0, 2], [0.5, 0.5]), first, words])
        _check(fast.decode(words.tobytes()), slow.decode(words.tolist()))
    assert (fast.ey, fast.time_low, fast.time_high) == (slow.ey, slow.low, slow.high)


class SlowEvt2:
    """EVT 2.0, one word at a time: events wait for a first time-high word; a time-high word more than half the
    range below its predecessor is a rollover, a smaller step back is counted."""

    def __init__(self, w, h):
        self.w, self.h, self.high, self.rolls = w, h, -1, 0
        self.counts = {"before_time": 0, "outside": 0, "triggers": 0, "unknown": 0, "backwards": 0}

    def decode(self, words):
        out = []
        for wd in words:
            typ = wd >> 28
            if typ == 8:
                v = wd & 0x0FFFFFFF
                if self.high >= 0 and v < self.high:
                    if self.high - v > 1 << 27:
                        self.rolls += 1
                    else:
                        self.counts["backwards"] += 1
                self.high = v
            elif typ <= 1:
                if self.high < 0:
                    self.counts["before_time"] += 1
                    continue
                t = ((((self.rolls << 28) | self.high) << 6) | ((wd >> 22) & 0x3F)) * 1000
                x, y = (wd >> 11) & 0x7FF, wd & 0x7FF
                if x < self.w and y < self.h:
                    out.append((t, x, y, 1 if typ == 1 else -1))
                else:
                    self.counts["outside"] += 1
            elif typ == 10:
                self.counts["triggers"] += 1
            elif typ not in (14, 15):
                self.counts["unknown"] += 1
        return out


@pytest.mark.parametrize("seed", range(4))
def test_evt2_matches_slow_reference(seed):
    rng = np.random.default_rng(200 + seed)
    w, h = 320, 240
    fast, slow = Evt2Decoder(w, h), SlowEvt2(w, h)
    high = (1 << 28) - 5000 if seed % 2 else int(rng.integers(0, 1 << 27))  # odd seeds: the 28-bit counter wraps
    for k in range(4):  # blocks: the time-high state carries over
        n = 3000
        typ = rng.choice([0, 1, 8, 10, 14, 3], size=n, p=[0.4, 0.4, 0.1, 0.04, 0.03, 0.03]) if k % 2 else (
            rng.choice([0, 1, 8], size=n, p=[0.45, 0.45, 0.1]))
        steps = rng.integers(-3, 60, size=n)
        highs = (high + np.cumsum(steps)) & 0x0FFFFFFF
        high = int(highs[-1])
        cd = (rng.integers(0, 64, size=n) << 22) | (rng.integers(0, 360, size=n) << 11) | rng.integers(0, 270, size=n)
        words = ((typ.astype(np.uint64) << 28) | np.where(typ == 8, highs, cd).astype(np.uint64)).astype(np.uint32)
        if seed == 0 and k == 0:
            words[:5] = cd[:5]  # events before the first time word: dropped
        _check(fast.decode(words.astype("<u4").tobytes()), slow.decode(words.tolist()))
    s, c = fast.stats, slow.counts
    assert (s.before_time, s.outside_sensor, s.triggers, s.unknown_codes, s.time_backwards) == (
        c["before_time"], c["outside"], c["triggers"], c["unknown"], c["backwards"])
    assert s.outside_sensor > 0 and s.time_backwards > 0 and slow.rolls == seed % 2


def test_libcaer_rollover_within_packet():
    # Timestamps near the 31-bit µs limit wrap to small values; the decoder must add 2**31 µs.
    ts = np.array([2**31 - 3, 2**31 - 1, 5, 7], dtype=np.int64)
    x = np.array([1, 2, 3, 4])
    y = np.array([10, 11, 12, 13])
    pol = np.array([1, 0, 1, 0])
    d = (x << 17) | (y << 2) | (pol << 1)
    blob = np.rec.fromarrays([d.astype("<u4"), ts.astype("<i4")], names="d,ts").tobytes()
    t, xx, yy, pp = LibcaerDecoder(640, 480).decode(blob, 1000)
    np.testing.assert_array_equal(t, 1000 + np.array([2**31 - 3, 2**31 - 1, 2**31 + 5, 2**31 + 7]) * 1000)
    np.testing.assert_array_equal(xx, x)
    np.testing.assert_array_equal(yy, y)
    np.testing.assert_array_equal(pp, np.where(pol > 0, 1, -1))


def test_mono_fields():
    t = np.array([0, 5, 4_000_000_000], dtype=np.uint64)
    x, y, pol = np.array([3, 639, 7], np.uint64), np.array([0, 479, 100], np.uint64), np.array([1, 0, 1], np.uint64)
    q = t | (x << np.uint64(32)) | (y << np.uint64(48)) | (pol << np.uint64(63))
    tt, xx, yy, pp = MonoDecoder(640, 480).decode(q.astype("<u8").tobytes(), 10)
    np.testing.assert_array_equal(tt, 10 + t.astype(np.int64))
    np.testing.assert_array_equal(xx, x)
    np.testing.assert_array_equal(yy, y)
    np.testing.assert_array_equal(pp, [1, -1, 1])


def test_encoders_round_trip_through_decoders():
    rng = np.random.default_rng(7)
    n = 5000
    t_us = np.sort(rng.integers(0, 3_000_000, n))
    x, y, p = rng.integers(0, 346, n), rng.integers(0, 260, n), np.where(rng.random(n) < 0.5, 1, -1)
    t, xx, yy, pp = LibcaerCmpDecoder(346, 260).decode(encode_libcaer_cmp(t_us, x, y, p), 123)
    np.testing.assert_array_equal(t, 123 + t_us * 1000)
    np.testing.assert_array_equal(np.c_[xx, yy, pp], np.c_[x, y, p])
    # evt3 across two packets whose sensor clock passes the 24-bit rollover (2**24 µs ~ 16.8 s) and a gap.
    t_abs = np.sort(rng.integers(2**24 - 2_000_000, 2**24 + 30_000_000, n))
    dec, prev = Evt3Decoder(346, 260), None
    outs = []
    for sl in (slice(0, n // 2), slice(n // 2, n)):
        blob, prev = encode_evt3(t_abs[sl], x[sl], y[sl], p[sl], prev)
        outs.append(dec.decode(blob))
    t = np.concatenate([o[0] for o in outs])
    np.testing.assert_array_equal(t, t_abs * 1000)
    np.testing.assert_array_equal(np.concatenate([o[3] for o in outs]), p)


def test_unknown_encoding_and_bad_packet_offsets():
    with pytest.raises(RecordingError, match="supported"):
        make_decoder("evt2", 640, 480)
    with pytest.raises(RecordingError):
        encode_libcaer_cmp(np.array([0, 1 << 24]), np.array([0, 0]), np.array([0, 0]), np.array([1, 1]))


def _evt3_messages(word_packets, width=346, height=260, odd_at=(), corrupt_at=()):
    from plsgraph.core.events import EventStream
    from plsgraph.io.base import RawMessage
    from plsgraph.io.writer import _packet_bytes

    geometry = EventStream(np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16),
                           np.zeros(0, np.int8), width, height)
    msgs = []
    for k, words in enumerate(word_packets):
        blob = words.tobytes() + (b"\x01" if k in odd_at else b"")
        data = _packet_bytes(1_000_000_000 + k * 1_000_000, "cam", geometry, k, 0, "evt3", blob)
        if k in corrupt_at:
            data = data[:20]  # cut inside the header
        msgs.append(RawMessage("/events", "event_camera_msgs/msg/EventPacket", 1_000_000_000 + k * 1_000_000, data,
                               "cdr"))
    return msgs


def _decode_both(msgs, group):
    from plsgraph.io.base import ReadLog
    from plsgraph.io.events_reader import _TopicDecoder

    one = _TopicDecoder(ReadLog(), "one")
    ref = [q for m in msgs for q in one.decode(m)] + one.flush()
    many = _TopicDecoder(ReadLog(), "many")
    out = []
    for i in range(0, len(msgs), group):
        out += many.decode_many(msgs[i : i + group])
    out += many.flush()
    cat = lambda qs: [np.concatenate([q[k] for q in qs]) for k in range(4)]
    for a, b in zip(cat(ref), cat(out), strict=True):
        np.testing.assert_array_equal(a, b)
    assert one.stats == many.stats and one.bad_messages == many.bad_messages
    return [q for q in ref if q[0].size], [q for q in out if q[0].size], many


def _monotonic_evt3(rng, n_packets, n_words=600):
    packets, t_us = [], 0
    for _ in range(n_packets):
        words = []
        for _ in range(n_words // 3):
            t_us += int(rng.integers(0, 40))
            words += [(8 << 12) | ((t_us >> 12) & 0xFFF), (6 << 12) | (t_us & 0xFFF), int(rng.integers(0, 260)),
                      (2 << 12) | (int(rng.integers(0, 2)) << 11) | int(rng.integers(0, 346))]
            if rng.random() < 0.1:  # a vector of events beside the last address
                words += [(3 << 12) | int(rng.integers(0, 330)), (5 << 12) | int(rng.integers(1, 256))]
        packets.append(np.array(words, np.uint16))
    return packets


def test_evt3_packets_decoded_in_groups_give_the_packets_events():
    # Time-ordered packets: a group is decoded at once (fewer, longer outputs) with the same events and stats, also
    # around a packet with a trailing odd byte and a packet that cannot be read, which are decoded on their own.
    rng = np.random.default_rng(3)
    msgs = _evt3_messages(_monotonic_evt3(rng, 60), odd_at={20}, corrupt_at={33})
    ref, out, dec = _decode_both(msgs, group=16)
    assert len(out) < len(ref) / 3
    assert sum(q[0].size for q in out) > 10_000
    assert dec.bad_messages == 1 and dec.stats.odd_bytes == 1


def test_evt3_group_out_of_time_order_is_decoded_packet_by_packet():
    # Random words step the time back and forth: each group falls back to its packets, so a reader checking each
    # message's order sees the same messages as without grouping.
    rng = np.random.default_rng(5)
    packets = [_random_words(rng, 2000, [0, 2, 3, 4, 5, 6, 8], [0.2, 0.35, 0.05, 0.05, 0.05, 0.2, 0.1], xmax=300)
               for _ in range(40)]
    ref, out, dec = _decode_both(_evt3_messages(packets), group=8)
    assert len(out) == len(ref) and len(ref) > 20
    assert dec.group_fallbacks == 3  # then one by one: grouping such a stream only costs


def test_evt3_vector_base_at_the_end_of_a_packet_carries_to_the_next():
    # A VECT_BASE_X ends one packet and its vectors start the next (drivers cut packets anywhere): the vectors'
    # events lie at that base, as a word-by-word decoder has them, whether the packets are decoded one by one or
    # in a group.
    t = [(8 << 12) | 0, (6 << 12) | 5, 17]  # time, then y = 17
    first = np.array(t + [(2 << 12) | 40, (3 << 12) | (1 << 11) | 100], np.uint16)  # an event, then the base
    second = np.array([(5 << 12) | 0xFF, (6 << 12) | 9, (2 << 12) | 41], np.uint16)  # 8 events at the base
    slow, fast = SlowEvt3(346, 260), Evt3Decoder(346, 260)
    for words in (first, second):
        _check(fast.decode(words.tobytes()), slow.decode(words.tolist()))
    x = Evt3Decoder(346, 260).decode(np.r_[first, second].tobytes())[1]
    assert sorted(x.tolist()) == [40, 41, *range(100, 108)]
    rng = np.random.default_rng(11)
    packets = _monotonic_evt3(rng, 20)
    packets[12] = np.r_[packets[12], np.uint16((3 << 12) | 200)]  # a base at the end of a packet in a group
    packets[13] = np.r_[np.uint16((4 << 12) | 0xFFF), packets[13]]  # its 12-wide vector starting the next
    _decode_both(_evt3_messages(packets), group=16)
