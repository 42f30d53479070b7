"""Detections refused by their neighbours in time: labellings shifted by a lattice step (front end)."""

from __future__ import annotations

import numpy as np
import pytest
from refine_cases import rotation_error_base_axes, sim_case

from plsgraph.core.tracks import Detections
from plsgraph.frontend.consistency import REASON_INCONSISTENT, inconsistent_frames
from plsgraph.frontend.detect import neighbour_distance
from plsgraph.frontend.track import _track_from_detections
from plsgraph.refine.graph import refine
from plsgraph.sim.robot import simulate_robot


def _shift_by_a_step(uv: np.ndarray, k: int, steps: float = 1.0) -> None:
    """Frame k labelled ``steps`` lattice steps off (every point moved onto where its neighbour is)."""
    seen = uv[k][np.all(np.isfinite(uv[k]), axis=1)]
    spacing = float(np.median(neighbour_distance(seen)))
    d = uv[k, 1] - uv[k, 0]
    uv[k] += steps * spacing * d / np.linalg.norm(d)


def _full_frames(det: Detections) -> np.ndarray:
    return np.where(np.all(np.isfinite(det.uv), axis=(1, 2)))[0]


@pytest.mark.parametrize("motion", ["rich", "spin", "straight"])
def test_clean_detections_are_all_kept(motion):
    # Smooth motion, 0.5 px noise, including fast turns in place: nothing is refused.
    rec = simulate_robot(motion, duration=10.0, seed=5, realism="ideal")
    det = rec.detections(0.5, seed=6)
    assert len(det) > 100
    assert not inconsistent_frames(det.t, det.uv).any()


def test_shifted_labellings_are_refused_and_only_they():
    rec = sim_case("rich").rec
    det = rec.detections(0.3, seed=13)
    uv, t = det.uv.copy(), det.t.copy()
    full = _full_frames(det)
    wrong = full[[40, 120, 200]]
    for k in wrong:
        _shift_by_a_step(uv, k)
    # One more right after a gap: its nearest neighbours are 0.13-0.2 s away (checked with the two nearest).
    gap = full[260]
    keep = np.ones(t.size, dtype=bool)
    keep[gap - 4:gap] = False
    keep[gap + 1:gap + 4] = False
    _shift_by_a_step(uv, gap, steps=0.8)
    t, uv = t[keep], uv[keep]
    expected = np.isin(np.arange(keep.size)[keep], np.r_[wrong, gap])
    bad = inconsistent_frames(t, uv)
    np.testing.assert_array_equal(bad, expected)


def test_two_wrong_frames_in_a_row_do_not_take_good_neighbours():
    rec = sim_case("rich").rec
    det = rec.detections(0.3, seed=14)
    uv = det.uv.copy()
    k = _full_frames(det)[150]
    _shift_by_a_step(uv, k)
    _shift_by_a_step(uv, k + 1)
    bad = inconsistent_frames(det.t, uv)
    assert set(np.where(bad)[0]) == {k, k + 1}


def test_front_end_records_the_refusal_and_the_refinement_matches_clean_data():
    case = sim_case("rich")
    rec = case.rec
    det = rec.detections(0.3, seed=15)
    uv = det.uv.copy()
    wrong = _full_frames(det)[[30, 100, 170, 240]]
    for k in wrong:
        _shift_by_a_step(uv, k)
    n = len(det)
    info = {"skipped": {}, "seconds": {}, "warnings": [], "kind": "count", "windows": n, "detected": n,
            "detector": ["rims"] * n,
            "window_outcomes": {"t": det.t.tolist(), "outcome": ["rims"] * n}}
    track = _track_from_detections(Detections(det.t, uv, det.board_points), info, rec.camera, 1.5, None)
    assert len(track) == n - len(wrong)
    assert track.info["skipped"][REASON_INCONSISTENT] == len(wrong)
    outcomes = np.asarray(track.info["window_outcomes"]["outcome"])
    np.testing.assert_array_equal(np.where(outcomes == REASON_INCONSISTENT)[0], wrong)
    assert len(track.info["detector"]) == len(track) and track.info["detected"] == len(track)
    assert not np.isin(det.t[wrong], track.t).any()
    # The refinement on what is left agrees with the one on the clean detections, and with the truth.
    clean = _track_from_detections(det, {**info, "skipped": {}, "seconds": {}, "detector": ["rims"] * n,
                                         "window_outcomes": {"t": det.t.tolist(), "outcome": ["rims"] * n}},
                                   rec.camera, 1.5, None)
    a = refine(track, case.base, rec.camera, case.seed_T, case.seed_td)
    b = refine(clean, case.base, rec.camera, case.seed_T, case.seed_td)
    err = rotation_error_base_axes(a.R_base_cam, rec.T_base_cam[:3, :3])
    assert np.all(np.abs(err) <= 3 * np.radians(a.sigma_rot_deg))
    assert np.degrees(np.linalg.norm(rotation_error_base_axes(a.R_base_cam, b.R_base_cam))) < 0.1
    assert abs(a.td - b.td) < 1e-3


