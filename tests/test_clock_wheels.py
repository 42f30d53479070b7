"""Two clocks and the wheel order, at the track level (simulated tracks, no events): fast."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plsgraph.calib.clock import align_clocks, masked_ncc
from plsgraph.core.board import load_board
from plsgraph.core.geometry import inv_T, rotation_error_deg
from plsgraph.core.tracks import CameraTrack
from plsgraph.errors import ClockAlignmentError, InputError
from plsgraph.odometry.wheel_order import HYPOTHESES, WheelSignals, check_wheel_order, orientation_problem
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.options import CalibrationOptions
from plsgraph.pairing import coarse_rule, pair_tracks
from plsgraph.pipeline import Run, solve
from plsgraph.result import calibration_result
from plsgraph.sim.robot import simulate_robot

EPOCH = 1_767_225_600.0  # 2026: float seconds at this size keep 0.24 µs
DIFF = 3725.4


@pytest.fixture(scope="module")
def sim():
    return simulate_robot(motion="rich", duration=12, seed=3, td=0.03, board=load_board("acircles_4x11_a2"))


def _cam(sim, t_shift=EPOCH):
    c = sim.camera_track()
    return CameraTrack(c.t + t_shift, c.T_board_cam, cov=c.cov)


def _wheels(sim, hypothesis="as_given", t_shift=EPOCH + DIFF):
    w = WheelSignals(sim.wheel_t + t_shift, sim.wheel_left, sim.wheel_right, "position", sim.wheel_radius,
                     sim.track_width)
    lft, rgt = w.under(hypothesis)  # what a mis-wired robot hands over
    return WheelSignals(w.t, lft, rgt, "position", w.wheel_radius, w.track_width)


def test_masked_ncc_finds_a_known_lag_across_a_gap():
    rng = np.random.default_rng(0)
    b = np.convolve(rng.normal(size=600), np.ones(5) / 5, mode="same")
    a = b[137:337].copy()  # a[i] = b[i + 137]
    ma = np.ones(a.size, bool)
    ma[50:80] = False
    a[50:80] = 1e6  # masked samples must not count
    k, r, n = masked_ncc(a, ma, b, np.ones(b.size, bool))
    good = n >= 150
    assert k[good][np.argmax(r[good])] == 137
    assert r[good].max() == pytest.approx(1.0, abs=1e-9)


def test_coarse_alignment_recovers_an_hour_clock_difference(sim):
    base = _wheels(sim).base_track()
    res = align_clocks(_cam(sim), base)
    # The coarse step finds the clock difference plus the true td to within a grid step (40 ms at 25 Hz).
    assert res.offset_s == pytest.approx(DIFF + sim.td, abs=0.02)
    assert res.ok and res.score > 0.9
    assert res.second_peak_ratio < 0.8 or res.separation > 4


def test_coarse_alignment_refuses_periodic_motion():
    # The same 4 s pattern again and again: every period fits as well as the true one.
    t = np.arange(0, 60, 0.02)
    phase = 2 * np.pi * t / 4.0
    left = np.cumsum(4 + 3 * np.sin(phase)) * 0.02
    right = np.cumsum(4 - 3 * np.sin(phase)) * 0.02
    base = base_track_from_wheels(t + 500.0, left, right)
    T_bc = np.eye(4)
    T_bc[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    tc = np.arange(20, 40, 1 / 30)
    T_board_cam = base.poses_at(tc + 500.0) @ T_bc
    cam = CameraTrack(tc, np.einsum("ij,njk->nik", inv_T(T_board_cam[0]), T_board_cam))
    with pytest.raises(ClockAlignmentError, match="ambiguous|--clock-offset"):
        align_clocks(cam, base)


@pytest.mark.parametrize("wired", HYPOTHESES)
@pytest.mark.parametrize("window", [(DIFF - 0.5, DIFF + 0.5), None], ids=["same-clock", "any-offset"])
def test_wheel_order_is_found_from_the_camera(sim, wired, window):
    chk = check_wheel_order(_cam(sim), _wheels(sim, wired), window)
    assert chk.decided
    assert chk.hypothesis == wired  # each corruption is its own inverse: applying it again repairs the wheels
    assert chk.up_component < -0.5  # the default camera is upright
    assert chk.turn_scale == pytest.approx(1.0, abs=0.05)
    if window is None:
        assert chk.alignment.offset_s == pytest.approx(DIFF + sim.td, abs=0.02)


def test_a_drive_without_turns_leaves_the_wheel_order_undecided_not_corrected():
    """Before: on a straight drive the sign came from the turn-rate noise (correlation 0.21) and the wheels as named
    were 'corrected' to swapped, with a warning that sent the user rewiring correct wheels."""
    sim = simulate_robot(motion="straight", duration=12, seed=1, td=0.03, board=load_board("acircles_4x11_a2"))
    for wired in ("as_given", "swapped"):
        chk = check_wheel_order(_cam(sim), _wheels(sim, wired), (DIFF - 0.5, DIFF + 0.5))
        assert not chk.decided and chk.hypothesis == "as_given", wired
        assert "hardly turns" in chk.message and chk.turn_correlation < 0.5


def test_upside_down_flag_reverses_the_sign_decision(sim):
    chk = check_wheel_order(_cam(sim), _wheels(sim, "as_given"), None, upside_down_camera=True)
    assert chk.hypothesis == "swapped"  # only swapped wheels make this (upright) camera come out upside down


def test_orientation_problem():
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # optical frame, upright
    flip = np.diag([1.0, -1.0, -1.0])  # rolled 180 deg about the base x axis
    assert orientation_problem(R) is None
    assert "upside down" in orientation_problem(flip @ R)
    assert orientation_problem(flip @ R, upside_down_camera=True) is None
    assert "upright" in orientation_problem(R, upside_down_camera=True)


def _run(sim, wired, **opts):
    options = CalibrationOptions.build(board="acircles_4x11_a2", wheel_radius=sim.wheel_radius,
                                       track_width=sim.track_width, **opts)
    wheels = _wheels(sim, wired)
    run = Run(Path("<sim>"), options, board=load_board("acircles_4x11_a2"), camera=sim.camera,
              camera_track=_cam(sim), base_track=wheels.base_track(), wheels=wheels,
              truth={"T_base_cam": sim.T_base_cam, "td": sim.td + DIFF})
    run.recording_info["base_source"] = "sim wheels"
    return run


@pytest.mark.parametrize("wired", ["swapped", "left_reversed"])
def test_wrong_wheels_are_corrected_and_said(sim, wired, caplog):
    import logging

    from plsgraph.pipeline import say_wheel_track_warnings

    # another file: the coarse step runs; the mount said (swapped wheels are corrected only for a camera said upright)
    run = _run(sim, wired, odometry_file="odometry.mcap", upright_camera=True)
    # What the wheels as named said about their own track (as the pipeline passes it on) is not the corrected one's.
    named = "4 odometry step(s) imply more than 3.0 m/s or 6.0 rad/s (first at t=2.000 s); treated as resets"
    run.base_track.info["warnings"].append(named)
    run.warn(named)
    assert coarse_rule(run)[0]
    pair_tracks(run)
    assert named not in run.warnings
    with caplog.at_level(logging.WARNING, logger="plsgraph"):  # nor in the console, where the pipeline says them
        say_wheel_track_warnings(run)
    assert named not in caplog.text
    assert all(w in caplog.text for w in run.base_track.info.get("warnings", []))
    res = calibration_result(solve(run, refine=False))
    assert res.ok, res.problems
    assert rotation_error_deg(res.R_base_cam, sim.R_base_cam) < 2.0
    assert res.time_offset_s == pytest.approx(DIFF + sim.td, abs=0.01)
    c = res.report["calibration"]
    assert c["wheel_order"]["hypothesis"] == wired and c["wheel_order"]["corrected"]
    assert c["clock_alignment"]["coarse"] and c["clock_alignment"]["offset_s"] == pytest.approx(DIFF + sim.td, abs=0.02)
    assert any("corrected" in w for w in res.warnings)


def _upside_down(sim, t_shift=EPOCH):
    """The camera track of the same drive with the camera rolled 180 deg about its optical axis (mounted upside down),
    and that mount's T_base_cam: what a recording of the upside-down camera gives (the same images turned over)."""
    c = sim.camera_track()
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    d = np.diag([-1.0, -1.0, 1.0, -1.0, -1.0, 1.0])  # the pose covariance's x and y components (turn and move) flip
    cov = None if c.cov is None else d @ c.cov @ d
    return CameraTrack(c.t + t_shift, c.T_board_cam @ flip, cov=cov), sim.T_base_cam @ flip


