"""Windows missed while the robot stood still are counted as such, not as detector failures."""

from types import SimpleNamespace

import numpy as np

from plsgraph.core.tracks import BaseTrack
from plsgraph.report.coverage import STILL_HALF_S, coverage_summary, coverage_table, robot_still, window_outcomes


def _base(t: np.ndarray, x: np.ndarray, yaw: np.ndarray) -> BaseTrack:
    T = np.broadcast_to(np.eye(4), (t.size, 4, 4)).copy()
    T[:, 0, 0] = T[:, 1, 1] = np.cos(yaw)
    T[:, 0, 1], T[:, 1, 0] = -np.sin(yaw), np.sin(yaw)
    T[:, 0, 3] = x
    return BaseTrack(t, T, np.zeros((t.size, 3)), np.zeros((t.size, 3)))


def _stop_and_go(rate_hz: float = 50.0, tick_m: float = 0.0):
    """0-4 s driving at 0.3 m/s, 4-8 s standing (with an encoder's one-tick dither), 8-10 s turning at 0.5 rad/s."""
    t = np.arange(0.0, 10.0, 1.0 / rate_hz)
    x = 0.3 * np.minimum(t, 4.0)
    standing = (t >= 4.0) & (t < 8.0)
    x = x + np.where(standing, tick_m * (np.arange(t.size) % 2), 0.0)
    yaw = 0.5 * np.clip(t - 8.0, 0.0, None)
    return _base(t, x, yaw)


def test_still_only_where_the_base_neither_moves_nor_turns():
    base = _stop_and_go(tick_m=0.00038)  # one tick of a 1660-tick encoder on a 0.1 m wheel
    tq = np.arange(0.5, 9.5, 1.0 / 30.0)
    still = robot_still(tq, base)
    inner = (tq > 4.0 + STILL_HALF_S + 0.02) & (tq < 8.0 - STILL_HALF_S - 0.02)
    assert np.all(still[inner])
    assert not np.any(still[(tq < 4.0 + STILL_HALF_S - 0.02) | (tq > 8.0 - STILL_HALF_S + 0.02)])


def test_a_slow_creep_and_times_outside_the_odometry_are_not_still():
    t = np.arange(0.0, 10.0, 0.02)
    creep = _base(t, 0.005 * t, np.zeros_like(t))  # 5 mm/s: a board 1.5 m away moves ~1 px/s
    assert not np.any(robot_still(np.array([2.0, 5.0]), creep))
    standing = _base(t, np.zeros_like(t), np.zeros_like(t))
    s = robot_still(np.array([-1.0, 0.1, 5.0, 9.9, 12.0]), standing)
    assert s.tolist() == [False, False, True, False, False]


def test_missed_windows_of_a_still_robot_are_relabelled_and_counted_apart():
    base = _stop_and_go()
    tq = np.arange(0.5, 9.5, 1.0 / 30.0)
    # The front end found the board while the robot drove and turned, and nothing while it stood; one window of the
    # drive was missed by the detector.
    outcome = np.where((tq > 4.0) & (tq < 8.0), "too_few_events", "rims").astype(object)
    outcome[10] = "grid_not_found"
    outcome[int(np.argmin(np.abs(tq - 6.0)))] = "jumped_from_track"  # a board found and refused while still
    # The camera clock runs 2 s behind the odometry's: clock shift 1.5 s plus td 0.5 s.
    info = {"window_outcomes": {"t": (tq - 2.0).tolist(), "outcome": outcome.tolist()}}
    run = SimpleNamespace(base_track=base, clock_offset_s=1.5, refinement=None, closed_form=SimpleNamespace(td=0.5))
    got = window_outcomes(info, run)
    inner = (tq > 4.0 + STILL_HALF_S + 0.02) & (tq < 8.0 - STILL_HALF_S - 0.02) & (outcome == "too_few_events")
    assert np.all(got[inner] == "robot_still")
    assert got[10] == "grid_not_found"  # a miss while moving stays a miss
    assert got[int(np.argmin(np.abs(tq - 6.0)))] == "jumped_from_track"  # a refusal stays a refusal
    assert np.all(got[outcome == "rims"] == "rims")  # a find is never relabelled
    # A converged refinement's td is the one used (here the same offset, split differently).
    refined = SimpleNamespace(base_track=base, clock_offset_s=1.5, refinement=SimpleNamespace(converged=True, td=0.5),
                              closed_form=SimpleNamespace(td=-3.0))
    assert np.array_equal(window_outcomes(info, refined), got)
    cov = coverage_summary(info, run)
    assert cov["windows"] == tq.size and cov["found"] == int(np.sum(outcome == "rims"))
    assert cov["robot_still"] == int(np.sum(got == "robot_still"))
    moving = cov["windows"] - cov["robot_still"]
    assert cov["found_fraction_robot_moving"] == cov["found"] / moving
    assert "the robot stood still" in coverage_table(info, run)
    # Without the odometry (or with the wrong clock) nothing is relabelled.
    assert "robot_still" not in coverage_summary(info)["by_outcome"]
    wrong_clock = SimpleNamespace(base_track=base, clock_offset_s=0.0, refinement=None,
                                  closed_form=SimpleNamespace(td=0.0))
    assert np.sum(window_outcomes(info, wrong_clock) == "robot_still") < np.sum(got == "robot_still")