def test_an_isolated_find_of_a_slow_board_is_checked_across_the_gaps():
    """A slow board's find between gaps of 0.15 and 0.25 s (no near pair can predict it) is checked against the
    finds before and after the gaps, interpolated: shifted by a lattice step it is refused, right it is kept."""
    rng = np.random.default_rng(3)
    base = rng.uniform(50, 250, (1, 44, 2)) + np.c_[np.arange(44) % 4 * 9.0, np.arange(44) // 4 * 9.0][None]
    t = np.r_[np.arange(0.0, 0.3, 1 / 30), 0.45, np.arange(0.7, 1.0, 1 / 30)]
    uv = base + np.array([3.0, 1.0])[None, None] * t[:, None, None] + rng.normal(0, 0.2, (t.size, 44, 2))
    i = int(np.flatnonzero(t == 0.45)[0])
    assert not inconsistent_frames(t, uv).any()
    _shift_by_a_step(uv, i)
    bad = inconsistent_frames(t, uv)
    assert bad[i] and bad.sum() == 1


def _slow_lattice(rng, t: np.ndarray, unit: float = 7.0, velocity=(3.0, 1.0)) -> np.ndarray:
    """The asymmetric 4 x 11 grid's circles (label 4 i + j at ((2 j + i % 2) u, i u)) drifting at ``velocity``
    (px/s, default 3 px/s), with 0.2 px of noise: (m, 44, 2)."""
    i, j = np.divmod(np.arange(44), 4)
    grid = np.c_[(2 * j + i % 2) * unit, i * unit] + np.array([120.0, 60.0])
    drift = np.array(velocity, dtype=float)[None, None] * t[:, None, None]
    return grid[None] + drift + rng.normal(0, 0.2, (t.size, 44, 2))


@pytest.mark.parametrize("shift", [8, 4])
def test_a_run_of_frames_labelled_a_lattice_step_off_after_a_gap_is_refused(shift):
    """A slow board found again after a gap, labelled two rows (8 labels) or one row (4 labels) off, and tracked in
    that labelling for four frames: the frames vouch for each other, so only the runs' meeting across the gaps
    refuses them (study_v28 run 5: four such frames). The right labelling is kept, and so is a board that moved
    across the gap by something no lattice step is."""
    rng = np.random.default_rng(5)
    t = np.r_[np.arange(0.0, 1.0, 1 / 30), 1.25 + np.arange(4) / 30, np.arange(1.6, 2.4, 1 / 30)]
    uv = _slow_lattice(rng, t)
    run_b = (t >= 1.2) & (t < 1.5)
    assert not inconsistent_frames(t, uv).any()
    wrong = uv.copy()
    wrong[run_b] = np.nan
    wrong[np.ix_(run_b, np.arange(44 - shift))] = uv[np.ix_(run_b, np.arange(shift, 44))]  # label k shows k + shift
    bad = inconsistent_frames(t, wrong)
    np.testing.assert_array_equal(bad, run_b)
    moved = uv.copy()
    moved[t >= 1.2] += np.array([7.0, 14.0])  # a jolt across the first gap: 1.6 spacings, as far as can be from a step
    assert not inconsistent_frames(t, moved).any()


def test_runs_equally_long_in_two_labellings_are_both_refused():
    rng = np.random.default_rng(6)
    t = np.r_[np.arange(0.0, 0.1, 1 / 30), 0.3 + np.arange(3) / 30]
    uv = _slow_lattice(rng, t)
    late = t >= 0.3
    uv[np.ix_(late, np.arange(36))] = uv[np.ix_(late, np.arange(8, 44))]
    uv[np.ix_(late, np.arange(36, 44))] = np.nan
    assert inconsistent_frames(t, uv).all()


def _relabel(uv: np.ndarray, rows: np.ndarray, shift: int) -> None:
    """Frames ``rows`` labelled ``shift`` labels off: label k shows circle k + shift (unseen where none)."""
    src = np.arange(44) + shift
    ok = (src >= 0) & (src < 44)
    moved = np.full((int(np.count_nonzero(rows)), 44, 2), np.nan)
    moved[:, ok] = uv[rows][:, src[ok]]
    uv[rows] = moved


def test_two_wrong_runs_off_in_opposite_directions_are_both_refused():
    """A run four labels off, a right run, a run four labels off the other way: the two wrong runs are not in one
    labelling (a step and its inverse are not the same step), so the right run, the longest, is kept."""
    rng = np.random.default_rng(7)
    t = np.r_[np.arange(3) / 30, 0.3 + np.arange(4) / 30, 0.7 + np.arange(3) / 30]
    uv = _slow_lattice(rng, t)
    first, last = t < 0.2, t > 0.6
    _relabel(uv, first, 4)
    _relabel(uv, last, -4)
    np.testing.assert_array_equal(inconsistent_frames(t, uv), first | last)


def test_points_missing_next_to_the_gap_do_not_condemn_a_right_run():
    """A board moving one lattice vector per 0.3 s gap, with most circles unseen in the frames beside the ends of
    the gap (the speed comes from the circles seen in both frames)."""
    rng = np.random.default_rng(8)
    t = np.r_[np.arange(6) / 30, 0.5 + np.arange(6) / 30]
    uv = _slow_lattice(rng, t, velocity=(7.0 / 0.3, 7.0 / 0.3))
    uv[[4, 7], :27] = np.nan  # the second-to-last frame of the first run, the second of the next
    assert not inconsistent_frames(t, uv).any()


def test_single_frames_between_gaps_are_not_compared_without_a_speed():
    rng = np.random.default_rng(9)
    t = np.array([0.0, 0.3, 0.6])
    uv = _slow_lattice(rng, t, velocity=(7.0 / 0.3, 7.0 / 0.3))  # one lattice vector per gap
    assert not inconsistent_frames(t, uv).any()