def test_swapped_wheels_with_the_mount_unsaid_are_corrected_but_flagged(sim):
    """Swapped wheels under an upright camera fit the camera's motion exactly as the wheels as named under an
    upside-down camera do: unless the user says how the camera is mounted, the corrected result is flagged."""
    from plsgraph.pairing import MOUNT_OR_SWAP_PROBLEM

    run = _run(sim, "swapped", clock_offset=DIFF)
    pair_tracks(run)
    assert run.recording_info["wheel_order"]["corrected"] and run.recording_info["wheel_order"]["mount_unstated"]
    res = calibration_result(solve(run, refine=False))
    assert not res.ok and MOUNT_OR_SWAP_PROBLEM in res.problems
    assert "--upright-camera" in MOUNT_OR_SWAP_PROBLEM and "--upside-down-camera" in MOUNT_OR_SWAP_PROBLEM
    assert rotation_error_deg(res.R_base_cam, sim.R_base_cam) < 2.0  # the result is the swapped-wheels one


@pytest.mark.parametrize("wired", ["as_given", "left_reversed"])
@pytest.mark.parametrize("said", [None, "upside_down_camera", "upright_camera"])
def test_an_upside_down_camera_never_passes_as_its_mirror(sim, said, wired):
    """The camera mounted upside down, the wheels as named (or the left one counting backwards): before the mount
    could be said, the wheel check took the camera for upright, 'corrected' the wheels to swapped (or took the right
    wheel for the reversed one) and passed (exit 0) a result 180 deg off."""
    from plsgraph.pairing import mount_problem

    cam, T_true = _upside_down(sim)
    run = _run(sim, wired, clock_offset=DIFF, **({said: True} if said else {}))
    run.camera_track = cam
    run.truth = {"T_base_cam": T_true, "td": sim.td + DIFF}
    pair_tracks(run)
    res = calibration_result(solve(run, refine=False))
    err = rotation_error_deg(res.R_base_cam, T_true[:3, :3])
    mirror = {"as_given": "swapped", "left_reversed": "right_reversed"}[wired]
    wo = res.report["calibration"]["wheel_order"]
    if said == "upside_down_camera":  # said right: the wheels as they are wired, the right answer
        assert wo["hypothesis"] == wired
        assert res.ok, res.problems
        assert err < 2.0
    elif said is None:  # unsaid: the mirror, flagged with the problem that says what to give
        assert wo["hypothesis"] == mirror and wo["mount_unstated"]
        assert err > 170.0
        assert not res.ok and mount_problem(mirror) in res.problems, res.problems
        assert "--upright-camera" in mount_problem(mirror) and "--upside-down-camera" in mount_problem(mirror)
    else:  # said wrong: the user's word is taken, the mirror of the truth
        assert wo["hypothesis"] == mirror and not wo.get("mount_unstated", True)
        assert err > 170.0


