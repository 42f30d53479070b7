"""No confident wrong answer, no mixed or stale result files (scripts/adversarial.py reruns the same cases on the
sample recording through the command line). Here: simulated tracks, no events, so each case costs a second or two."""

import contextlib
import dataclasses
import json
import logging
import os
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

import plsgraph
from plsgraph.batch import _batch_item
from plsgraph.cli.main import main
from plsgraph.core.board import Board, load_board
from plsgraph.core.geometry import so3_log
from plsgraph.errors import InputError, InsufficientDataError, PlsgraphError
from plsgraph.frontend.pose import camera_track_from_detections
from plsgraph.gate import problems_of, upside_down_problems
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.options import CalibrationOptions
from plsgraph.report.files import OutputLock, prepare_output_dir
from plsgraph.report.output import write_calibration, write_result_folder
from plsgraph.sim.robot import simulate_robot

BOARD = "acircles_4x11_a2"


@pytest.fixture(scope="module")
def sim():
    s = simulate_robot("rich", duration=10.0, seed=3, td=0.03, realism="ideal")
    cam = camera_track_from_detections(s.detections(noise_px=0.3, seed=4), s.camera)
    return s, cam


def _calibrate(sim, radius=1.0, track=1.0, cut=None, swap=False, kind="position"):
    s, cam = sim
    keep = np.ones(s.wheel_t.size, dtype=bool)
    if cut is not None:
        rel = s.wheel_t - s.wheel_t[0]
        keep = ~((rel > cut[0]) & (rel < cut[1]))
    left, right = (s.wheel_right, s.wheel_left) if swap else (s.wheel_left, s.wheel_right)
    if kind == "velocity":  # a driver that publishes wheel rates only: nothing is known across a gap
        t = s.wheel_t
        left, right = np.gradient(left, t), np.gradient(right, t)
    base = base_track_from_wheels(s.wheel_t[keep], left[keep], right[keep], s.wheel_radius * radius,
                                  s.track_width * track, kind=kind)
    truth = {"T_base_cam": s.T_base_cam.tolist(), "td": s.td}
    return plsgraph.calibrate_tracks(cam, base, s.camera, board=BOARD, truth=truth)


# ---------------------------------------------------------------------------------------------- the gate


def test_right_settings_pass_the_gate(sim):
    r = _calibrate(sim)
    assert r.ok and not r.problems
    assert r.report["calibration"]["ok"] is True
    assert r.report["calibration"]["ros_static_transform"].startswith("ros2 run")


def _right_or_flagged(r, s, what: str) -> None:
    """The rule: a result is either right within its sigma (and carries the robot's effective geometry) or flagged
    with a problem naming ``what``."""
    if r.ok:
        d_rot = so3_log(r.T_base_cam[:3, :3] @ s.T_base_cam[:3, :3].T)  # about the base axes, as the covariance
        err = np.r_[d_rot, r.T_base_cam[:2, 3] - s.T_base_cam[:2, 3], r.time_offset_s - s.td]
        sig = np.sqrt(np.diag(r.covariance))[[0, 1, 2, 3, 4, 6]]
        assert np.all(np.abs(err) <= 3 * sig), (err, sig)
        odo = r.report["calibration"]["odometry"]
        assert odo["wheel_radius_m"] == pytest.approx(s.wheel_radius, rel=0.01)
        assert odo["track_width_m"] == pytest.approx(s.track_width, rel=0.02)
        assert "0.75 % for the event detector" in odo["note"]  # the radius's model floor is said where it is used
    else:
        assert any(what in p for p in r.problems), r.problems


@pytest.mark.parametrize("setting, factor, mention, flagged", [
    ("radius", 1.15, "wheel-radius", True),  # as likely a misprinted board as a wrong radius
    ("radius", 1.05, "wheel-radius", False),  # a few per cent: estimated and applied
    ("track", 2.0, "track-width", True),  # a nominal track twice the effective one: no robot's
    ("track", 0.5, "track-width", False),  # half: what a skid-steer robot shows
])
def test_wrong_odometry_geometry_is_estimated_or_flagged(sim, setting, factor, mention, flagged):
    # Before: exit 0 with yaw 7-18 deg (radius) or x/y 0.5-0.7 m (track) off and a confident sigma. The refinement
    # now estimates the effective radius and track: plausible errors are corrected, implausible ones flagged.
    r = _calibrate(sim, **{setting: factor})
    _right_or_flagged(r, sim[0], mention)
    if flagged:
        assert not r.ok


def test_a_wrong_wheel_radius_names_the_likely_one(sim):
    r = _calibrate(sim, radius=1.15)
    text = " ".join(r.problems)
    assert "suggests 0.09" in text  # the nominal 0.098 m, as the closed form estimates it


def test_swapped_wheels_never_pass(sim):
    try:
        r = _calibrate(sim, swap=True)
    except PlsgraphError as exc:  # refused outright is fine too
        assert "wheel" in str(exc)
        return
    assert not r.ok


def test_an_upside_down_camera_is_a_problem_unless_allowed():
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # camera y (down in the image) -> base +z
    assert upside_down_problems(T, allow=False)
    assert not upside_down_problems(T, allow=True)
    assert any("upside down" in p for p in problems_of(None, None, T_base_cam=T))


def test_refined_far_from_closed_form_is_named_per_quantity(sim):
    from dataclasses import replace

    from plsgraph.core.geometry import so3_exp

    r = _calibrate(sim)
    cf = r.run.closed_form
    ref = replace(r.run.refinement, td_searched=None)  # td judged against the closed form's, not a searched one
    far = replace(cf, R_base_cam=so3_exp(np.array([0.0, 0.0, 0.3])) @ cf.R_base_cam, td=ref.td + 0.2)
    text = " ".join(problems_of(far, ref))
    assert "refined rotation" in text and "refined time offset" in text and "closed form" in text
    assert not any("refined rotation" in p for p in problems_of(cf, ref))


