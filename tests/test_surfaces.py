"""Surfaces against small hand-computed examples and invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plsgraph.core.events import EventStream
from plsgraph.errors import InputError
from plsgraph.frontend import surfaces as S

MS = 1_000_000


def _stream(rows: list[tuple[int, int, int, int]], w: int = 4, h: int = 3) -> EventStream:
    """Events from (t_ms, x, y, p) rows."""
    a = np.array(rows, dtype=np.int64).reshape(-1, 4)
    return EventStream.from_arrays(a[:, 0] * MS, a[:, 1], a[:, 2], a[:, 3], w, h)


# Pixel (1, 0): ON at 1 ms, ON at 3 ms.  Pixel (2, 1): ON at 2 ms, OFF at 5 ms.
# Pixel (0, 2): OFF at 4 ms only.         Pixel (3, 2): OFF 6 ms, OFF 7 ms, ON 8 ms.
HAND = [
    (1, 1, 0, 1),
    (2, 2, 1, 1),
    (3, 1, 0, 1),
    (4, 0, 2, -1),
    (5, 2, 1, -1),
    (6, 3, 2, -1),
    (7, 3, 2, -1),
    (8, 3, 2, 1),
]


def test_count_and_polarity_sum_by_hand():
    s = _stream(HAND)
    c = S.count_image(s)
    assert c.dtype == np.float32 and c.shape == (3, 4)
    expect = np.zeros((3, 4))
    expect[0, 1], expect[1, 2], expect[2, 0], expect[2, 3] = 2, 2, 1, 3
    np.testing.assert_array_equal(c, expect)
    ps = S.surface(s, "polarity_sum")
    expect[0, 1], expect[1, 2], expect[2, 0], expect[2, 3] = 2, 0, -1, -1
    np.testing.assert_array_equal(ps, expect)


def test_time_surface_by_hand():
    s = _stream(HAND)
    tau = 0.004
    on = S.time_surface(s, t_ref_ns=10 * MS, tau_s=tau, polarity="on")
    off = S.time_surface(s, t_ref_ns=10 * MS, tau_s=tau, polarity="off")
    e = lambda age_ms: math.exp(-age_ms * 1e-3 / tau)
    assert on[0, 1] == pytest.approx(e(7), rel=1e-6)  # last ON at 3 ms
    assert on[1, 2] == pytest.approx(e(8), rel=1e-6)  # ON at 2 ms; its OFF at 5 ms is another channel
    assert on[2, 3] == pytest.approx(e(2), rel=1e-6)
    assert on[2, 0] == 0.0
    assert off[1, 2] == pytest.approx(e(5), rel=1e-6)
    assert off[2, 3] == pytest.approx(e(3), rel=1e-6)  # OFF at 7 ms
    assert off[0, 1] == 0.0
    signed = S.time_surface(s, t_ref_ns=10 * MS, tau_s=tau, polarity="signed")
    assert signed[1, 2] == pytest.approx(-e(5), rel=1e-6)
    assert signed[2, 3] == pytest.approx(+e(2), rel=1e-6)
    assert np.count_nonzero(signed) == 4


def test_time_surface_pair_matches_single_polarities():
    s = _random_stream(2000)
    pair = S.time_surface_pair(s, t_ref_ns=40 * MS, tau_s=0.01)
    assert pair.shape == (2, 30, 40)
    np.testing.assert_allclose(pair[0], S.time_surface(s, 40 * MS, 0.01, "off"))
    np.testing.assert_allclose(pair[1], S.time_surface(s, 40 * MS, 0.01, "on"))


def test_time_surface_ignores_events_after_reference():
    s = _stream(HAND)
    ts = S.time_surface(s, t_ref_ns=5 * MS, tau_s=0.01, polarity="any")
    assert ts[2, 3] == 0.0  # its events are at 6..8 ms
    assert ts[1, 2] == pytest.approx(1.0)  # event exactly at t_ref
    assert ts.max() <= 1.0


def test_polarity_aware_by_hand_without_blur():
    s = _stream(HAND)
    img = S.polarity_aware_surface(s, alpha=0.1, blur_ksize=0, previous="pixel")
    flip = math.exp(-2 / 0.1)
    assert img[0, 1] == pytest.approx(1.0)  # ON, ON
    assert img[1, 2] == pytest.approx(flip, abs=1e-12)  # ON then OFF
    assert img[2, 0] == pytest.approx(1.0)  # single event, lone="keep"
    assert img[2, 3] == pytest.approx(flip, abs=1e-12)  # OFF, OFF, ON: the last two differ
    assert np.count_nonzero(img) == 4
    drop = S.polarity_aware_surface(s, blur_ksize=0, lone="drop")
    assert drop[2, 0] == 0.0 and drop[0, 1] == pytest.approx(1.0)
    signed = S.polarity_aware_surface(s, blur_ksize=0, signed=True)
    assert signed[2, 0] == pytest.approx(-1.0) and signed[0, 1] == pytest.approx(1.0)


def test_polarity_aware_stream_reading_by_hand():
    s = _stream(HAND)
    img = S.polarity_aware_surface(s, blur_ksize=0, previous="stream")
    flip = math.exp(-20)
    # Last events and their predecessors in the stream:
    # (1,0) idx 2 ON after idx 1 ON -> 1;  (2,1) idx 4 OFF after idx 3 OFF -> 1
    # (0,2) idx 3 OFF after idx 2 ON -> flip;  (3,2) idx 7 ON after idx 6 OFF -> flip
    assert img[0, 1] == pytest.approx(1.0)
    assert img[1, 2] == pytest.approx(1.0)
    assert img[2, 0] == pytest.approx(flip, abs=1e-12)
    assert img[2, 3] == pytest.approx(flip, abs=1e-12)


def test_polarity_aware_blur_is_the_paper_kernel():
    s = _stream([(1, 5, 5, 1)], w=11, h=11)
    img = S.polarity_aware_surface(s)
    g = np.exp(-(np.arange(-2, 3) ** 2) / (2 * 0.7**2))
    g /= g.sum()
    np.testing.assert_allclose(img[3:8, 3:8], np.outer(g, g), atol=1e-6)
    assert img.sum() == pytest.approx(1.0, abs=1e-5)


def test_leaky_integrator_by_hand():
    s = _stream(HAND)
    tau, C = 0.005, 0.2
    img = S.leaky_integrator(s, t_ref_ns=8 * MS, tau_s=tau, contrast=C)
    d = lambda t_ms: math.exp(-(8 - t_ms) * 1e-3 / tau)
    assert img[0, 1] == pytest.approx(C * (d(1) + d(3)), rel=1e-6)
    assert img[1, 2] == pytest.approx(C * (d(2) - d(5)), rel=1e-6)
    assert img[2, 3] == pytest.approx(C * (-d(6) - d(7) + d(8)), rel=1e-6)
    no_decay = S.leaky_integrator(s, tau_s=None, contrast=C)
    np.testing.assert_allclose(no_decay, C * S.count_image(s, signed=True), rtol=1e-6)


def _random_stream(n: int, w: int = 40, h: int = 30, seed: int = 0) -> EventStream:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 50 * MS, n))
    return EventStream.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n), w, h)


def _loop_reference(s: EventStream, tau: float, t_ref: int):
    """Per-event loop reference for the vectorized code (tests only)."""
    last_t = {}
    prev_p = {}
    last_p = {}
    for t, x, y, p in zip(s.t, s.x, s.y, s.p, strict=True):
        k = (int(y), int(x))
        if k in last_p:
            prev_p[k] = last_p[k]
        last_p[k] = int(p)
        last_t[(k, int(p))] = int(t)
    ts = np.zeros((s.height, s.width))
    pa = np.zeros((s.height, s.width))
    for (k, p), t in last_t.items():
        if p > 0:
            ts[k] = math.exp(-(t_ref - t) * 1e-9 / tau)
    for k, p in last_p.items():
        pa[k] = math.exp(-abs(p - prev_p.get(k, p)) / 0.1)
    return ts, pa


def test_vectorized_matches_event_loop():
    s = _random_stream(3000)
    ts_ref, pa_ref = _loop_reference(s, 0.01, s.t_last)
    np.testing.assert_allclose(S.time_surface(s, tau_s=0.01, polarity="on"), ts_ref, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(S.polarity_aware_surface(s, blur_ksize=0), pa_ref, rtol=1e-5, atol=1e-7)


def test_surface_at_uses_window_before_query():
    s = _stream(HAND)
    # Window (4 ms, 7 ms]: events at 5, 6, 7 ms.
    img = S.surface_at(s, 7 * MS, "count", window_ns=3 * MS)
    assert img.sum() == 3 and img[1, 2] == 1 and img[2, 3] == 2
    img = S.surface_at(s, 7 * MS, "count", count=2)
    assert img.sum() == 2 and img[2, 3] == 2
    ts = S.surface_at(s, 7 * MS, "time_surface", tau_s=0.0005, polarity="any")
    assert ts[2, 3] == pytest.approx(1.0)
    assert ts[1, 2] == pytest.approx(math.exp(-4), rel=1e-5)  # 2 ms old, inside the 2.5 ms look-back
    assert ts[0, 1] == 0.0 and ts[2, 0] == 0.0  # 4 and 3 ms old: outside
    stack = S.surfaces_at(s, [3 * MS, 8 * MS], "count", window_ns=10 * MS)
    assert stack.shape == (2, 3, 4) and stack[0].sum() == 3 and stack[1].sum() == 8


def test_windows_by_duration_and_count_cover_all_events():
    s = _random_stream(1000)
    out = list(S.windows(s, "count", duration_ns=10 * MS))
    assert sum(img.sum() for _, img in out) == len(s)
    assert all(t2 - t1 == 10 * MS for (t1, _), (t2, _) in zip(out, out[1:], strict=False))
    out = list(S.windows(s, "count", count=300))
    assert [int(img.sum()) for _, img in out] == [300, 300, 300]
    assert out[0][0] == s.t[299]
    overlapping = list(S.windows(s, "polarity_sum", count=500, step=250))
    assert len(overlapping) == 3


def test_to_uint8_ranges():
    img = np.array([[0.0, 0.5, 1.0]], dtype=np.float32)
    np.testing.assert_array_equal(S.to_uint8(img), [[0, 128, 255]])
    np.testing.assert_array_equal(S.to_uint8(img, invert=True), [[255, 128, 0]])
    signed = np.array([[-1.0, 0.0, 1.0]], dtype=np.float32)
    np.testing.assert_array_equal(S.to_uint8(signed), [[0, 128, 255]])
    big = np.array([[-4.0, 0.0, 4.0]], dtype=np.float32)
    u = S.to_uint8(big)
    assert u[0, 1] == 128 and u[0, 0] < 5 and u[0, 2] > 250


def test_bad_parameters_raise_typed_errors():
    s = _stream(HAND)
    with pytest.raises(InputError):
        S.surface(s, "nonsense")
    with pytest.raises(InputError):
        S.time_surface(s, tau_s=0.0)
    with pytest.raises(InputError):
        S.polarity_aware_surface(s, previous="global")
    with pytest.raises(InputError):
        S.polarity_aware_surface(s, blur_ksize=4)
    with pytest.raises(InputError):
        list(S.windows(s, duration_ns=MS, count=3))
    with pytest.raises(InputError):
        S.surface_at(s, MS, "count", window_ns=MS, count=3)


def test_empty_stream_gives_zero_images():
    s = EventStream.empty(5, 4)
    for kind in S.KINDS:
        img = S.surface(s, kind)
        assert img.shape == (4, 5) and img.dtype == np.float32 and not img.any()
    assert list(S.windows(s, count=10)) == []
