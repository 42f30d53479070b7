"""Hot pixels: found from their rates, masked before detection, and nothing else masked."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.core.events import EventStream
from plsgraph.errors import InsufficientDataError
from plsgraph.frontend.noise import drop_pixels, hot_pixel_mask

W, H = 120, 90


def _stream(seconds: float, hot: dict[tuple[int, int], float], seed: int = 0) -> EventStream:
    """Background activity (1 Hz per pixel), a vertical edge sweeping the image twice, a textured strip that
    is active all the time (rows 40-49, every pixel at 15-40 Hz, as a flickering lamp or a moving texture makes
    it) and a small rim active all the time, plus ``hot`` pixels (x, y) -> rate in Hz."""
    rng = np.random.default_rng(seed)
    parts = []
    n_bg = rng.poisson(1.0 * W * H * seconds)
    parts.append((rng.uniform(0, seconds, n_bg), rng.integers(0, W, n_bg), rng.integers(0, H, n_bg)))
    for sweep in range(2):  # the edge crosses each column in 1/W of the sweep; 6 events per pixel it passes
        t0 = sweep * seconds / 2
        for x in range(W):
            tx = t0 + (x + 0.5) / W * (seconds / 2)
            n = 6 * H
            parts.append((tx + rng.uniform(0, 0.01, n), np.full(n, x), np.repeat(np.arange(H), 6)))
    yy, xx = np.mgrid[40:50, 0:W]
    rates = rng.uniform(15, 40, yy.size)
    for x, y, r in zip(xx.ravel(), yy.ravel(), rates, strict=True):
        parts.append(_steady(rng, x, y, r, seconds))
    # A small circle's rim (radius 3 px) firing at 100 Hz all the time, as a distant board on an idling robot does.
    ang = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    for x, y in sorted({(int(round(90 + 3 * np.cos(a))), int(round(20 + 3 * np.sin(a)))) for a in ang}):
        parts.append(_steady(rng, x, y, 100.0, seconds))
    for (x, y), r in hot.items():
        parts.append(_steady(rng, x, y, r, seconds))
    return _join(parts, W, H, rng)


def _steady(rng, x: int, y: int, rate_hz: float, seconds: float) -> tuple:
    """Poisson events of one pixel."""
    n = rng.poisson(rate_hz * seconds)
    return rng.uniform(0, seconds, n), np.full(n, x), np.full(n, y)


def _join(parts: list[tuple], width: int, height: int, rng) -> EventStream:
    t, x, y = (np.concatenate([p[k] for p in parts]) for k in range(3))
    order = np.argsort(t, kind="stable")
    return EventStream.from_arrays((t[order] * 1e9).astype(np.int64), x[order], y[order],
                                   rng.integers(0, 2, t.size), width, height)


def _pixels(mask: np.ndarray) -> set[tuple[int, int]]:
    ys, xs = np.nonzero(mask)
    return {(int(x), int(y)) for x, y in zip(xs, ys, strict=True)}


HOT = {(5, 5): 60.0, (60, 20): 80.0, (61, 20): 300.0, (100, 80): 1000.0, (30, 44): 400.0, (119, 89): 50.0}


def test_hot_pixels_found_and_only_they():
    ev = _stream(3.0, HOT)
    mask = hot_pixel_mask(ev)
    found = _pixels(mask)
    # Every hot pixel, including two side by side, one in the always-active strip and one in the corner; no
    # pixel of the sweeping edge, of the strip or of the busy rim.
    assert found == set(HOT)


def test_slow_hot_pixels_and_short_spans_are_left_alone():
    ev = _stream(3.0, {(10, 10): 5.0, (20, 20): 500.0})
    assert _pixels(hot_pixel_mask(ev)) == {(20, 20)}  # 5 Hz is background activity's range
    short = ev.slice_time(ev.t_first, ev.t_first + 300_000_000)  # 0.3 s: an edge could look like that
    assert not hot_pixel_mask(short).any()
    assert not hot_pixel_mask(EventStream.empty(W, H)).any()


def test_dropping_removes_exactly_their_events():
    ev = _stream(2.0, HOT)
    mask = hot_pixel_mask(ev)
    out = drop_pixels(ev, mask)
    on_hot = mask[ev.y, ev.x]
    assert len(out) == len(ev) - int(on_hot.sum())
    assert not mask[out.y, out.x].any()
    np.testing.assert_array_equal(out.t, ev.t[~on_hot])
    assert drop_pixels(ev, np.zeros((H, W), dtype=bool)) is ev


@pytest.mark.parametrize("mask_hot_pixels", [True, False])
def test_front_end_reports_the_masked_pixels(mask_hot_pixels):
    from plsgraph.core.board import load_board
    from plsgraph.core.camera import davis346_default
    from plsgraph.frontend.track import detect_in_events

    cam = davis346_default()
    rng = np.random.default_rng(3)
    xy = zip(rng.integers(0, cam.width, 12), rng.integers(0, cam.height, 12), rng.uniform(50, 500, 12), strict=True)
    hot = {(int(x), int(y)): float(r) for x, y, r in xy}
    ev = _join([_steady(rng, x, y, r, 2.0) for (x, y), r in hot.items()], cam.width, cam.height, rng)
    if mask_hot_pixels:
        # Nothing but hot pixels: a clear error rather than windows of nothing.
        with pytest.raises(InsufficientDataError, match="hot pixel"):
            detect_in_events(ev, cam, load_board("acircles_4x11"), mask_hot_pixels=True, require_detection=False)
    else:
        _, info = detect_in_events(ev, cam, load_board("acircles_4x11"), mask_hot_pixels=False,
                                   require_detection=False)
        assert info["hot_pixels"] == 0 and info["detected"] == 0


def _board_sweep(seconds: float, **sim):
    """Events of the A2 board sweeping sideways 1.2 m in front of a DAVIS346, from the event simulator."""
    from plsgraph.core.board import load_board
    from plsgraph.core.camera import davis346_default
    from plsgraph.core.geometry import make_T, so3_exp
    from plsgraph.sim.events import EventSimParams, simulate_events

    cam, board = davis346_default(), load_board("acircles_4x11_a2")
    R = so3_exp(np.array([0.1, -0.1, 0.05]))
    c = board.points.mean(axis=0)
    s = np.linspace(0.0, seconds, 21)
    T = np.stack([make_T(R, c + R @ np.array([0.1 * x, 0.0, -1.2])) for x in s])
    return simulate_events(1000.0 + s, T, cam, board, EventSimParams(**sim)), cam, board


@pytest.mark.parametrize("hz", [100.0, 120.0])
def test_flicker_is_recognised_by_its_frequency(hz):
    """Lamps on AC mains (the simulator's flicker, depth 0.2 over the whole scene): the flickering pixels and their
    frequency are found and most of the events are theirs; a moving board under steady light with hot pixels and
    background activity flickers nowhere."""
    from plsgraph.frontend.noise import flicker_events

    ev, *_ = _board_sweep(0.6, flicker_depth=0.2, flicker_hz=hz)
    steady, *_ = _board_sweep(0.6, hot_pixels=30, noise_rate_hz=2.0, contrast_sigma=0.03)
    flick, f, n_pix = flicker_events(ev)
    assert f == hz and n_pix > 10_000 and flick.mean() > 0.4
    assert len(ev) > 10 * len(steady)
    none, f0, n0 = flicker_events(steady)
    assert f0 is None and n0 == 0 and not none.any()


def test_the_front_end_warns_of_flickering_lights(monkeypatch):
    """Flicker is reported always, and warned of when the board was found in few windows (the detector often copes)."""
    import plsgraph.frontend.track as track

    ev, cam, board = _board_sweep(0.6, flicker_depth=0.2, flicker_hz=120.0)
    info = track.camera_track_from_events(ev, cam, board).info
    assert info["flicker_hz"] == 120.0 and info["flicker_event_share"] > 0.4
    warned = any("120 Hz lighting" in w for w in info["warnings"])
    assert warned == (info["detected"] / info["windows"] < track.FLICKER_WARN_FOUND)
    monkeypatch.setattr(track, "FLICKER_WARN_FOUND", 1.01)
    info = track.camera_track_from_events(ev, cam, board).info
    assert any("120 Hz lighting" in w for w in info["warnings"])
    steady, cam, board = _board_sweep(0.6)
    info = track.camera_track_from_events(steady, cam, board).info
    assert info["flicker_hz"] is None and not any("lighting" in w for w in info["warnings"])


def test_with_worker_processes_the_flicker_test_runs_beside_them_with_the_same_answer(monkeypatch):
    """The windows do not depend on the flicker test unless flicker is suppressed, so with worker processes it runs in
    the calling process while they detect: the same frequency, pixels and share as run first in one process."""
    import plsgraph.frontend.track as track

    ev, cam, board = _board_sweep(0.6, flicker_depth=0.2, flicker_hz=120.0)
    keys = ("flicker_hz", "flicker_pixels", "flicker_event_share")
    one = track.camera_track_from_events(ev, cam, board, workers=1).info
    two = track.camera_track_from_events(ev, cam, board, workers=2).info
    assert one["flicker_hz"] == 120.0
    assert [one[k] for k in keys] == [two[k] for k in keys]
    calls = []
    original = track.flicker_events
    monkeypatch.setattr(track, "flicker_events", lambda s: calls.append(original(s)) or calls[-1])
    monkeypatch.setattr(track, "SUPPRESS_FLICKER", True)  # then it must run first: the windows use its answer
    suppressed = track.camera_track_from_events(ev, cam, board, workers=2).info
    # Suppressing needs every event's verdict: the whole stream is tested (the report's census may sample it).
    assert len(calls) == 1
    flagged, hz, n_pix = calls[0]
    assert [suppressed[k] for k in keys] == [hz, n_pix, float(flagged.mean())]


@pytest.mark.parametrize("share", [0.0, 1.01])
def test_the_flicker_sums_are_the_same_whether_the_steady_pixels_events_are_picked_out_or_not(monkeypatch, share):
    """The phase sums take every event of a block when most are steady pixels' (a busy scene) and pick the steady ones
    out otherwise: a pixel's sum is over its own events in their order either way, so the answer is the same to the
    bit, on flickering lamps and on a scene that does not flicker."""
    from plsgraph.frontend import noise

    lamp, *_ = _board_sweep(0.6, flicker_depth=0.2, flicker_hz=100.0)
    quiet = _stream(4.0, HOT)
    for ev in (lamp, quiet):
        default = noise.flicker_events(ev)
        monkeypatch.setattr(noise, "FLICKER_PICK_SHARE", share)
        forced = noise.flicker_events(ev)
        monkeypatch.undo()
        assert np.array_equal(default[0], forced[0]) and default[1:] == forced[1:]
    assert noise.flicker_events(lamp)[1] == 100.0


def test_the_flicker_census_of_a_long_stream_measures_a_sample_with_the_whole_streams_answer():
    """Only for the report, a stream longer than the census's budget is tested on the events of a sample of its pixels
    (before: the whole stream, 0.75 s of a processor for 10 s at 2 M events/s beside the detector's workers). On
    flickering lamps a sixth of the pixels gives the same frequency and nearly the same share and pixel count; a scene
    that does not flicker stays clean; a stream within the budget is tested whole."""
    from plsgraph.frontend import noise

    lamp, *_ = _board_sweep(0.6, flicker_depth=0.2, flicker_hz=100.0)
    flagged, hz, n_pix = noise.flicker_events(lamp)
    share, hz5, n5 = noise.flicker_census(lamp, budget=len(lamp) // 5)
    assert hz5 == hz == 100.0
    assert abs(share - flagged.mean()) < 0.01, (share, flagged.mean())
    assert abs(n5 - n_pix) < 0.05 * n_pix, (n5, n_pix)
    assert noise.flicker_census(lamp, budget=len(lamp)) == (float(flagged.mean()), hz, n_pix)  # the whole stream
    steady, *_ = _board_sweep(0.6, hot_pixels=30, noise_rate_hz=2.0, contrast_sigma=0.03)
    assert noise.flicker_census(steady, budget=len(steady) // 5) == (0.0, None, 0)


def test_the_flicker_census_finds_a_lamp_lighting_part_of_the_image():
    """A lamp lighting a 30 x 30 px patch (100 Hz, one event per cycle near one phase) in busy background activity: a
    ninth of the pixels gives its frequency, its share of the events and about its pixel count, as the whole test."""
    from plsgraph.frontend import noise

    rng = np.random.default_rng(3)
    seconds, parts = 2.0, []
    n_bg = rng.poisson(20.0 * W * H * seconds)  # 20 Hz per pixel of activity that does not lock
    parts.append((rng.uniform(0, seconds, n_bg), rng.integers(0, W, n_bg), rng.integers(0, H, n_bg)))
    cycles = np.arange(int(100 * seconds)) / 100.0
    for x in range(40, 70):
        for y in range(30, 60):
            phase = rng.uniform(0, 0.01)
            parts.append((cycles + phase + rng.normal(0, 3e-4, cycles.size), np.full(cycles.size, x),
                          np.full(cycles.size, y)))
    t, x, y = (np.concatenate([p[k] for p in parts]) for k in range(3))
    t = np.clip(t, 0.0, seconds)
    order = np.argsort(t, kind="stable")
    ev = EventStream.from_arrays((t[order] * 1e9).astype(np.int64), x[order], y[order], np.ones(t.size, bool), W, H)
    flagged, hz, n_pix = noise.flicker_events(ev)
    assert hz == 100.0 and 850 <= n_pix <= 900, n_pix  # the 900 lamp pixels (a few jittered ones missed)
    share, hz9, n9 = noise.flicker_census(ev, budget=len(ev) // 9 + 1)
    assert hz9 == 100.0
    assert abs(share - flagged.mean()) < 0.02, (share, flagged.mean())
    assert abs(n9 - n_pix) < 0.25 * n_pix, (n9, n_pix)
