"""The camera model's lens distortion checked against the board views (plsgraph.calib.lens), the calibration's move
to the views' distortion (refine.graph.camera_sensitivity) and the gate's flag."""

import dataclasses
from functools import lru_cache

import cv2
import numpy as np
import pytest

import plsgraph
from plsgraph.calib import lens
from plsgraph.errors import InputError
from plsgraph.frontend.pose import camera_track_from_detections
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.refine.graph import RefinementOptions
from plsgraph.sim.realism import only
from plsgraph.sim.robot import simulate_robot

BOARD = "acircles_4x11_a2"


@lru_cache(maxsize=1)
def _drive():
    """A 15 s rich drive seen through a lens with k1 -0.06, k2 +0.02 (as an independent recording whose camera info
    left them out), 0.3 px detections, nominal odometry."""
    fx = only("lens_distortion")
    fx = dataclasses.replace(fx, sensor=dataclasses.replace(fx.sensor, k1=-0.06, k2=0.02))
    rec = simulate_robot("rich", duration=15.0, seed=5, realism=fx)
    base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius_nominal,
                                  rec.track_width_nominal)
    return rec, base, rec.detections(0.3, seed=15)


def _no_distortion(camera):
    return dataclasses.replace(camera, dist=np.zeros(5))


def test_the_views_find_the_lens_a_camera_model_without_distortion_leaves_out():
    rec, _, det = _drive()
    assert rec.camera.dist[0] == pytest.approx(-0.06) and rec.camera.dist[1] == pytest.approx(0.02)
    wrong = lens.distortion_from_views(det.uv, det.board_points, _no_distortion(rec.camera))
    right = lens.distortion_from_views(det.uv, det.board_points, rec.camera)
    assert wrong is not None and right is not None
    assert wrong.n_frames == lens.MAX_FRAMES
    # The views' k1 and k2 against the lens's (k1 and k2 trade off against each other; the displacement where the
    # board was seen is what is determined)
    sig = np.sqrt(np.diag(wrong.cov))
    assert np.all(np.abs(wrong.views - rec.camera.dist[:2]) < np.maximum(4 * sig, [0.01, 0.03])), (wrong.views, sig)
    truth_shift = lens._radial_px(rec.camera, rec.camera.dist[:2], wrong.radius)
    assert wrong.shift_px == pytest.approx(truth_shift, abs=max(3 * wrong.shift_sigma_px, 0.05))
    assert truth_shift < -0.5  # barrel: points pulled inwards, by more than half a pixel at the board's outer radii
    assert wrong.significant and wrong.rms_px < 0.5  # per point (both coordinates): 0.3 px each gives 0.42
    # With the lens's own coefficients the views agree with the camera model
    assert not right.significant, right.to_dict()
    assert abs(right.shift_px) < 3 * max(right.shift_sigma_px, 0.03)
    d = wrong.to_dict()
    assert d["significant"] is True and d["frames"] == lens.MAX_FRAMES and len(d["k1_k2_views"]) == 2
    np.testing.assert_array_equal(wrong.camera(rec.camera).dist[:2], wrong.views)
    np.testing.assert_array_equal(wrong.camera(rec.camera).dist[2:], rec.camera.dist[2:])


def test_too_few_views_or_broken_input_gives_no_check():
    rec, _, det = _drive()
    few = det.uv[: lens.MIN_FRAMES - 1]
    assert lens.distortion_from_views(few, det.board_points, rec.camera) is None
    assert lens.distortion_from_views(det.uv[:, :5], det.board_points, rec.camera) is None  # shapes disagree
    empty = np.full_like(det.uv, np.nan)
    assert lens.distortion_from_views(empty, det.board_points, rec.camera) is None


def test_the_lens_option_is_checked():
    with pytest.raises(InputError, match="lens_distortion_views"):
        RefinementOptions(lens_distortion_views=(0.1, float("nan")))
    with pytest.raises(InputError, match="lens_distortion_views"):
        RefinementOptions(lens_distortion_views=(0.1,))