def _bent(ref, turn: float = 1.0, length: float = 1.0):
    """``ref`` with its knots' heading changes scaled by ``turn`` and their steps by ``length`` (tilt kept)."""
    from dataclasses import replace

    Tk = np.array(ref.T_world_base, dtype=float)
    yaw = np.unwrap(np.arctan2(Tk[:, 1, 0], Tk[:, 0, 0]))
    d = yaw[0] + turn * (yaw - yaw[0]) - yaw
    c, s = np.cos(d), np.sin(d)
    Rz = np.zeros((len(d), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    Tk[:, :3, :3] = Rz @ Tk[:, :3, :3]
    Tk[:, :2, 3] = Tk[0, :2, 3] + length * (Tk[:, :2, 3] - Tk[0, :2, 3])
    return replace(ref, T_world_base=Tk)


def _ratio(texts, pattern: str) -> float | None:
    """The x<number> of the first text matching ``pattern`` (a regex with one group for the number)."""
    import re

    for t in texts:
        m = re.search(pattern, t)
        if m:
            return float(m.group(1))
    return None


def test_a_path_bent_beyond_the_estimated_track_is_a_warning_up_to_the_gross_limit(sim):
    # With the odometry's radius and track estimated, a refined path that turns a few per cent less (or runs a few
    # per cent longer) than the scaled odometry is slip one effective track and radius do not describe: a warning;
    # far beyond, a problem. Without estimated scales the strict limits stay problems.
    from dataclasses import replace

    from plsgraph.gate import path_warnings

    r = _calibrate(sim)
    cf, ref, base = r.run.closed_form, r.run.refinement, r.run.base_track
    turns, longer = r"turns x(\d\.\d+)", r"is x(\d\.\d+) as long"
    assert not any("refined path" in p for p in problems_of(cf, ref, base_track=base))
    assert not path_warnings(ref, base)
    bent = _bent(ref, turn=0.9)
    assert not any("refined path" in p or "odometry's turns" in p for p in problems_of(cf, bent, base_track=base))
    (w,) = path_warnings(bent, base)
    assert _ratio([w], turns) == pytest.approx(0.9, abs=0.005) and "slip" in w and "track width" in w
    far = problems_of(cf, _bent(ref, turn=0.6), base_track=base)
    assert _ratio(far, turns) == pytest.approx(0.6, abs=0.005)
    stretched = _bent(ref, length=1.04)
    (w,) = path_warnings(stretched, base)
    assert _ratio([w], longer) == pytest.approx(1.04, abs=0.005) and "wheel radius" in w
    assert not any("refined path" in p for p in problems_of(cf, stretched, base_track=base))
    assert _ratio(problems_of(cf, _bent(ref, length=1.2), base_track=base), longer) == pytest.approx(1.2, abs=0.005)
    plain = replace(bent, odometry={})  # no estimated scales: the odometry's own turns must hold
    assert _ratio(problems_of(cf, plain, base_track=base), r"turns by x(\d\.\d+)") == pytest.approx(0.9, abs=0.005)
    assert not path_warnings(plain, base)
    broken = replace(bent, odometry={**bent.odometry, "turn_scale": None})  # no usable estimate: nothing to divide
    assert path_warnings(broken, base) == [] and isinstance(problems_of(cf, broken, base_track=base), list)


def test_turn_dependent_slip_is_warned_not_flagged():
    # A skid-steer robot whose wheels slip more the faster it turns: no single effective track describes its turns,
    # and the refined path turned 4.5 % less than the scaled odometry. This used to flag the run (limit 3 %) with a
    # message blaming --track-width, although the result is right within its sigmas.
    import dataclasses

    from plsgraph.sim import realism as R

    base = R.ideal()
    robot = dataclasses.replace(base.robot, slip_sigma=0.04, slip_turn_gain=4.0, slip_tau_s=0.7, track_ratio=1.5)
    s = simulate_robot("rich", duration=20.0, seed=4, td=0.03, realism=dataclasses.replace(base, robot=robot))
    cam = camera_track_from_detections(s.detections(noise_px=0.3, seed=104), s.camera)
    odo = base_track_from_wheels(s.wheel_t, s.wheel_left, s.wheel_right, s.wheel_radius, s.track_width)
    r = plsgraph.calibrate_tracks(cam, odo, s.camera, board=BOARD, truth={"T_base_cam": s.T_base_cam.tolist(),
                                                                           "td": s.td})
    assert any("refined path turns" in w and "slip" in w for w in r.warnings), r.warnings
    assert r.ok, r.problems
    d_rot = so3_log(r.T_base_cam[:3, :3] @ s.T_base_cam[:3, :3].T)
    err = np.r_[d_rot, r.T_base_cam[:2, 3] - s.T_base_cam[:2, 3], r.time_offset_s - s.td]
    sig = np.sqrt(np.diag(r.covariance))[[0, 1, 2, 3, 4, 6]]
    assert np.all(np.abs(err) <= 3 * sig), (err, sig)


def test_a_wrong_turn_angle_search_does_not_flag_a_refinement_that_came_back(sim, monkeypatch):
    # The turn-angle search replaces the closed form's td when they differ by more than 20 ms. On three runs of the
    # second validation study the search's peak was the wrong one (61-275 ms off), the refinement started there and
    # came back to within 10 ms of the truth, next to the closed form's td; the gate then compared the refined td
    # with the search's and flagged the run. Here the search is made to return a peak 150 ms off.
    import plsgraph.refine.graph as graph

    r0 = _calibrate(sim)  # the real search: it replaced the closed form's td, and the refinement stayed near it
    assert r0.run.refinement.td_searched is not None and r0.ok
    monkeypatch.setattr(graph, "turn_angle_td_search", lambda cam, base, td0, half, **kw: (td0 + 0.15, 1.0, 0.1, 0.1))
    r = _calibrate(sim)
    s = sim[0]
    assert r.run.refinement.td_searched is None  # the closed form's td is the reference again
    assert abs(r.time_offset_s - s.td) < 3 * np.sqrt(r.covariance[6, 6])
    assert r.ok, r.problems
    # 150 ms off against a td sigma of a few ms: the data do not favour the search's peak (and say by how much).
    assert any(re.search(r"nearer the closed form's; the search's peak lies \d+ ms, \d+\.\d sigma from the "
                         r"refined td", w) for w in r.warnings), r.warnings
    assert not any("wrong correlation peak" in w for w in r.warnings)  # the closed form is not blamed


def test_a_refinement_far_from_both_td_seeds_is_flagged_without_the_rotation_check(sim, monkeypatch):
    # Closed form 80 ms off, search 200 ms beyond it: the refinement finds the truth, nearer the closed form's td but
    # far outside what their sigmas allow. It agrees with neither: td is flagged against the closed form's, and the
    # closed form's rotation (solved at a td that far off) is not used as a reference.
    import plsgraph.calib.closed_form as closed_form
    import plsgraph.refine.graph as graph

    s = sim[0]
    plain = closed_form.calibrate_closed_form
    monkeypatch.setattr(closed_form, "calibrate_closed_form",
                        lambda cam, base, *a, **kw: plain(cam, base, *a, **{**kw, "td": s.td + 0.08}))
    monkeypatch.setattr(graph, "turn_angle_td_search", lambda cam, base, td0, half, **kw: (td0 + 0.2, 1.0, 0.1, 0.1))
    r = _calibrate(sim)
    ref = r.run.refinement
    assert abs(ref.td - s.td) < 3 * np.sqrt(r.covariance[6, 6])
    assert not r.ok and any("time offset" in p and "closed form's" in p for p in r.problems)
    assert set(ref.disagreement) <= {"td"}  # no roll/pitch/yaw against the closed form solved 80 ms off
    assert any("agrees with neither" in w for w in r.warnings)


# ---------------------------------------------------------------------------------------------- gaps


def test_an_odometry_gap_is_cut_not_interpolated(sim):
    # Before: the odometry was integrated across the gap as one arc and the result kept ok: true with no word of it.
    # Integrated wheel rates know nothing of the motion across the gap: it is cut.
    r = _calibrate(sim, cut=(2.0, 3.0), kind="velocity")
    disc = r.report["discarded"]
    assert disc["odometry_gaps_crossed_by_motion"] and disc["kept_segment_s"]
    assert any("gap" in w and "longest stretch" in w for w in r.warnings)
    assert not len(r.run.base_track.info["gaps"])  # what was calibrated has no gap left
    if r.ok:  # from the good stretch: a right answer
        assert r.truth_errors["refined.rot_err_deg"] < 1.5
        assert r.truth_errors["refined.t_xy_err_m"] < 0.03


@pytest.mark.parametrize("cut", [(2.0, 2.5), (5.0, 5.6)])
def test_a_short_gap_in_wheel_angles_is_bridged_and_every_other_frame_used(sim, cut):
    # Before: a 0.5 s stall of the wheel messages kept only the longest stretch without it (on the independent
    # generator's level-2 recordings 250-303 of ~500 frames). Wheel angles are cumulative, so the motion across the
    # gap is known as a whole: the recording is kept, frames near the gap are dropped, the edge across it is loose.
    r = _calibrate(sim, cut=cut)
    disc = r.report["discarded"]
    assert disc["odometry_gaps_bridged"] and "kept_segment_s" not in disc
    assert any("bridged" in w for w in r.warnings) and not any("longest stretch" in w for w in r.warnings)
    assert r.ok, r.problems
    full = _calibrate(sim)
    gap_s = cut[1] - cut[0]
    lost = full.run.refinement.n_frames - r.run.refinement.n_frames
    assert 0 < lost <= 30 * (gap_s + 0.5)  # the gap and a margin on each side, at 30 Hz
    s = sim[0]
    d_rot = so3_log(r.T_base_cam[:3, :3] @ s.T_base_cam[:3, :3].T)
    err = np.r_[d_rot, r.T_base_cam[:2, 3] - s.T_base_cam[:2, 3], r.time_offset_s - s.td]
    sig = np.sqrt(np.diag(r.covariance))[[0, 1, 2, 3, 4, 6]]
    assert np.all(np.abs(err) <= 3 * sig), (err, sig)
    assert r.truth_errors["refined.rot_err_deg"] < 1.0


def test_a_cut_track_keeps_the_front_ends_per_detection_lists_with_its_detections():
    """A review: cutting the camera track at a gap sliced its frames but not info["span_windows"] / ["detector"] /
    ["window_t"], whose lengths then no longer matched and the refinement's span and detector filters were skipped
    without a word."""
    from plsgraph.core.tracks import CameraTrack, Detections
    from plsgraph.gaps import _slice_camera

    n = 10
    t = 0.1 * np.arange(n)
    pts = np.c_[np.random.default_rng(0).uniform(size=(5, 2)), np.zeros(5)]
    info = {"span_windows": [float(i) for i in range(n)], "detector": ["rims", "blobs"] * 5,
            "window_t": list(t + 0.01), "kind": "polarity"}
    track = CameraTrack(t, np.repeat(np.eye(4)[None], n, axis=0), detections=Detections(t, np.zeros((n, 5, 2)), pts),
                        info=info)
    keep = np.arange(n) % 3 != 0
    cut = _slice_camera(track, keep)
    assert len(cut) == len(cut.detections) == keep.sum()
    for key in ("span_windows", "detector", "window_t"):
        assert cut.info[key] == [v for v, k in zip(info[key], keep, strict=True) if k]
    assert cut.info["kind"] == "polarity" and track.info["span_windows"] == info["span_windows"]  # a copy


def test_a_long_gap_or_a_jump_in_one_is_not_bridged():
    from plsgraph.gaps import MAX_BRIDGE_S, bridgeable

    t = np.r_[np.arange(0, 5, 0.02), np.arange(5 + MAX_BRIDGE_S + 0.1, 10, 0.02)]
    ang = 5.0 * t  # both wheels: straight driving
    base = base_track_from_wheels(t, ang, ang)
    g = [(float(a), float(b)) for a, b in base.info["gaps"]]
    assert g and not bridgeable(base, g)
    t2 = np.r_[np.arange(0, 5, 0.02), np.arange(5.5, 10, 0.02)]
    ang2 = 5.0 * t2
    ok = base_track_from_wheels(t2, ang2, ang2)
    g2 = [(float(a), float(b)) for a, b in ok.info["gaps"]]
    assert bridgeable(ok, g2)
    ang3 = np.where(t2 >= 5.5, ang2 + 300.0, ang2)  # the wheels' counters reset in the gap: its motion is lost
    reset = base_track_from_wheels(t2, ang3, ang3)
    assert len(reset.info["jumps"]) and not bridgeable(reset, [(float(a), float(b)) for a, b in reset.info["gaps"]])
    rates = base_track_from_wheels(t2, np.full(t2.size, 5.0), np.full(t2.size, 5.0), kind="velocity")
    assert not bridgeable(rates, [(float(a), float(b)) for a, b in rates.info["gaps"]])


@pytest.mark.parametrize("speed, wrap, bridged", [(0.3, True, True), (0.8, True, False), (0.8, False, True)])
def test_a_gap_in_wrapped_wheel_angles_is_bridged_only_below_half_a_turn(speed, wrap, bridged):
    # Joint angles reported within one turn are unwrapped per joint: a wheel that turned more than pi while the
    # messages were missing loses 2 pi, and the gap's net motion with it. At 0.8 m/s (r 0.1 m) a 0.62 s gap turns the
    # wheels 5 rad: cut. Cumulative encoder angles (beyond one turn) are not unwrapped: that gap is bridged.
    from plsgraph.gaps import bridgeable
    from plsgraph.io.recording import JointStates
    from plsgraph.odometry.joints import wheel_track_from_joints

    t = np.r_[np.arange(0, 5, 0.02), np.arange(5.6, 10, 0.02)]
    ang = speed / 0.1 * t + 7.0
    angles = (ang + np.pi) % (2 * np.pi) - np.pi if wrap else ang
    joints = JointStates((t * 1e9).astype(np.int64) + 10**18, ("left_wheel_joint", "right_wheel_joint"),
                         np.stack([angles, angles], 1), np.full((t.size, 2), np.nan))
    base, _ = wheel_track_from_joints(joints, 0.1, 0.5)
    gaps = [(float(a), float(b)) for a, b in base.info["gaps"]]
    assert len(gaps) == 1 and bridgeable(base, gaps) is bridged
    if bridged:  # the net motion across the gap is the true one
        i = int(np.searchsorted(base.t, gaps[0][1]))
        assert base.T_world_base[i, 0, 3] - base.T_world_base[i - 1, 0, 3] == pytest.approx(
            (gaps[0][1] - gaps[0][0]) * speed, rel=1e-6)


def test_the_edge_across_a_bridged_gap_is_found_after_the_stamps_are_regularized():
    # The refinement may put the odometry stamps on a regular clock, which moves the samples that open and close a
    # gap by up to 0.45 of a step: the gap's samples are still found (the loose edge and its knots go with them).
    from plsgraph.refine.graph import _gap_steps

    rng = np.random.default_rng(0)
    t = np.r_[np.arange(0, 5, 0.02), np.arange(5.5, 10, 0.02)]
    ang = 3.0 * t
    base = base_track_from_wheels(t, ang, ang)
    g = np.array(base.info["gaps"], dtype=float).reshape(-1, 2)
    i_open = int(np.searchsorted(t, g[0, 0]))
    for shift in (4e-16, 0.009, -0.009, *rng.uniform(-0.009, 0.009, 10)):
        moved = t + rng.uniform(-0.009, 0.009, t.size)
        moved[i_open] = t[i_open] + shift
        moved[i_open + 1] = t[i_open + 1] - shift
        track = dataclasses.replace(base, t=moved, info=dict(base.info, bridged_gaps=g))
        ia, ib = _gap_steps(track)
        assert ia.tolist() == [i_open] and ib.tolist() == [i_open + 1]


def test_too_little_left_between_gaps_is_a_diagnosis(sim):
    with pytest.raises(InsufficientDataError, match="gap"):
        _calibrate(sim, cut=(3.86, 5.11))


def test_the_gate_flags_a_base_track_with_a_gap_the_robot_moved_across(sim):
    s, cam = sim
    rel = s.wheel_t - s.wheel_t[0]
    keep = ~((rel > 4.0) & (rel < 4.5))
    base = base_track_from_wheels(s.wheel_t[keep], s.wheel_left[keep], s.wheel_right[keep])
    probs = problems_of(None, None, base_track=base, camera_track=cam)
    assert any("gap" in p for p in probs)


def test_event_gaps_are_found_inside_and_between_chunks():
    from plsgraph.gaps import event_gaps

    t = np.r_[np.arange(0, 100_000_000, 1000), np.arange(600_000_000, 700_000_000, 1000)].astype(np.int64)
    assert event_gaps(t, None) == [(99_999_000, 600_000_000)]
    assert event_gaps(t[:10] + 2_000_000_000, int(t[-1])) == [(int(t[-1]), 2_000_000_000)]


# ---------------------------------------------------------------------------------------------- files


def test_a_flagged_calibration_yaml_says_so_and_has_no_tf_line(sim, tmp_path):
    # Before: a flagged run's calibration.yaml had a ready-to-paste TF line and no ok / problems.
    r = _calibrate(sim, radius=1.15)
    out = tmp_path / "flagged"
    out.mkdir()
    write_calibration(out, r)
    text = (out / "calibration.yaml").read_text()
    c = yaml.safe_load(text)
    assert c["ok"] is False and c["problems"]
    assert "ros2 run" not in text
    assert text.startswith("# FLAGGED")


def _old_result(d):
    d.mkdir()
    (d / "calibration.yaml").write_text("ok: true\n")
    (d / "residuals.png").write_bytes(b"old")
    return d


def test_force_replaces_the_whole_folder(tmp_path):
    # Before: --force --no-refine left the old residuals.png, observability.png and methods.png.
    out = _old_result(tmp_path / "out")

    def work(stage):
        (stage / "report.json").write_text("{}")
        return {"ok": True, "text": f"written: {stage / 'report.json'}"}

    res = write_result_folder(out, work)
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]
    assert str(out / "report.json") in res["text"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.") and "lock" not in p.name]


def test_an_interrupt_leaves_the_previous_result_intact(tmp_path):
    # Before: an interrupt during figure writing left a new trajectories.png beside the old calibration.yaml.
    out = _old_result(tmp_path / "out")

    def work(stage):
        (stage / "trajectories.png").write_bytes(b"new")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_result_folder(out, work)
    assert sorted(p.name for p in out.iterdir()) == ["calibration.yaml", "residuals.png"]
    assert (out / "residuals.png").read_bytes() == b"old"
    assert not [p for p in tmp_path.iterdir() if "staging" in p.name]


def test_what_a_killed_run_left_beside_its_folder_is_cleared_by_the_next_and_a_result_caught_mid_swap_restored(
        tmp_path):
    """A review: runs killed by SIGKILL or SIGTERM left hidden .NAME.staging-* folders (one held a calibration.yaml)
    that no later run removed. A run killed between the swap's two renames would leave the earlier result only in
    .NAME.old-*/previous."""
    out = tmp_path / "out"
    (tmp_path / ".out.staging-abc_1234").mkdir()
    (tmp_path / ".out.staging-abc_1234" / "calibration.yaml").write_text("ok: true\n")
    (tmp_path / ".out.old-xyz98765" / "previous").mkdir(parents=True)
    (tmp_path / ".out.old-xyz98765" / "previous" / "calibration.yaml").write_text("earlier\n")
    (tmp_path / ".other.staging-1").mkdir()  # another folder's: not this run's business
    # A review: the name was a glob pattern (`out[1]` reached `out1`'s), and `.out.old-*` matched a folder's own
    # stage when that folder is named `out.old-x`.
    (tmp_path / ".out1.staging-abcdefgh").mkdir()
    (tmp_path / ".out.old-x.staging-abcdefgh").mkdir()

    seen = {}

    def work(stage):
        seen["out"] = (out / "calibration.yaml").read_text()  # put back before the run's own work
        (stage / "report.json").write_text("{}")
        return {"ok": True, "text": ""}

    write_result_folder(out, work)
    assert seen["out"] == "earlier\n" and sorted(p.name for p in out.iterdir()) == ["report.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.staging-1", ".out.old-x.staging-abcdefgh",
                                                           ".out1.staging-abcdefgh", "out"]
    write_result_folder(tmp_path / "out[1]", lambda stage: {"ok": True, "text": ""})
    assert (tmp_path / ".out1.staging-abcdefgh").exists()


def test_a_signal_that_surfaces_as_another_error_ends_the_run_as_the_signal(monkeypatch, capsys):
    """A SIGTERM that arrived while GTSAM was being imported (beside the front end's last spans) came out of the
    import as ImportError("initialization failed"), was logged as a failed import, and the run went on until the
    refinement's own import of the half-initialised module failed ("type KeyList is already registered"): exit 3 and a
    bug report asked for, instead of exit 143."""
    import argparse
    import signal

    import plsgraph.cli.main as cli
    from plsgraph.core.processes import interrupt_behind

    def failing(exc):
        def func(args):
            raise exc
        return argparse.Namespace(func=func, verbose=False, json=False)

    def from_(cause, message="initialization failed"):
        try:
            raise cause
        except BaseException as inner:  # noqa: BLE001
            try:
                raise ImportError(message) from inner
            except ImportError as outer:
                return outer

    monkeypatch.setattr(cli, "SIGNALS_RECEIVED", [])
    term = cli.Terminated(signal.SIGTERM)
    assert interrupt_behind(from_(term)) is term and interrupt_behind(ImportError("x")) is None
    assert cli._run_command(failing(from_(term))) == 143
    assert "terminated (SIGTERM)" in capsys.readouterr().err
    assert cli._run_command(failing(from_(KeyboardInterrupt()))) == 130
    assert "interrupted" in capsys.readouterr().err
    # No signal: a failed import is a bug, said as one.
    assert cli._run_command(failing(ImportError("type KeyList is already registered"))) == 3
    assert "internal error" in capsys.readouterr().err
    # The second import's failure, after the signal was swallowed: the signal's doing.
    monkeypatch.setattr(cli, "SIGNALS_RECEIVED", [])

    def after(sig, exc):
        def func(args):
            cli.SIGNALS_RECEIVED.append(int(sig))
            raise exc
        return argparse.Namespace(func=func, verbose=False, json=False)

    assert cli._run_command(after(signal.SIGHUP, ImportError("type KeyList is already registered"))) == 129
    assert "terminated (SIGHUP)" in capsys.readouterr().err
    # ... also when it surfaces as one of the errors the command explains (a review), and a chained Ctrl-C is Ctrl-C's
    from plsgraph.errors import InputError

    assert cli._run_command(after(signal.SIGTERM, InputError("no board"))) == 143
    assert cli._run_command(after(signal.SIGTERM, PermissionError("clean-up"))) == 143
    assert cli._run_command(after(signal.SIGTERM, from_(KeyboardInterrupt()))) == 130
    capsys.readouterr()
    # A signal of an earlier command in the same process is not this one's (the list is the command's own).
    assert cli._run_command(failing(ImportError("a bug"))) == 3
    assert "internal error" in capsys.readouterr().err
    # With --json a script reads the signal's end on stdout as it reads an error's.
    args = after(signal.SIGTERM, ImportError("type KeyList is already registered"))
    args.json = True
    assert cli._run_command(args) == 143
    said = json.loads(capsys.readouterr().out)
    assert said["ok"] is False and said["exit_code"] == 143 and "terminated (SIGTERM)" in said["error"]
    args = failing(KeyboardInterrupt())
    args.json = True
    assert cli._run_command(args) == 130
    assert json.loads(capsys.readouterr().out)["exit_code"] == 130


@pytest.mark.parametrize("to", ["process", "another thread"])
def test_an_interrupt_held_back_during_the_swap_says_the_result_was_written(tmp_path, monkeypatch, capsys, to):
    """A review: a signal that arrives while the finished result is being swapped into --out is held back until the
    swap is done, so the run ends with the new result in place; the message said an earlier result was kept. Sent to
    the process, the kernel may hand it to any thread (numpy's BLAS threads, the figure worker's writer): a signal mask
    of the main thread did not hold it back then, and the message was wrong again on a busy machine."""
    import argparse
    import os
    import signal
    import threading
    import time

    import plsgraph.cli.main as cli
    import plsgraph.report.files as files
    from plsgraph.report.output import write_result_folder

    out = tmp_path / "out"
    real_rename = os.rename
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()

    def rename(src, dst):
        real_rename(src, dst)
        if Path(dst) == out:
            if to == "process":
                os.kill(os.getpid(), signal.SIGHUP)
            else:
                signal.pthread_kill(other.ident, signal.SIGHUP)
            time.sleep(0.2)  # delivered (to a thread that waits: when it is next scheduled) while the swap goes on

    def hup(signum, frame):
        raise cli.Terminated(signum)

    old = signal.signal(signal.SIGHUP, hup)
    monkeypatch.setattr(files.os, "rename", rename)
    try:
        def func(args):
            write_result_folder(out, lambda stage: (stage / "calibration.yaml").write_text("new\n") and {})
            return 0

        code = cli._run_command(argparse.Namespace(func=func, verbose=False, json=False))
    finally:
        signal.signal(signal.SIGHUP, old)
        stop.set()
    assert code == 129
    assert f"result was written to {out}" in capsys.readouterr().err
    assert (out / "calibration.yaml").read_text() == "new\n"


def test_sigterm_ends_a_calibration_like_ctrl_c(tmp_path):
    """A review: SIGTERM (a job scheduler, systemd) or SIGHUP (a closed ssh session) ended a calibration with no
    message and left its staging folder behind."""
    import signal
    import subprocess
    import sys
    import time

    from realdata import SAMPLE

    exe = Path(sys.executable).with_name("plsgraph")
    out = _old_result(tmp_path / "out")
    proc = subprocess.Popen([str(exe), "calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(out),
                             "--force"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".out.staging-*")) and time.monotonic() < deadline:  # the run is under way
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "terminated (SIGTERM)" in err and "Traceback" not in err
    assert sorted(p.name for p in out.iterdir()) == ["calibration.yaml", "residuals.png"]  # the earlier result
    assert not [p for p in tmp_path.iterdir() if "staging" in p.name or ".old-" in p.name]


def test_a_second_run_on_the_same_out_fails_clearly(tmp_path):
    # Before: two runs on one new --out both said "written" and the folder mixed their files.
    out = tmp_path / "out"
    with OutputLock(out), pytest.raises(InputError, match="another plsgraph run is writing"):
        plsgraph.calibrate_to_dir(tmp_path / "nosuch.mcap", out, CalibrationOptions(board=BOARD))
    assert not out.exists()


def test_batch_force_replaces_a_failed_recordings_old_result(tmp_path):
    # Before: the old calibration.yaml (ok: true) stayed beside a summary row saying "failed".
    rec = tmp_path / "a.mcap"
    rec.write_bytes(b"\0" * 4096)
    out = _old_result(tmp_path / "a")
    row = _batch_item((str(rec), str(out), CalibrationOptions(board=BOARD), True))
    assert row["status"] == "failed"
    # The old calibration is no longer the folder's result, but it is kept apart, not lost.
    assert sorted(p.name for p in out.iterdir()) == ["previous_calibration", "report.json"]
    assert sorted(p.name for p in (out / "previous_calibration").iterdir()) == ["calibration.yaml", "residuals.png"]
    rep = json.loads((out / "report.json").read_text())
    assert rep["ok"] is False and rep["calibration"] is None and rep["problems"]
    assert rep["previous_calibration"] == "previous_calibration"


def test_a_run_without_a_calibration_keeps_the_one_it_replaces(tmp_path, monkeypatch):
    # Before: calibrate --force of a recording cut short into a folder with a good calibration left report.json only.
    import plsgraph.api as api

    def too_little(*a, **k):
        raise InsufficientDataError("only 2.9 s of camera velocity samples")

    monkeypatch.setattr(api, "run_recording", too_little)
    out = _old_result(tmp_path / "out")
    res = api.calibrate_to_dir(tmp_path / "cut.mcap", out, CalibrationOptions(board=BOARD), force=True,
                               figure_worker=False)
    assert res["ok"] is False and "previous_calibration" in res["text"]
    assert sorted(p.name for p in out.iterdir()) == ["previous_calibration", "report.json"]
    assert (out / "previous_calibration" / "calibration.yaml").read_text() == "ok: true\n"
    assert (out / "previous_calibration" / "residuals.png").read_bytes() == b"old"
    # A second failure passes the kept calibration on; the folder stays one --force may replace.
    api.calibrate_to_dir(tmp_path / "cut.mcap", out, CalibrationOptions(board=BOARD), force=True, figure_worker=False)
    assert (out / "previous_calibration" / "calibration.yaml").read_text() == "ok: true\n"
    assert not (out / "previous_calibration" / "previous_calibration").exists()
    # A folder that never held a calibration keeps nothing.
    fresh = tmp_path / "fresh"
    api.calibrate_to_dir(tmp_path / "cut.mcap", fresh, CalibrationOptions(board=BOARD), figure_worker=False)
    assert sorted(p.name for p in fresh.iterdir()) == ["report.json"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_an_unwritable_out_is_refused_before_the_work(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(InputError, match="no write permission in .*ro") as exc:
            prepare_output_dir(ro / "out", create=False)
        assert ".tmp" not in str(exc.value)
    finally:
        ro.chmod(0o755)


# ---------------------------------------------------------------------------------------------- user errors


@pytest.mark.parametrize("over, expect", [
    ({"cols": 1000000, "rows": 1000000}, "not a printable target"),
    ({"square_size": float("nan")}, "square_size must be a finite"),
    ({"cols": 4.5}, "cols has the wrong type: it must be a whole number"),
    ({"pattern": "hexagons"}, "unknown pattern 'hexagons'"),
    ({"square_size": 50.0, "circle_diameter": 40.0}, "lengths are in metres"),  # written in mm
    ({"square_size": 5.0, "circle_diameter": 4.0}, "lengths are in metres"),  # in cm
    ({"spacing": 0.05}, "unknown key spacing"),
    ({"tag_size": 0.05}, "unknown key tag_size for pattern asymmetric_circles"),
])
def test_bad_board_definitions_are_named(over, expect):
    d = {"pattern": "asymmetric_circles", "cols": 4, "rows": 11, "square_size": 0.05, "circle_diameter": 0.03}
    d.update(over)
    with pytest.raises(InputError, match=expect):
        Board.from_dict(d)


def test_a_misspelt_aprilgrid_key_is_refused_not_left_at_its_default():
    d = {"target_type": "aprilgrid", "pattern": "aprilgrid", "tagCols": 6, "tagRows": 6, "tagSize": 0.088,
         "tagSpacing": 0.3}
    with pytest.raises(InputError, match="unknown key tag_border_bit .*tag_border_bits"):
        Board.from_dict(dict(d, tag_border_bit=1))
    with pytest.raises(InputError, match="lengths are in metres"):
        Board.from_dict(dict(d, tagSize=88))  # mm
    assert Board.from_dict(dict(d, codeOffset=0, description="lab board")).n_points == 144


def test_kalibr_circlegrid_files_are_read(tmp_path):
    ours = load_board("acircles_4x11_a2")
    f = tmp_path / "circlegrid.yaml"
    f.write_text("target_type: 'circlegrid'\ntargetCols: 4\ntargetRows: 11\nspacingMeters: 0.05\n"
                 "asymmetricGrid: True\ncircle_diameter: 0.04\n")
    b = Board.from_yaml(f)
    assert (b.pattern, b.cols, b.rows, b.circle_diameter) == ("asymmetric_circles", 4, 11, 0.04)
    np.testing.assert_array_equal(b.points, ours.points)  # Kalibr's layout is the same
    for text, expect in [
        ("asymmetricGrid: True\n", "circle_diameter: <metres>"),
        ("asymmetricGrid: False\ncircle_diameter: 0.04\n", "asymmetric circle grids only"),
        ("asymmetricGrid: True\ncircle_diameter: 0.04\nspacing: 1\n", "unknown key spacing"),
    ]:
        f.write_text("target_type: circlegrid\ntargetCols: 4\ntargetRows: 11\nspacingMeters: 0.05\n" + text)
        with pytest.raises(InputError, match=expect):
            Board.from_yaml(f)
    f.write_text("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\n")
    with pytest.raises(InputError, match="'checkerboard' is not a target plsgraph detects"):
        Board.from_yaml(f)


@pytest.mark.parametrize("bits, expect", [(0, "must be 1, 2 or 3"), (1.5, "whole number"), ("two", "whole number")])
def test_an_aprilgrids_tag_border_is_checked(bits, expect):
    d = {"target_type": "aprilgrid", "pattern": "aprilgrid", "tagCols": 6, "tagRows": 6, "tagSize": 0.088,
         "tagSpacing": 0.3}
    assert Board.from_dict(d).tag_border_bits == 2  # Kalibr's print
    assert Board.from_dict(dict(d, tag_border_bits=1)).tag_border_bits == 1
    with pytest.raises(InputError, match=expect):
        Board.from_dict(dict(d, tag_border_bits=bits))
    for bad in (True, 2.0):  # built directly, without the file reader's check
        with pytest.raises(InputError, match="tag_border_bits"):
            Board("aprilgrid", 6, 6, tag_size=0.088, tag_spacing=0.3, tag_border_bits=bad)


@pytest.mark.parametrize("args, expect", [
    (["--duration", "nan"], "--duration"),
    (["--td", "nan"], "--td"),
    (["--td", "1e9"], "--td"),
    (["--seed", "-1"], "--seed"),
])
def test_bad_simulate_flags_are_user_errors(tmp_path, capsys, args, expect):
    code = main(["simulate", "--out", str(tmp_path / "s.mcap"), "--duration", "2", *args])
    err = capsys.readouterr().err
    assert code == 2 and expect in err and err.count("error:") == 1
    assert not (tmp_path / "s.mcap").exists()


def test_a_recording_without_events_says_so_before_asking_for_intrinsics(tmp_path, capsys):
    from plsgraph.io.recording import JointStates
    from plsgraph.io.writer import write_recording

    t = (np.arange(100) * 2e7).astype(np.int64) + 10**18
    joints = JointStates(t, ("left_wheel_joint", "right_wheel_joint"), np.zeros((100, 2)), np.zeros((100, 2)))
    rec = tmp_path / "odo_only.mcap"
    write_recording(rec, None, joints, None, None)
    code = main(["calibrate", str(rec), "--board", BOARD, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "no events" in err and "--camera-info" not in err


@pytest.fixture(scope="module")
def skid_sim():
    """A skid-steer robot (effective track 1.9x nominal: it turns 0.53x what its wheels say) with slip growing with
    the turn rate, as on the study's run that a wrong search peak sent into a wrong answer passed as ok."""
    import dataclasses

    from plsgraph.sim import realism as R

    base = R.ideal()
    robot = dataclasses.replace(base.robot, slip_sigma=0.04, slip_turn_gain=4.0, slip_tau_s=0.7, track_ratio=1.9)
    s = simulate_robot("rich", duration=20.0, seed=4, td=-0.05, realism=dataclasses.replace(base, robot=robot))
    cam = camera_track_from_detections(s.detections(noise_px=0.3, seed=104), s.camera)
    odo = base_track_from_wheels(s.wheel_t, s.wheel_left, s.wheel_right, s.wheel_radius, s.track_width)
    return s, cam, odo


def test_a_search_peak_that_traps_the_refinement_is_escaped_by_the_second_start(skid_sim, monkeypatch, tmp_path):
    # The search is made to return a peak 60 ms early with a turn scale 0.45 (the study's run: -106 ms against a
    # truth of -48 ms). Started there alone, the refinement stops in a worse minimum; started also from the closed
    # form's offset, both final graphs prefer that answer, which is kept and is right within its sigmas.
    import plsgraph.refine.graph as graph
    from plsgraph.core.geometry import make_T

    s, cam, odo = skid_sim
    monkeypatch.setattr(graph, "turn_angle_td_search", lambda c, b, td0, half, **kw: (s.td - 0.06, 0.45, 0.1, 0.1))
    r = plsgraph.calibrate_tracks(cam, odo, s.camera, board=BOARD)
    ref = r.run.refinement
    two = ref.two_starts
    assert two is not None and two["chosen"] == "closed_form" and two["delta"] < 0, two
    (aa, ab), (ba, bb) = two["errors"]
    assert ab < aa and bb < ba  # each graph prefers the kept answer
    assert any("solved from the search's time offset" in w for w in ref.warnings)
    d_rot = so3_log(ref.R_base_cam @ s.T_base_cam[:3, :3].T)
    err = np.r_[d_rot, ref.T_base_cam[:2, 3] - s.T_base_cam[:2, 3], ref.td - s.td]
    sig = np.sqrt(np.diag(ref.cov_base_axes))[[0, 1, 2, 3, 4, 6]]
    assert np.all(np.abs(err) <= 3 * sig), (err, sig)
    # The search's start alone (the behaviour before): its answer is farther from the truth in x and td.
    cf = r.run.closed_form
    sc = cf.odometry_scale
    t = np.where(np.isfinite(cf.t_base_cam), cf.t_base_cam, 0.0)  # the height is not the closed form's
    one = graph.refine(cam, r.run.base_track, s.camera, make_T(cf.R_base_cam, t), cf.td,
                       graph.RefinementOptions(td_two_starts=False),
                       seed_odometry_scale=(sc["speed"], sc["turn_rate"]))
    assert one.two_starts is None and one.td == pytest.approx(two["td_end_s"][0], abs=5e-3)
    assert abs(one.td - s.td) > 2 * abs(ref.td - s.td)
    assert abs(one.T_base_cam[0, 3] - s.T_base_cam[0, 3]) > 2 * abs(ref.T_base_cam[0, 3] - s.T_base_cam[0, 3])
    # The record reaches report.json as plain JSON.
    out = prepare_output_dir(tmp_path / "calib")
    write_calibration(out, r)
    rep = json.loads((out / "report.json").read_text())
    assert rep["refinement"]["two_starts"]["chosen"] == "closed_form"
    assert rep["refinement"]["two_starts"]["td_end_s"] == pytest.approx(two["td_end_s"])


def test_two_answers_the_data_cannot_choose_between_are_flagged(sim):
    from dataclasses import replace

    r = _calibrate(sim)
    assert r.ok
    ref = replace(r.run.refinement, two_starts={"chosen": "search", "delta": 2.0, "ambiguous": ["x", "td"]})
    text = " ".join(problems_of(r.run.closed_form, ref))
    assert "answers more than 3 sigma apart on x, td" in text


def test_frames_that_disagree_point_at_the_intrinsics(sim):
    from dataclasses import replace

    r = _calibrate(sim)
    ref = replace(r.run.refinement, warnings=("outlier rejection / re-bracketing / freezing did not settle within "
                                              "max_passes",))
    text = " ".join(problems_of(r.run.closed_form, ref))
    assert "did not settle" in text and "intrinsics" in text
    many = replace(r.run.refinement, n_frames_rejected=r.run.refinement.n_frames)  # half the frames rejected
    text = " ".join(problems_of(r.run.closed_form, many))
    assert "as outliers" in text and "intrinsics" in text


def test_two_starts_keep_the_answer_both_graphs_prefer():
    # Two "solves" of one toy problem whose graphs differ in their noise (as adapted noise models do): each graph
    # scores both answers; the sum of the differences decides, and answers that differ beyond their sigmas while the
    # scores hardly differ are recorded as ambiguous.
    from dataclasses import replace

    import gtsam

    import plsgraph.refine.graph as graph

    def toy(x: float, td: float, sigma: float, var_x: float = 1e-4):
        g = gtsam.NonlinearFactorGraph()
        g.add(gtsam.PriorFactorPose3(graph.KEY_CAM, gtsam.Pose3(gtsam.Rot3(), np.array([0.1, 0.0, 0.0])),
                                     gtsam.noiseModel.Isotropic.Sigma(6, sigma)))
        g.add(gtsam.PriorFactorVector(graph.KEY_TD, np.array([0.0]), gtsam.noiseModel.Isotropic.Sigma(1, 0.01)))
        v = gtsam.Values()
        v.insert(graph.KEY_CAM, gtsam.Pose3(gtsam.Rot3(), np.array([x, 0.0, 0.0])))
        v.insert(graph.KEY_TD, np.array([td]))
        T = np.eye(4)
        T[0, 3] = x
        res = graph.RefinementResult(
            T_base_cam=T, td=td, T_world_board=np.eye(4), knot_t=np.zeros(2), T_world_base=np.stack([np.eye(4)] * 2),
            converged=True, iterations=1, initial_error=1.0, final_error=float(g.error(v)), rms_px_initial=0.2,
            rms_px_final=0.2, n_frames=10, n_frames_rejected=0, n_frames_dropped=0, n_points=100,
            cov_base_axes=np.diag([1e-6] * 3 + [var_x] * 3 + [1e-5]), seed_T_base_cam=np.eye(4), seed_td=0.0)
        return res, g.error, v

    opt = graph.RefinementOptions()
    near, far = toy(0.1, 0.0, 0.01), toy(0.2, 0.0, 0.02)  # the second answer is 10 cm off the data's 0.1 m
    kept = graph._two_starts(far, near, -0.05, 0.0, opt)
    assert kept.two_starts["chosen"] == "closed_form" and kept.T_base_cam[0, 3] == pytest.approx(0.1)
    assert "ambiguous" not in kept.two_starts  # decisively worse: not a second answer
    assert graph._two_starts(near, far, -0.05, 0.0, opt).two_starts["chosen"] == "search"
    # Nearly as good (the scores differ by less than two_starts_decisive) but 5 sigmas apart in x: ambiguous.
    a, b = toy(0.1, 0.0, 0.01, 1e-6), toy(0.105, 0.0, 0.01, 1e-6)
    amb = graph._two_starts(a, b, -0.05, 0.0, opt).two_starts
    assert amb["ambiguous"] == ["x"] and abs(amb["delta"]) < opt.two_starts_decisive
    # Scores that cannot be compared (not finite): the search's start is kept, and a 5-sigma difference is ambiguous.
    nan = (a[0], lambda v: float("nan"), a[2])
    rec = graph._two_starts(nan, b, -0.05, 0.0, opt).two_starts
    assert rec["chosen"] == "search" and rec["compared"] is False and rec["ambiguous"] == ["x"]
    # A start that did not converge or failed leaves the other's answer, and the note says which.
    stuck = (replace(far[0], converged=False, cov_base_axes=None), far[1], far[2])
    kept = graph._two_starts(stuck, near, -0.05, 0.0, opt)
    assert kept.two_starts["chosen"] == "closed_form" and kept.two_starts["converged"] == [False, True]
    assert "the one from the search's did not converge" in kept.warnings[-1]
    kept = graph._two_starts(near, None, -0.05, 0.0, opt, [RuntimeError("boom")])
    assert kept.two_starts["chosen"] == "search" and kept.two_starts["failed"] == ["boom"]
    assert "the one from the closed form's failed" in kept.warnings[-1]

    # Starts solved without their knots' second opinion (refine's defer_knots): the chosen one is finished, the
    # other's is dropped (its child stopped, its answer never asked for).
    class Deferred:
        def __init__(self, res):
            self.res, self.calls = res, []

        def result(self):
            self.calls.append("result")
            return replace(self.res, warnings=("finished",))

        def discard(self):
            self.calls.append("discard")

    dn, df = Deferred(near[0]), Deferred(far[0])
    kept = graph._two_starts((*far, df), (*near, dn), -0.05, 0.0, opt)
    assert kept.two_starts["chosen"] == "closed_form" and kept.warnings[0] == "finished"
    assert dn.calls == ["result"] and df.calls == ["discard"]


def test_a_start_that_fails_does_not_cost_the_other_answer(skid_sim, monkeypatch):
    import plsgraph.refine.graph as graph
    from plsgraph.errors import InsufficientDataError

    s, cam, odo = skid_sim
    monkeypatch.setattr(graph, "turn_angle_td_search", lambda c, b, td0, half, **kw: (s.td - 0.06, 0.45, 0.1, 0.1))
    plain = graph._refine_from

    def second_fails(*args, **kw):
        if args[6] == args[7] and not kw.get("probe"):  # td_start == td_given: the closed form's start
            raise InsufficientDataError("refine: almost every frame is an outlier")
        return plain(*args, **kw)

    monkeypatch.setattr(graph, "_refine_from", second_fails)
    r = plsgraph.calibrate_tracks(cam, odo, s.camera, board=BOARD)
    two = r.run.refinement.two_starts
    assert two["chosen"] == "search" and two["converged"] == [True, False] and "outlier" in two["failed"][0]
    assert r.run.refinement.converged and r.run.refinement.td == pytest.approx(two["td_end_s"][0])


@contextlib.contextmanager
def _root_warnings():
    """The messages of the warnings that reach a handler on the root logger within the block."""
    root = logging.getLogger()
    records: list[str] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = lambda r: records.append(r.getMessage())
    root.addHandler(handler)
    try:
        yield records
    finally:
        root.removeHandler(handler)


def test_warnings_once_says_each_warning_once_with_whose_it_is_and_forgets_after():
    from plsgraph.core.logs import warnings_once

    lg = logging.getLogger("plsgraph.test_once")
    with _root_warnings() as records:
        with warnings_once("a.mcap"):
            for n in (10, 20, 30):  # a reader's pass over a damaged file: same warning, other counts
                lg.warning("file is cut short; kept the %d messages read before it", n)
            lg.warning("a.mcap: said with its name already")
        lg.warning("file is cut short; kept the %d messages read before it", 40)
    assert records == ["a.mcap: file is cut short; kept the 10 messages read before it",
                       "a.mcap: said with its name already",
                       "file is cut short; kept the 40 messages read before it"]


def test_recordings_in_threads_of_one_process_keep_their_own_warnings():
    # A Dask worker runs recordings in threads: each says its own warnings, once, under its own name.
    import threading

    from plsgraph.core.logs import warnings_once

    lg = logging.getLogger("plsgraph.test_once_threads")
    both = threading.Barrier(2)

    def recording(name: str, n: int) -> None:
        with warnings_once(name):
            both.wait()
            for _ in range(3):
                lg.warning("%d gap(s) in odometry", n)
            both.wait()

    with _root_warnings() as records:
        threads = [threading.Thread(target=recording, args=(f"{c}.mcap", n)) for c, n in (("a", 2), ("b", 7))]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    assert sorted(records) == ["a.mcap: 2 gap(s) in odometry", "b.mcap: 7 gap(s) in odometry"]


def test_batch_says_a_damaged_files_reader_warnings_once(tmp_path, caplog):
    sample = Path(__file__).resolve().parents[1] / "data" / "sample" / "rich_sample.mcap"
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(sample.read_bytes()[:5_000_000])
    with caplog.at_level(logging.WARNING):
        row = _batch_item((str(cut), str(tmp_path / "cut"), CalibrationOptions(board=BOARD), False))
    said = [r.getMessage() for r in caplog.records if "truncated or corrupt" in r.getMessage()]
    assert said and len(said) == len(set(said))  # each pass over the file used to repeat them
    assert all(m.startswith("cut.mcap: ") for m in said)
    assert row["status"] in ("ok", "flagged") and any("truncated" in w for w in row["warnings"])


def test_an_output_folder_nothing_can_be_written_into_is_a_clear_error(tmp_path, monkeypatch):
    # Before: "[Errno 2] No such file or directory: '/proc/.x.plsgraph-lock'" (--out /proc/x), or a raw read-only
    # file-system error.
    import errno

    def refuse(path, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(path))

    monkeypatch.setattr(os, "open", refuse)
    with pytest.raises(InputError, match=r"cannot write the output folder .*out: Read-only file system in .*; choose "
                                         r"an --out on a writable disk"), OutputLock(tmp_path / "out"):
        pass


def test_simulate_into_a_folder_nothing_can_be_written_into_fails_before_simulating(tmp_path, monkeypatch):
    import errno
    import tempfile

    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    monkeypatch.setattr("plsgraph.api.simulate_recording", lambda *a, **k: pytest.fail("simulated before the check"))
    with pytest.raises(InputError, match=r"cannot write .*s\.mcap: Read-only file system"):
        plsgraph.simulate(tmp_path / "s.mcap", duration=3.0)


def test_a_linked_out_folder_has_its_target_replaced_and_an_interrupted_run_leaves_no_empty_folders(tmp_path):
    """A review: --out given as a symbolic link (with --force) had the link replaced by a real folder while the target
    kept the old result, without a word; an interrupted run into new/deep/cal left the empty new/deep/."""
    target = _old_result(tmp_path / "real")
    link = tmp_path / "link"
    link.symlink_to(target)

    def work(stage):
        (stage / "report.json").write_text("{}")
        return {"ok": True, "text": ""}

    write_result_folder(link, work)
    assert link.is_symlink() and sorted(p.name for p in target.iterdir()) == ["report.json"]

    def interrupted(stage):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_result_folder(tmp_path / "new" / "deep" / "cal", interrupted)
    assert not (tmp_path / "new").exists()


def test_the_swap_puts_every_signal_handler_back_however_it_ends(tmp_path, monkeypatch):
    """A review: the handlers that hold signals back during the swap were put in before its try and back one by one;
    a swap that fails (here a rename refused) must leave the handlers it found, and a later Ctrl-C must still reach
    Python's own."""
    import os
    import signal

    import plsgraph.report.files as files
    from plsgraph.report.output import write_result_folder

    before = {s: signal.getsignal(s) for s in files.HELD_SIGNALS}
    real_rename = os.rename

    def rename(src, dst):
        if Path(dst) == tmp_path / "out":
            raise OSError("refused")
        real_rename(src, dst)

    monkeypatch.setattr(files.os, "rename", rename)
    with pytest.raises(OSError, match="refused"):
        write_result_folder(tmp_path / "out", lambda stage: (stage / "calibration.yaml").write_text("new\n") and {})
    assert {s: signal.getsignal(s) for s in files.HELD_SIGNALS} == before
    assert not (tmp_path / "out").exists()


def test_report_options_name_a_board_file_by_its_absolute_path(tmp_path, monkeypatch):
    # A review: report.json kept a board file's relative path while the recording's and the truth's were absolute.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "b.yaml").write_text("pattern: asymmetric_circles\ncols: 4\nrows: 11\nsquare_size: 0.05\n"
                                     "circle_diameter: 0.04\n")
    assert CalibrationOptions(board="b.yaml").to_dict()["board"] == str(tmp_path / "b.yaml")
    assert CalibrationOptions(board="acircles_4x11_a2").to_dict()["board"] == "acircles_4x11_a2"


def test_a_camera_turning_against_the_wheels_is_named_not_an_infinite_track():
    # A review: events of another camera's drive gave "the effective track width comes out inf x the nominal one".
    from plsgraph.gate import _odometry_problems

    (said,) = _odometry_problems(1.0, -0.4)
    assert "turns against the wheel odometry" in said and "inf" not in said and "--events-topic" in said
    assert "track width comes out 3.33 x" in _odometry_problems(1.0, 0.3)[0]
    assert _odometry_problems(1.0, 0.8) == []


def test_a_killed_runs_leftovers_are_cleared_once_its_forked_child_lets_the_lock_go(tmp_path):
    # A review: the refinement's forked helper of a killed batch worker inherits the folder's lock for a moment, and
    # the cleanup after an interrupt gave up at once, leaving the staging folder.
    import subprocess
    import sys
    import time

    from plsgraph.report.files import clear_after_killed_run

    out = tmp_path / "a"
    stage = tmp_path / ".a.staging-abcd1234"
    stage.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from plsgraph.report.files import OutputLock\n"
        f"with OutputLock({str(out)!r}):\n    print('held', flush=True); time.sleep(1.0)\n")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        t0 = time.monotonic()
        assert clear_after_killed_run(out, wait_s=10.0)
        assert 0.3 < time.monotonic() - t0 < 9.0 and not stage.exists()
        holder.wait(timeout=10)
        stage.mkdir()
        holder = subprocess.Popen([sys.executable, "-c", (
            "import time; from plsgraph.report.files import OutputLock\n"
            f"with OutputLock({str(out)!r}):\n    print('held', flush=True); time.sleep(5)\n")],
            stdout=subprocess.PIPE, text=True)
        assert holder.stdout.readline().strip() == "held"
        assert not clear_after_killed_run(out, wait_s=0.5) and stage.exists()  # a live run's folder: left alone
    finally:
        holder.kill()
