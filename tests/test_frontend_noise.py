"""Sensor-noise handlers of the front end: each removes what it should and keeps the board's events."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.core.board import load_board
from plsgraph.core.camera import davis346_default
from plsgraph.core.events import EventStream
from plsgraph.core.geometry import make_T, so3_exp
from plsgraph.frontend import noise
from plsgraph.frontend.track import OUTCOMES, camera_track_from_events
from plsgraph.sim.events import simulate_events

CAM = davis346_default()
BOARD = load_board("acircles_4x11")


def _board_events(duration: float = 0.3, still_after: float | None = None, seed: int = 0) -> EventStream:
    """The desk board 0.6 m away, sliding at ~150 px/s (and stopping at ``still_after`` s)."""
    t = np.arange(0.0, duration + 1e-9, 0.002)
    tm = t if still_after is None else np.minimum(t, still_after)
    p = np.stack([0.12 * tm, 0.05 * np.sin(3 * tm), 0.04 * tm], axis=1)
    R = so3_exp(np.array([-0.05, 0.01, 0.05]))[None] @ so3_exp(np.stack([0.3 * tm, -0.2 * tm, 0 * tm], axis=1))
    poses = make_T(R, BOARD.points.mean(axis=0) + np.array([-0.02, 0.0, -0.6]) + p)
    return simulate_events(t, poses, CAM, BOARD, seed=seed)


def _merge(*streams: EventStream) -> tuple[EventStream, np.ndarray]:
    """Streams merged in time order, and which input each event came from."""
    src = np.concatenate([np.full(len(s), i) for i, s in enumerate(streams)])
    cat = [np.concatenate([getattr(s, a) for s in streams]) for a in "txyp"]
    order = np.argsort(cat[0], kind="stable")
    return EventStream(*(a[order] for a in cat), CAM.width, CAM.height), src[order]


def _events(t_ns, x, y, p) -> EventStream:
    return EventStream(np.asarray(t_ns, np.int64), np.asarray(x, np.uint16), np.asarray(y, np.uint16),
                       np.asarray(p, np.int8), CAM.width, CAM.height)


@pytest.fixture(scope="module")
def board_events():
    return _board_events()


def test_hot_pixel_at_1khz_is_masked_and_the_board_kept(board_events):
    ev = board_events
    n = int(0.3 * 1000)
    t = ev.t_first + np.sort(np.random.default_rng(1).integers(0, 300_000_000, n))
    hot = _events(t, np.full(n, 40), np.full(n, 30), np.ones(n))
    merged, _ = _merge(ev, hot)
    model = noise.NoiseModel.from_stream(merged)
    assert model.hot[30, 40]
    board_pix = noise.pixel_counts(ev) > 0
    assert np.count_nonzero(model.mask & board_pix) <= 0.01 * np.count_nonzero(board_pix)
    # Updating with more of the same keeps it; a fresh model on the board alone flags nothing much.
    assert model.update(hot).hot[30, 40]
    assert np.count_nonzero(noise.NoiseModel.from_stream(ev).hot) <= 0.01 * np.count_nonzero(board_pix)


def test_background_activity_filter_drops_isolated_noise_and_keeps_edges(board_events):
    ev = board_events
    rng = np.random.default_rng(2)
    n = int(2.0 * CAM.width * CAM.height * 0.3)  # 2 Hz per pixel over 0.3 s
    ba = _events(ev.t_first + rng.integers(0, 300_000_000, n), rng.integers(0, CAM.width, n),
                 rng.integers(0, CAM.height, n), rng.choice([-1, 1], n))
    merged, src = _merge(ev, ba)
    keep = noise.background_activity_filter(merged, dt_s=0.005)
    assert keep[src == 0].mean() >= 0.9  # board edges fire in runs of neighbours
    assert keep[src == 1].mean() <= 0.25  # isolated noise rarely has a neighbour within 5 ms


def test_flicker_on_a_static_bright_patch_is_masked(board_events):
    ev = board_events
    rng = np.random.default_rng(3)
    xs, ys = np.meshgrid(np.arange(300, 320), np.arange(200, 220))
    xs, ys = xs.ravel(), ys.ravel()
    k = np.arange(int(0.3 * 200))  # a burst every half period of 100 Hz, alternating polarity
    t = (k[None, :] * 5_000_000 + rng.integers(0, 300_000, (xs.size, k.size))).ravel() + ev.t_first
    p = np.tile(np.where(k % 2 == 0, 1, -1), xs.size)
    fl = _events(t, np.repeat(xs, k.size), np.repeat(ys, k.size), p)
    merged, _ = _merge(ev, fl)
    mask = noise.flicker_mask(merged)
    assert mask[200:220, 300:320].mean() >= 0.95
    board_pix = noise.pixel_counts(ev) > 0
    assert np.count_nonzero(mask & board_pix) <= 0.01 * np.count_nonzero(board_pix)
    assert noise.NoiseModel.from_stream(merged).mask[200:220, 300:320].mean() >= 0.95


def test_board_found_through_noise_and_still_windows_are_held():
    ev = _board_events(duration=0.5, still_after=0.25, seed=4)
    rng = np.random.default_rng(5)
    n = int(1.0 * CAM.width * CAM.height * 0.5)
    ba = _events(ev.t_first + rng.integers(0, 500_000_000, n), rng.integers(0, CAM.width, n),
                 rng.integers(0, CAM.height, n), rng.choice([-1, 1], n))
    m = 500
    hot = _events(ev.t_first + np.sort(rng.integers(0, 500_000_000, m)), np.full(m, 10), np.full(m, 10), np.ones(m))
    merged, _ = _merge(ev, ba, hot)
    track = camera_track_from_events(merged, CAM, BOARD, kind="count")
    codes = track.info["window_outcomes"]["code"]
    names = np.array(OUTCOMES)[codes]
    assert codes.size == track.info["windows"]
    moving = track.info["window_outcomes"]["t"] - ev.t_first * 1e-9 < 0.25
    assert np.mean(names[moving] == "detected") >= 0.6
    assert np.count_nonzero(names[~moving] == "held_still") >= 3
    # Held windows repeat the last detection's points.
    held = track.detections.uv[-1]
    assert np.all(np.isfinite(held[np.all(np.isfinite(held), axis=1)]))