def test_a_camera_model_without_its_distortion_is_flagged_with_the_move_it_makes():
    """A camera info published without the lens's distortion: the fit looks good and the lever arm is off by several
    sigmas. The board views name the distortion, the refinement measures what it moves (one Gauss-Newton step), and
    the move agrees with calibrating again with the views' distortion; the result is flagged."""
    rec, base, det = _drive()
    wrong_cam = _no_distortion(rec.camera)
    track = camera_track_from_detections(det, wrong_cam)
    r = plsgraph.calibrate_tracks(track, base, wrong_cam, board=BOARD)
    ref = r.run.refinement
    check = r.run.lens
    assert check is not None and check.significant
    move = ref.inflation["lens_distortion_move"]
    assert move["k1_k2"] == pytest.approx(list(check.views))
    assert not r.ok
    assert any("lens distortion" in p and "--camera-info" in p for p in r.problems), r.problems
    assert any("board views want another lens distortion" in w for w in r.warnings)
    from plsgraph.result import robot_sections

    sec = robot_sections(r.run)["lens_distortion"]
    assert sec["significant"] is True and sec["calibration_move"]["x_m"] == pytest.approx(move["x"])
    assert sec["k1_k2_views"] == pytest.approx(list(check.views))
    # The move, against calibrating again with the views' distortion (the same detections)
    views_cam = check.camera(rec.camera)
    again = plsgraph.calibrate_tracks(camera_track_from_detections(det, views_cam), base, views_cam, board=BOARD)
    d_x = again.run.refinement.T_base_cam[0, 3] - ref.T_base_cam[0, 3]
    assert abs(move["x"]) > 0.03  # centimetres: what the missing distortion costs here
    assert move["x"] == pytest.approx(d_x, rel=0.3), (move["x"], d_x)
    # and the error it leaves: the result's x error is mostly the move
    err_x = ref.T_base_cam[0, 3] - rec.T_base_cam[0, 3]
    assert abs(err_x + move["x"]) < 0.5 * abs(err_x), (err_x, move["x"])
    # Checked again with its views' distortion, the camera model agrees with the views and nothing is flagged on it
    assert again.run.lens is not None and not again.run.lens.significant
    assert not any("lens distortion" in p for p in again.problems)


def test_the_gate_reads_the_move_against_the_sigmas():
    from types import SimpleNamespace

    from plsgraph.gate import LENS_MOVE_LIMIT, lens_move_text, lens_problems

    cov = np.diag(np.array([0.1, 0.1, 1.0, 10.0, 10.0, 1000.0, 5.0]) ** 2 * np.array([3e-4] * 3 + [1e-6] * 3 + [1e-6]))
    sig = np.sqrt(np.diag(cov))
    inside = {"k1_k2": [-0.1, 0.05], "roll": 0.0, "pitch": 0.0, "yaw": 0.0, "x": (LENS_MOVE_LIMIT - 0.1) * sig[3],
              "y": 0.0, "z": 0.0, "td": 0.0}
    beyond = dict(inside, x=(LENS_MOVE_LIMIT + 0.1) * sig[3], z=100.0)  # z is not judged (unobservable)
    ok = SimpleNamespace(inflation={"lens_distortion_move": inside}, cov_base_axes=cov)
    bad = SimpleNamespace(inflation={"lens_distortion_move": beyond}, cov_base_axes=cov)
    assert lens_problems(ok) == []
    (p,) = lens_problems(bad)
    assert "x +" in p and "2.1 sigma" in p and "k1 -0.100" in p
    assert lens_move_text(bad).startswith("x +")
    units = dict(inside, yaw=3.0 * sig[2], td=3.0 * sig[6])  # radians and seconds, read as degrees and ms
    (p,) = lens_problems(SimpleNamespace(inflation={"lens_distortion_move": units}, cov_base_axes=cov))
    assert f"yaw {np.degrees(3.0 * sig[2]):+.2f} deg (3.0 sigma)" in p and f"td {3e3 * sig[6]:+.1f} ms (3.0 sigma)" in p
    assert lens_problems(SimpleNamespace(inflation={}, cov_base_axes=cov)) == []
    assert lens_problems(SimpleNamespace(inflation={"lens_distortion_move": beyond}, cov_base_axes=None)) == []


def test_the_views_distortion_is_written_as_a_camera_file_for_a_second_run(tmp_path):
    """camera_from_board_views.yaml: the camera model with the views' k1, k2, which --camera-info reads back; written
    only when the views disagree with the camera model."""
    from types import SimpleNamespace

    from plsgraph.io.camera_files import load_camera_file
    from plsgraph.report.robot_files import LENS_CAMERA_NAME, write_lens_camera

    rec, _, det = _drive()
    wrong_cam = _no_distortion(rec.camera)
    check = lens.distortion_from_views(det.uv, det.board_points, wrong_cam)
    result = SimpleNamespace(run=SimpleNamespace(lens=check, camera=wrong_cam, log_path=tmp_path / "rec.mcap"))
    (path,) = write_lens_camera(tmp_path, result)
    assert path == tmp_path / LENS_CAMERA_NAME
    back = load_camera_file(path)
    np.testing.assert_allclose(back.K, wrong_cam.K, rtol=1e-12)
    np.testing.assert_allclose(back.dist[:2], check.views, rtol=1e-12)
    assert (back.width, back.height) == (wrong_cam.width, wrong_cam.height)
    assert "rec.mcap" in path.read_text()
    agreeing = lens.distortion_from_views(det.uv, det.board_points, rec.camera)
    other = tmp_path / "other"
    other.mkdir()
    assert write_lens_camera(other, SimpleNamespace(run=SimpleNamespace(lens=agreeing, camera=rec.camera,
                                                                        log_path="x"))) == []
    assert write_lens_camera(other, SimpleNamespace(run=None)) == [] and not any(other.iterdir())


