"""Frames taken while the wheel odometry says the base stood still are left out of the refinement."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from plsgraph.core.board import load_board
from plsgraph.core.camera import davis346_default
from plsgraph.core.tracks import CameraTrack
from plsgraph.odometry.still import MIN_FRAMES_LEFT, still_base
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.options import CalibrationOptions
from plsgraph.pipeline import Run, _moving_frames


def _parked_drive(t_end=12.0, park=(0.0, 3.0), stop=9.0, rate=50.0, tick_m=2e-4):
    """Wheel angles of a base parked until park[1], driving an arc until ``stop``, parked after; encoder jitter of
    ``tick_m`` while parked (a tick back and forth)."""
    t = np.arange(0.0, t_end, 1.0 / rate)
    moving = (t > park[1]) & (t < stop)
    r = 0.098
    left = np.cumsum(np.where(moving, 0.30, 0.0)) / rate / r
    right = np.cumsum(np.where(moving, 0.40, 0.0)) / rate / r
    jitter = np.where(moving, 0.0, tick_m / r * (np.arange(t.size) % 2))
    return t, left + jitter, right


def test_still_base_finds_the_parked_stretches_and_their_ends():
    t, left, right = _parked_drive()
    base = base_track_from_wheels(t + 100.0, left, right)
    q = np.array([0.0, 0.2, 1.5, 2.5, 3.1, 3.5, 6.0, 8.9, 9.5, 11.5, 11.97, 12.5]) + 100.0
    still = still_base(q, base)
    # parked (the first sample's stretch is cut at the odometry's start and still long enough), driving, parked again
    # (the last samples' too); past the odometry's end nothing says so.
    want = [True, True, True, True, False, False, False, False, True, True, True, False]
    assert still.tolist() == want


def _built_run() -> Run:
    """A run of the parked drive's base with a frame every 1/30 s from 0.05 to 11.9 s (on the odometry's clock)."""
    t, left, right = _parked_drive()
    base = base_track_from_wheels(t + 100.0, left, right)
    tc = np.arange(0.05, 11.9, 1.0 / 30.0) + 100.0
    cam = CameraTrack(tc, np.broadcast_to(np.eye(4), (tc.size, 4, 4)).copy())
    board = "acircles_4x11_a2"
    return Run(Path("<built>"), CalibrationOptions.build(board=board), board=load_board(board),
               camera=davis346_default(), camera_track=cam, base_track=base)


def test_the_refinement_takes_the_frames_of_a_moving_base_only():
    run = _built_run()
    base, cam = run.base_track, run.camera_track
    tc = cam.t
    run.closed_form = SimpleNamespace(time_offset=SimpleNamespace(ok=True, at_range_edge=False))
    kept = _moving_frames(run, 0.0)
    still = still_base(tc, base)
    assert 0 < still.sum() < tc.size and len(kept) == tc.size - still.sum()
    assert not np.any(still_base(kept.t, base))
    assert run.discarded["refinement_frames_base_still"] == still.sum()
    assert any("stood still" in w and "leaves them out" in w for w in run.warnings)
    # The frames are put on the odometry clock with the offset (t_odom = t_cam + td): the camera stamped 0.5 s early.
    early = CameraTrack(tc - 0.5, cam.T_board_cam)
    run.camera_track = early
    assert np.array_equal(_moving_frames(run, 0.5).t, kept.t - 0.5)
    # An offset the closed form does not trust: only frames still over the whole search range either side go.
    run.camera_track = cam
    run.closed_form = SimpleNamespace(time_offset=SimpleNamespace(ok=False, at_range_edge=False))
    wide = _moving_frames(run, 0.0)
    assert len(wide) > len(kept) and set(kept.t) <= set(wide.t)
    # Too few frames of a moving base: none are left out (the rest of the pipeline says what is wrong).
    run2 = Run(Path("<built>"), run.options, board=run.board, camera=run.camera,
               camera_track=CameraTrack(tc[:MIN_FRAMES_LEFT + 20], cam.T_board_cam[:MIN_FRAMES_LEFT + 20]),
               base_track=base)
    assert len(_moving_frames(run2, 0.0)) == MIN_FRAMES_LEFT + 20
    assert run2.discarded["refinement_frames_base_still"] == 0


def test_run_refinement_hands_the_refinement_the_moving_frames_only(monkeypatch):
    import plsgraph.refine.graph as graph
    from plsgraph.pipeline import run_refinement

    run = _built_run()
    base, cam = run.base_track, run.camera_track
    tc = cam.t
    run.closed_form = SimpleNamespace(time_offset=SimpleNamespace(ok=True, at_range_edge=False), td=0.0,
                                      R_base_cam=np.eye(3), t_base_cam=np.zeros(3), odometry_scale={})
    given = {}

    class Stop(Exception):
        pass

    def refine(camera_track, *args, **kwargs):
        given["track"] = camera_track
        raise Stop

    monkeypatch.setattr(graph, "refine", refine)
    try:
        run_refinement(run, lambda *a, **k: __import__("contextlib").nullcontext(lambda *a: None))
    except Stop:
        pass
    assert len(given["track"]) == tc.size - still_base(tc, base).sum() < tc.size
