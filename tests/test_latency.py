"""Pixel latency, a cause of the time offset's error found by the validation study: on a recording built to show it
(dim scene, slow photoreceptors) the events show the board late, and the calibrated td moves by that lag."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from plsgraph.api import simulate_recording
from plsgraph.frontend.track import camera_track_from_events
from plsgraph.io.writer import write_recording, write_truth
from plsgraph.options import CalibrationOptions
from plsgraph.pipeline import Run, build_tracks, solve
from plsgraph.sim import realism as R

BOARD = "acircles_4x11_a2"


def _recording(latency_s: float | None):
    real = R.only("lighting")  # scene reflectances and light at their defaults
    real = dataclasses.replace(real, scene=dataclasses.replace(real.scene, illumination=0.35),
                               sensor=dataclasses.replace(real.sensor, latency_s=latency_s))
    return simulate_recording("rich", 12.0, 3, 0.02, BOARD, realism=real)


def _lag_ms(rec, track) -> float:
    """The one truth-time shift that best fits all detections in least squares (negative: the board shows late).

    Each detection weighs by its image speed, as in a refinement of td from reprojection errors. (The median of
    per-detection best shifts is not used: on the dim recording those fall in two clusters, near -8 and -14 ms,
    and the median jumps between them when a few detections come or go.)"""
    from plsgraph.core.geometry import inv_T

    sim = rec.sim
    pts = (sim.board_true if sim.board_true is not None else sim.board).points

    def project(t):
        T = inv_T(sim.camera_poses_at(t))
        p = np.einsum("mij,nj->mni", T[:, :3, :3], pts) + T[:, None, :3, 3]
        return sim.camera.project(p.reshape(-1, 3)).reshape(p.shape[:2] + (2,))

    tb = sim.truth_base.t
    t = np.asarray(track.detections.t) - rec.epoch_ns * 1e-9
    keep = (t > tb[0] - sim.td + 0.04) & (t < tb[-1] - sim.td - 0.04)
    t, uv = t[keep], np.asarray(track.detections.uv)[keep]
    shift = 0.0
    for _ in range(10):  # Gauss-Newton on the shift; points off by more than 5 px are left out
        r = uv - project(t + shift)
        v = (project(t + shift + 1e-3) - project(t + shift - 1e-3)) / 2e-3
        ok = np.isfinite(r).all(axis=-1) & (np.linalg.norm(r, axis=-1) < 5.0)
        shift += float(np.sum(np.sum(v * r, axis=-1)[ok]) / np.sum(np.sum(v * v, axis=-1)[ok]))
    return 1e3 * shift


def _td_error_ms(rec, tmp_path) -> tuple[float, float]:
    path = tmp_path / "rec.mcap"
    write_recording(path, rec.events, rec.joints, None, rec.sim.camera, truth=None, event_format="evt3",
                    overwrite=True)
    opts = CalibrationOptions.build(board=BOARD, wheel_radius=rec.truth["wheel_radius_nominal"],
                                    track_width=rec.truth["track_width_nominal"], truth=write_truth(path, rec.truth))
    run = Run(path, opts)
    build_tracks(run)
    solve(run, refine=True)
    ref = run.refinement
    sigma_td = float(np.sqrt(ref.cov_base_axes[6, 6]))
    return 1e3 * (ref.td - rec.truth["td"]), 1e3 * sigma_td


@pytest.mark.slow
def test_pixel_latency_shows_as_a_detection_lag_and_moves_td_by_it(tmp_path):
    from plsgraph.core.board import load_board

    board = load_board(BOARD)
    fast = _recording(None)
    slow = _recording(6e-4)  # dark circles at 0.35 light: time constant ~20 ms (capped)
    lag = {}
    for name, rec in (("fast", fast), ("slow", slow)):
        track = camera_track_from_events(rec.events, rec.sim.camera, board, 30.0, "count")
        lag[name] = _lag_ms(rec, track)
    assert abs(lag["fast"]) <= 1.0  # without latency the detections are on time
    assert lag["slow"] <= -3.0  # the slow pixels show the board late
    err_fast, _ = _td_error_ms(fast, tmp_path)
    err_slow, sigma_slow = _td_error_ms(slow, tmp_path)
    # td takes the lag in: the calibrated offset moves the same way (events stamped late = camera clock behind),
    # by the lag's order (the refinement also trades some of the lag against the board and camera poses), and its
    # sigma, which carries a model floor for latency, still covers the error against the clock truth. Measured: lag
    # -9.3 ms, td moved -14.6 ms (when this test was written); lag -9.5 ms, td -18.6 ms (seventeenth session, ratio
    # 1.95); lag -8.8 ms, td -18.6 ms with the blob centres by polarity (eighteenth, ratio 2.1: the same td, the blob
    # detections nearer their stamps' instant).
    assert 0.5 <= (err_slow - err_fast) / lag["slow"] <= 2.5
    assert abs(err_slow) <= 3 * sigma_slow