def test_the_two_mounts_cannot_both_be_said_and_a_later_one_replaces_the_earlier():
    with pytest.raises(InputError, match="upright-camera"):
        CalibrationOptions.build(upright_camera=True, upside_down_camera=True)
    with pytest.raises(InputError, match="true or false"):
        CalibrationOptions.build(upright_camera="no")
    batch = CalibrationOptions.build(upright_camera=True)  # a batch's flag, then a recording's options file
    own = CalibrationOptions.build(batch, upside_down_camera=True)
    assert own.mount.upside_down_camera and not own.mount.upright_camera
    assert CalibrationOptions.build(batch, wheel_radius=0.1).mount.upright_camera  # unsaid there: the batch's


def test_swapped_wheels_never_pass_silently(sim):
    # flag: kept as named, the result is flagged; off: not checked, the mirrored (upside-down) camera is a problem.
    for mode, expect in (("flag", "not corrected"), ("off", "upside down")):
        run = _run(sim, "swapped", wheel_order=mode, clock_offset=DIFF)
        pair_tracks(run)
        res = calibration_result(solve(run, refine=False))
        assert not res.ok
        assert any(expect in p for p in res.problems), res.problems


def test_same_clock_single_file_is_unchanged(sim):
    run = _run(sim, "as_given")
    run.base_track = _wheels(sim, t_shift=EPOCH).base_track()
    run.wheels = _wheels(sim, t_shift=EPOCH)
    coarse, why = coarse_rule(run)
    assert not coarse and "same clock" in why
    pair_tracks(run)
    assert run.clock_offset_s == 0.0
    assert run.recording_info["wheel_order"]["hypothesis"] == "as_given"


def test_option_checks():
    with pytest.raises(InputError, match="clock_align"):
        CalibrationOptions.build(clock_align="sometimes")
    with pytest.raises(InputError, match="wheel_order"):
        CalibrationOptions.build(wheel_order="guess")
    with pytest.raises(InputError, match="child_frame"):
        CalibrationOptions.build(child_frame="my camera")


def test_a_clock_offset_that_leaves_the_two_spans_apart_is_refused_with_its_sign_named(sim):
    """Before: --clock-offset with the wrong sign ran to a diagnosis advising to record longer and drive more."""
    from plsgraph.errors import InputError

    run = _run(sim, "as_given", clock_offset=-DIFF)
    with pytest.raises(InputError, match=r"--clock-offset -3725.4 s .* do not overlap .* its sign"):
        pair_tracks(run)
    run = _run(sim, "as_given", clock_offset=DIFF)
    pair_tracks(run)  # the right one
    assert run.clock_offset_s == DIFF
    # --clock-align never with the clocks an hour apart: refused the same way (before: exit 1, a diagnosis that
    # advised recording longer and driving forwards and backwards).
    run = _run(sim, "as_given", clock_align="never")
    with pytest.raises(InputError, match=r"--clock-align never the two clocks are taken as one, but .* do not "
                                         r"overlap .*--clock-align auto or always"):
        pair_tracks(run)