def test_windows_passed_over_while_lost_are_named_after_the_detectors_reasons():
    """The summary line and the HTML table list the detector's reasons for a miss first and the windows passed over
    while the board was lost (not searched, track.LOST_SEARCH_STRIDE) after them, under their own name."""
    from plsgraph.frontend.track import REASON_NOT_SEARCHED
    from plsgraph.report.coverage import NOT_SEARCHED
    from plsgraph.report.output import coverage_line

    assert NOT_SEARCHED == REASON_NOT_SEARCHED
    outcome = ["rims"] * 10 + [NOT_SEARCHED] * 40 + ["grid_not_found"] * 20 + ["too_few_points"] * 5
    info = {"window_outcomes": {"t": list(np.arange(len(outcome)) / 30.0), "outcome": outcome}}
    cov = coverage_summary(info)
    assert cov["by_outcome"][NOT_SEARCHED] == 40 and cov["found"] == 10
    line = coverage_line(cov)
    assert line.index("grid_not_found 20") < line.index("too_few_points 5") < line.index(f"{NOT_SEARCHED} 40")
    table = coverage_table(info)
    assert table.index("missed: grid_not_found") < table.index("not searched: the board was lost")


def test_missed_windows_the_odometry_does_not_reach_are_not_counted_as_the_moving_robots():
    base = _stop_and_go()  # odometry over 0-10 s (its last sample at 9.98 s)
    tq = np.arange(-3.0, 13.0, 1.0 / 30.0)  # the events run 3 s longer on either side
    outcome = np.where((tq > 1.0) & (tq < 3.0), "rims", "grid_not_found").astype(object)
    outcome[np.argmin(np.abs(tq + 2.0))] = "rims"  # a find outside the odometry stays a find
    info = {"window_outcomes": {"t": tq.tolist(), "outcome": outcome.tolist()}}
    run = SimpleNamespace(base_track=base, clock_offset_s=0.0, refinement=None, closed_form=SimpleNamespace(td=0.0))
    got = window_outcomes(info, run)
    outside = (tq < base.t[0]) | (tq > base.t[-1])  # inside, a window near an end is the moving robot's
    assert np.all(got[outside & (outcome != "rims")] == "no_odometry")
    assert not np.any(got[~outside] == "no_odometry") and got[np.argmin(np.abs(tq + 2.0))] == "rims"
    cov = coverage_summary(info, run)
    moving = cov["windows"] - cov["robot_still"] - cov["no_odometry"]
    assert cov["no_odometry"] == int(np.sum(got == "no_odometry")) > 0
    assert cov["found_fraction_robot_moving"] == cov["found"] / moving
    assert "the odometry says nothing of the robot" in coverage_table(info, run)
    # On a clock the odometry does not share (two files not yet aligned): no window is the moving robot's, and the
    # summary line says nothing of a moving robot.
    from plsgraph.report.output import coverage_line

    far = {"window_outcomes": {"t": (tq + 1.7e9).tolist(), "outcome": ["grid_not_found"] * tq.size}}
    cov = coverage_summary(far, run)
    assert cov["no_odometry"] == tq.size and cov["found_fraction_robot_moving"] is None
    assert "moved" not in coverage_line(cov)


def test_windows_on_a_second_files_clock_never_aligned_keep_the_detectors_reasons():
    """Before: with the odometry from a second file whose clock was never aligned (the run ended first), the windows
    the odometry happened to span were called the moving robot's ('1 of 30 windows, 20 % of those in which the robot
    moved') and the detector's reasons for the rest were replaced by no_odometry."""
    from plsgraph.options import CalibrationOptions
    from plsgraph.report.output import coverage_line

    base = _stop_and_go()
    tq = np.arange(8.0, 12.0, 1.0 / 30.0)  # partly inside the odometry's span, by chance of the two clocks
    outcome = np.where(tq < 8.5, "rims", "grid_not_found").astype(object)
    info = {"window_outcomes": {"t": tq.tolist(), "outcome": outcome.tolist()}}
    opts = CalibrationOptions.build(board="acircles_4x11_a2", odometry_file="/elsewhere/robot.bag")
    run = SimpleNamespace(base_track=base, clock_offset_s=0.0, refinement=None, closed_form=None, options=opts,
                          recording_info={})
    assert list(window_outcomes(info, run)) == list(outcome)  # the front end's own outcomes
    cov = coverage_summary(info, run)
    assert cov["clocks_not_aligned"] and cov["found_fraction_robot_moving"] is None and cov["no_odometry"] == 0
    line = coverage_line(cov)
    assert "not aligned" in line and "moved" not in line and "grid_not_found" in line
    run.recording_info = {"clock": {"coarse": True, "offset_s": 0.0}}  # once aligned, the odometry counts again
    assert "clocks_not_aligned" not in coverage_summary(info, run)
    run.recording_info = {}  # the user said one clock (--clock-align never): the odometry counts
    run.options = CalibrationOptions.build(board="acircles_4x11_a2", odometry_file="/elsewhere/robot.bag",
                                           clock_align="never")
    assert "clocks_not_aligned" not in coverage_summary(info, run)
