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
    assert np.array_equal(run.still_frames, still)  # what the residual figure and compare read
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
    assert run2.discarded["refinement_frames_base_still"] == 0 and run2.still_frames is None


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


def _run_with_detections(rocking_px: float = 6.0) -> tuple[Run, np.ndarray]:
    """The built run with detections of a board about 8 m ahead of a forward-looking camera, exact while the base moves
    and ``rocking_px`` off while it stands still; its still frames marked as the refinement's step marks them."""
    from plsgraph.core.tracks import Detections
    from plsgraph.refine.residuals import predicted_pixels

    run = _built_run()
    cam, board = run.camera_track, run.board
    T_base_cam = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0.3], [0, 0, 0, 1]], dtype=float)  # looks along x
    T_world_board = np.eye(4)
    c, s = np.cos(0.6), np.sin(0.6)  # the board 8 m away, 34 deg to the left, where the arc turns the camera
    T_world_board[:3, 3] = (8.0 * c, 8.0 * s, 0.3)
    T_world_board[:3, :3] = np.array([[-s, 0, c], [c, 0, s], [0, -1, 0]], dtype=float)  # facing the start
    pts = board.points
    blank = Detections(cam.t, np.zeros((cam.t.size, len(pts), 2)), pts)
    uv, ok = predicted_pixels(blank, run.base_track, run.camera, T_base_cam, 0.0, T_world_board)
    assert ok.all() and np.isfinite(uv).all()
    still = still_base(cam.t, run.base_track)
    uv[still] += rocking_px
    run.camera_track = CameraTrack(cam.t, cam.T_board_cam, detections=Detections(cam.t, uv, pts))
    run.still_frames = still
    run.refinement = SimpleNamespace(T_base_cam=T_base_cam, R_base_cam=T_base_cam[:3, :3], td=0.0,
                                     T_world_board=T_world_board, observability=None)
    return run, still


def test_the_residual_figure_draws_still_base_frames_apart_and_leaves_them_out_of_the_distribution(tmp_path):
    from plsgraph.report.figures import _fig_residuals, figure_inputs, frame_residuals

    run, still = _run_with_detections()
    ref = run.refinement
    t, rms, flat, flagged = frame_residuals(run, ref.T_base_cam, ref.td, ref.T_world_board)
    assert np.array_equal(flagged, still) and np.array_equal(t, run.camera_track.t)
    assert np.allclose(rms[still], 6.0 * np.sqrt(2)) and np.allclose(rms[~still], 0.0, atol=1e-9)
    # The distribution holds the frames the refinement took, every point of them and nothing of a still base.
    assert flat.shape == (int((~still).sum()) * len(run.board.points), 2)
    assert np.abs(flat).max() < 1e-9
    # The figure inputs carry the mask to the figure worker.
    assert np.array_equal(figure_inputs(run).still_frames, still)
    assert _fig_residuals(run, tmp_path) == "residuals.png" and (tmp_path / "residuals.png").stat().st_size > 0
    # Without the mask (no frame left out) every frame is in the distribution.
    run.still_frames = None
    assert len(frame_residuals(run, ref.T_base_cam, ref.td, ref.T_world_board)[2]) == still.size * len(
        run.board.points)


def test_compare_scores_every_solution_on_the_frames_the_refinement_took(monkeypatch):
    import plsgraph.api as api
    import plsgraph.refine.compare as compare

    run, still = _run_with_detections()
    run.closed_form = SimpleNamespace(methods={"pls": SimpleNamespace(R_base_cam=np.eye(3), error=None)})
    given = {}

    class Stop(Exception):
        pass

    def compare_solutions(solutions, refinement, *, camera_track, **kwargs):
        given["track"] = camera_track
        raise Stop

    monkeypatch.setattr(api, "run_recording", lambda *a, **k: run)
    monkeypatch.setattr(compare, "compare_solutions", compare_solutions)
    try:
        api.compare("<built>", options=run.options)
    except Stop:
        pass
    assert np.array_equal(given["track"].t, run.camera_track.t[~still])
    assert len(given["track"].detections) == int((~still).sum())