def test_the_no_distortion_warning_is_dropped_when_the_views_agree_with_no_distortion():
    """Rectified events: the camera model has no distortion and the views agree; the warning that a camera info
    without distortion may be wrong is dropped. When they disagree, or were not checked, it stays."""
    from pathlib import Path

    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, drop_confirmed_no_distortion_warning, no_distortion_warning

    rec, _, _ = _drive()
    det = rec.detections(0.1, seed=15)  # 0.3 px gives a jackknife sigma of 0.17 px here: too noisy to show agreement
    flat = _no_distortion(rec.camera)
    (said,) = no_distortion_warning(flat)
    straight = det.uv.copy()  # the views as a lens without distortion would give them: undistorted pixels
    ok = np.all(np.isfinite(straight), axis=2)
    pts = cv2.undistortPoints(straight[ok].reshape(-1, 1, 2), rec.camera.K, rec.camera.dist, P=rec.camera.K)
    straight[ok] = pts.reshape(-1, 2)
    agree = lens.distortion_from_views(straight, det.board_points, flat)
    disagree = lens.distortion_from_views(det.uv, det.board_points, flat)
    assert agree is not None and not agree.significant and disagree.significant
    for check, kept in ((agree, False), (disagree, True), (None, True)):
        run = Run(Path("x.mcap"), CalibrationOptions(board="acircles_4x11_a2"), camera=flat)
        run.warn("another warning", said)
        run.lens = check
        drop_confirmed_no_distortion_warning(run)
        assert (said in run.warnings) == kept and "another warning" in run.warnings
    run = Run(Path("x.mcap"), CalibrationOptions(board="acircles_4x11_a2"), camera=rec.camera)
    run.warn(said)
    run.lens = agree
    drop_confirmed_no_distortion_warning(run)  # a camera model with distortion: not this warning's case
    assert run.warnings == [said]


def test_a_view_that_fits_far_worse_is_left_out():
    """A mislabelled grid (the points' order reversed) in one of the views used: the fit leaves it out and finds what
    it finds without it."""
    rec, _, det = _drive()
    cam = _no_distortion(rec.camera)
    clean = lens.distortion_from_views(det.uv, det.board_points, cam)
    uv = det.uv.copy()
    found = np.all(np.isfinite(uv), axis=2)
    full = np.flatnonzero(found.all(axis=1))
    used = full[np.unique(np.linspace(0, full.size - 1, min(lens.MAX_FRAMES, full.size)).round().astype(int))]
    for i in used[[10, 40]]:
        uv[i] = uv[i][::-1]
    bad = lens.distortion_from_views(uv, det.board_points, cam)
    assert bad.n_frames == clean.n_frames - 2
    assert bad.shift_px == pytest.approx(clean.shift_px, abs=2 * clean.shift_sigma_px)
    assert bad.rms_px < 1.5 * clean.rms_px


def test_a_result_folder_with_the_views_camera_file_can_be_replaced(tmp_path):
    """camera_from_board_views.yaml is one of plsgraph's result files: --force replaces a folder holding it."""
    from plsgraph.report.files import RESULT_FILES, prepare_output_dir
    from plsgraph.report.robot_files import LENS_CAMERA_NAME

    assert LENS_CAMERA_NAME in RESULT_FILES
    out = tmp_path / "out"
    out.mkdir()
    for name in ("calibration.yaml", "report.json", LENS_CAMERA_NAME):
        (out / name).write_text("x: 1\n")
    prepare_output_dir(out, force=True)  # refused before: "holds files plsgraph did not write"


def test_a_check_too_noisy_to_tell_keeps_the_no_distortion_warning():
    from pathlib import Path

    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, drop_confirmed_no_distortion_warning, no_distortion_warning

    rec, _, _ = _drive()
    flat = _no_distortion(rec.camera)
    (said,) = no_distortion_warning(flat)
    for shift, sigma, kept in ((0.05, 0.02, False), (0.1, 0.15, True), (-0.2, 0.06, True)):
        check = lens.LensCheck(given=np.zeros(2), views=np.zeros(2), cov=np.eye(2) * 1e-6, radius=0.5,
                               shift_px=shift, shift_sigma_px=sigma, n_frames=80, rms_px=0.3)
        assert not check.significant
        run = Run(Path("x.mcap"), CalibrationOptions(board=BOARD), camera=flat)
        run.warn(said)
        run.lens = check
        drop_confirmed_no_distortion_warning(run)
        assert (said in run.warnings) == kept, (shift, sigma)
