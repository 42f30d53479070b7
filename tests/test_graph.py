"""GTSAM refinement on simulated recordings: recovery of the truth, honesty of the covariance, failure modes."""

import gtsam
import numpy as np
import pytest
from refine_cases import rotation_error_base_axes, sim_case

from plsgraph.core.geometry import make_T, rotation_error_deg
from plsgraph.core.tracks import CameraTrack, Detections
from plsgraph.errors import InputError, InsufficientDataError
from plsgraph.refine.compare import compare_solutions
from plsgraph.refine.graph import (
    RefinementOptions,
    joint_marginal_covariance,
    refine,
    seed_translation_and_board,
)


@pytest.fixture(scope="module")
def rich():
    case = sim_case("rich")
    return case, refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td)


def test_refinement_recovers_truth_on_rich_motion(rich):
    case, res = rich
    truth = case.rec.T_base_cam
    assert res.converged
    assert res.rms_px_final < 0.6  # 0.3 px per coordinate -> 0.42 px expected
    rot_err = rotation_error_deg(res.R_base_cam, truth[:3, :3])
    seed_err = rotation_error_deg(case.seed_T[:3, :3], truth[:3, :3])
    assert rot_err < seed_err / 2
    # Roll and pitch (the camera tilt, seen through the turning axis) are sharp; the yaw, tied to the direction
    # of travel, is the weak rotation axis of a 10 s recording. Each axis within 4 sigma of the truth: the
    # covariance is not overconfident.
    d = np.degrees(rotation_error_base_axes(res.R_base_cam, truth[:3, :3]))
    assert np.all(np.abs(d[:2]) < 0.3)
    assert np.all(np.abs(d) < 4 * res.sigma_rot_deg + 0.05), (d, res.sigma_rot_deg)
    assert np.linalg.norm(res.T_base_cam[:2, 3] - truth[:2, 3]) < 0.03
    # td: the seed was 5 ms off.
    assert abs(res.td - case.rec.td) < max(0.003, 4 * res.sigma_td)
    assert res.n_frames_rejected == 0
    assert res.iterations >= 1 and res.final_error < res.initial_error


def test_result_serializes_to_json(rich):
    import json

    _, res = rich
    d = json.loads(json.dumps(res.to_dict()))
    assert d["converged"] and len(d["cov_base_axes"]) == 7 and d["observability"]["axes"][5]["name"] == "z"


@pytest.mark.parametrize("optimizer", ["gtsam-lm", "dogleg"])
def test_gtsam_optimizers_reach_the_same_solution(rich, optimizer):
    case, res = rich
    other = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td,
                   RefinementOptions(optimizer=optimizer))
    assert other.converged
    assert rotation_error_deg(other.R_base_cam, res.R_base_cam) < 0.05
    assert abs(other.td - res.td) < 5e-4


def test_rich_motion_leaves_only_the_camera_height_unobservable(rich):
    _, res = rich
    rep = res.observability
    assert rep.unobservable == ("z",)
    assert set(rep.observable) >= {"roll", "pitch", "yaw", "x", "y", "td"}
    assert any("camera height" in m and "planar" in m for m in rep.messages)
    # The unobservable height keeps (about) the prior's sigma; the classification is not a fluke of scale.
    z = [a for a in rep.axes if a.name == "z"][0]
    assert z.ratio > 0.5


def test_camera_height_prior_fixes_the_height():
    case = sim_case("rich")
    h = float(case.rec.T_base_cam[2, 3])
    opt = RefinementOptions(camera_height=h, camera_height_sigma=0.005)
    res = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td, opt)
    assert abs(res.T_base_cam[2, 3] - h) < 0.01
    assert any("measured-height prior" in m for m in res.observability.messages)


def test_outlier_frames_are_rejected_and_counted():
    case = sim_case("rich")
    det = case.track.detections
    uv = det.uv.copy()
    bad = np.arange(5, len(det), 37)
    uv[bad] += 25.0  # a wrong association: every point of the frame off by 25 px
    track = CameraTrack(case.track.t, case.track.T_board_cam, detections=Detections(det.t, uv, det.board_points))
    res = refine(track, case.base, case.rec.camera, case.seed_T, case.seed_td)
    assert res.converged
    assert res.n_frames_rejected == bad.size
    d = np.degrees(rotation_error_base_axes(res.R_base_cam, case.rec.T_base_cam[:3, :3]))
    assert np.all(np.abs(d) < 4 * res.sigma_rot_deg + 0.05)


def test_unconverged_solve_gives_no_covariance():
    case = sim_case("rich")
    opt = RefinementOptions(max_iterations=1, max_passes=1)
    res = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td, opt)
    assert not res.converged
    assert res.cov is None and res.sigma_rot_deg is None
    assert set(a.status for a in res.observability.axes) == {"unknown"}
    assert any("did not converge" in w for w in res.warnings)


def test_bad_input_raises_typed_errors():
    case = sim_case("rich")
    no_det = CameraTrack(case.track.t, case.track.T_board_cam)
    with pytest.raises(InputError, match="detections"):
        refine(no_det, case.base, case.rec.camera, case.seed_T, case.seed_td)
    with pytest.raises(InputError, match="rotation"):
        refine(case.track, case.base, case.rec.camera, 2 * np.eye(4), case.seed_td)
    with pytest.raises(InputError):
        refine(case.track, case.base, case.rec.camera, case.seed_T, float("nan"))
    with pytest.raises(InsufficientDataError):  # td puts every frame outside the odometry
        refine(case.track, case.base, case.rec.camera, case.seed_T, 100.0)


def test_seed_translation_recovers_lever_arm_from_rotation():
    case = sim_case("rich")
    rec = case.rec
    t, B = seed_translation_and_board(case.track, case.base, rec.T_base_cam[:3, :3], rec.td, rec.T_base_cam[:3, 3])
    assert np.linalg.norm(t[:2] - rec.T_base_cam[:2, 3]) < 0.05
    assert rotation_error_deg(B[:3, :3], rec.T_world_board[:3, :3]) < 1.0


def test_joint_marginal_matches_gtsam_marginals_on_a_small_graph():
    rng = np.random.default_rng(0)
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    keys = [gtsam.symbol("x", k) for k in range(4)] + [gtsam.symbol("c", 0)]
    for k in keys:
        v.insert(k, gtsam.Pose3(make_T(np.eye(3), rng.normal(size=3))))
    v.insert(gtsam.symbol("t", 0), np.array([0.01]))
    noise = gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.05, 0.2, 6))
    g.add(gtsam.PriorFactorPose3(keys[0], gtsam.Pose3(), noise))
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        g.add(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(make_T(np.eye(3), rng.normal(size=3))), noise))
    g.add(gtsam.PriorFactorVector(gtsam.symbol("t", 0), np.array([0.0]), gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    want = [gtsam.symbol("c", 0), gtsam.symbol("t", 0)]
    mine = joint_marginal_covariance(g, v, want)
    jm = gtsam.Marginals(g, v).jointMarginalCovariance(gtsam.KeyVector(want))
    ref = np.block([[jm.at(a, b) for b in want] for a in want])
    assert np.allclose(mine, ref, rtol=1e-8, atol=1e-12)
    # The scipy fallback gives the same Schur complement as GTSAM's partial elimination.
    from plsgraph.refine.graph import _schur_sparse

    S = _schur_sparse(g.linearize(v), v, want)
    assert np.allclose(np.linalg.inv(S), ref, rtol=1e-8, atol=1e-12)


def test_comparison_table_with_and_without_truth(rich):
    case, res = rich
    rec = case.rec
    closed = {"closed_form": case.seed_T[:3, :3]}
    tab = compare_solutions(closed, res, camera_track=case.track, base_track=case.base, camera=rec.camera,
                            truth_T_base_cam=rec.T_base_cam, truth_td=rec.td)
    rows = {r["method"]: r for r in tab.rows}
    assert rows["refined"]["rot_err_deg"] < rows["closed_form"]["rot_err_deg"]
    seed_err = rotation_error_deg(case.seed_T[:3, :3], rec.T_base_cam[:3, :3])
    assert rows["closed_form"]["rot_err_deg"] == pytest.approx(seed_err)
    assert rows["refined"]["rms_px"] < rows["closed_form"]["rms_px"]
    assert tab.markdown.split("\n\n")[0].count("\n") == 3 and "closed_form" in tab.markdown
    # A rotation-only solver has no translation to score: shown as not determined, never as "nan".
    assert np.isnan(rows["closed_form"]["t_xy_err_m"])
    assert "nan" not in tab.markdown and "-: not determined" in tab.markdown
    # One set of keys in every row (a script reads columns), the refinement's own RMS explained.
    assert all(set(r) == set(rows["refined"]) for r in tab.rows) and np.isnan(rows["closed_form"]["rms_px_graph"])
    assert rows["refined"]["rms_px_graph"] == res.rms_px_final
    assert "rms_px_graph: the refinement's own fit" in tab.markdown
    tab2 = compare_solutions(closed, res)
    r2 = {r["method"]: r for r in tab2.rows}
    assert r2["refined"]["rot_diff_deg"] == 0.0 and r2["closed_form"]["rot_diff_deg"] > 1.0


def test_odometry_smoothing_keeps_uniform_motion_exact_up_to_the_ends():
    """A centred moving average reproduces motion at constant linear and angular velocity everywhere; a window
    that repeats the end sample would lag (start) or lead (end) the odometry there."""
    from plsgraph.core.geometry import so3_exp
    from plsgraph.refine.graph import smooth_poses

    t = np.arange(40) * 0.02
    T = np.stack([make_T(so3_exp(np.array([0.1, -0.2, 0.8]) * ti), np.array([0.5, 0.1, 0.0]) * ti) for ti in t])
    S = smooth_poses(T, 2)
    assert np.allclose(S[:, :3, 3], T[:, :3, 3], atol=1e-12)
    assert np.max(rotation_error_deg(S[:, :3, :3], T[:, :3, :3])) < 1e-4  # arccos resolves ~1e-6 deg
    # The smoothing still does its job inside: jagged (quantization-like) positions get smoother.
    rng = np.random.default_rng(0)
    J = T.copy()
    J[:, :3, 3] += rng.uniform(-1e-3, 1e-3, (t.size, 3))
    assert np.std(smooth_poses(J, 2)[5:-5, :3, 3] - T[5:-5, :3, 3]) < 0.6 * np.std(J[5:-5, :3, 3] - T[5:-5, :3, 3])


def test_odometry_smoothing_in_time_keeps_motion_exact_on_uneven_stamps():
    """Stamps 5-40 ms apart (jitter, dropped messages): a line fitted in time through each window reproduces motion at
    constant linear and angular velocity exactly, where a plain average of the window shifts each pose along the path
    by the speed times the window's mean time offset (tenths of a degree of heading at 1 rad/s)."""
    from plsgraph.core.geometry import so3_exp
    from plsgraph.refine.graph import smooth_poses

    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.005, 0.04, 60))
    w, v = np.array([0.05, -0.02, 1.0]), np.array([0.5, 0.1, 0.0])
    T = np.stack([make_T(so3_exp(w * ti), v * ti) for ti in t])
    S = smooth_poses(T, 2, t)
    assert np.allclose(S[:, :3, 3], T[:, :3, 3], atol=1e-12)
    assert np.max(rotation_error_deg(S[:, :3, :3], T[:, :3, :3])) < 1e-4
    plain = smooth_poses(T, 2)
    assert np.max(rotation_error_deg(plain[:, :3, :3], T[:, :3, :3])) > 0.2
    assert np.max(np.linalg.norm(plain[:, :3, 3] - T[:, :3, 3], axis=1)) > 1e-3
    # On even stamps the line and the average are the same.
    te = np.arange(30) * 0.02
    Te = T[:30] @ make_T(np.eye(3), np.array([0.0, 1e-3, 0.0]))
    np.testing.assert_allclose(smooth_poses(Te, 2, te), smooth_poses(Te, 2), atol=1e-12)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_frames_near_the_odometry_ends_do_not_bias_td(seed):
    """Exact odometry (no slip, no quantization) and noise-free detections whose first and last frames lie within
    the smoothing window of the odometry's ends: td and the rotation come out at the truth. With end samples
    repeated in the smoothing these few frames moved td by 3 to 6 ms and the rotation by 0.3 to 0.5 deg."""
    from plsgraph.frontend.pose import camera_track_from_detections
    from plsgraph.odometry.wheels import base_track_from_wheels
    from plsgraph.sim.robot import simulate_robot

    rec = simulate_robot("rich", duration=4.0, seed=seed, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius, rec.track_width)
    track = camera_track_from_detections(rec.detections(0.0, seed=seed), rec.camera)
    margin = 0.5 * RefinementOptions().odometry_smoothing_s
    assert track.t[0] + rec.td - base.t[0] < margin and base.t[-1] - (track.t[-1] + rec.td) < margin
    res = refine(track, base, rec.camera, rec.T_base_cam, rec.td)
    assert abs(res.td - rec.td) < 0.002
    assert rotation_error_deg(res.R_base_cam, rec.T_base_cam[:3, :3]) < 0.15


def test_detections_found_on_long_spans_weigh_less(rich):
    """A detection the front end found on m windows' events shares most of them with its neighbours: with
    weight_by_span (off by default, see RefinementOptions) its pixel sigma is sqrt(m) times larger. With every
    frame at m = 4 the camera carries a quarter of the information: the rotation sigmas grow (the odometry and
    the planar prior keep part of them), the answer stays within them, and without span weighting (or with spans
    of one window) the result is the plain one."""
    import dataclasses

    case, _ = rich
    opt = RefinementOptions(inflate_correlated=False, scale_covariance=False, add_noise_model_sensitivity=False,
                            adapt_odometry_noise=False, adapt_planar_prior=False, weight_by_span=True)
    n = len(case.track)

    def with_spans(m: float) -> CameraTrack:
        return dataclasses.replace(case.track, info={**case.track.info, "span_windows": [m] * n})

    args = (case.base, case.rec.camera, case.seed_T, case.seed_td)
    plain = refine(case.track, *args, options=opt)
    one = refine(with_spans(1.0), *args, options=opt)
    four = refine(with_spans(4.0), *args, options=opt)
    ignored = refine(with_spans(4.0), *args, options=dataclasses.replace(opt, weight_by_span=False))
    np.testing.assert_allclose(one.sigma_rot_deg, plain.sigma_rot_deg, rtol=1e-6)
    np.testing.assert_allclose(ignored.sigma_rot_deg, plain.sigma_rot_deg, rtol=1e-6)
    ratio = four.sigma_rot_deg / plain.sigma_rot_deg
    # Never smaller, at most sqrt(4) larger: the planar prior and the odometry hold roll nearly alone.
    assert np.all(ratio >= 1.0 - 1e-6) and ratio.max() > 1.2 and np.all(ratio <= 2.0 + 1e-6), ratio
    d = np.degrees(rotation_error_base_axes(four.R_base_cam, case.rec.T_base_cam[:3, :3]))
    assert np.all(np.abs(d) < 4 * four.sigma_rot_deg + 0.05)


def test_the_comparison_scores_every_solution_under_the_refined_odometry_and_no_unmeasured_height(rich):
    """Before: rms_px took the odometry as is, so on a skid-steer robot the refined row (the best answer) read 26.9
    px against 2.6-3.0 px for answers five times further off; and the refined t_err_m scored its seed height."""
    from plsgraph.refine.compare import solution_rms_px
    from plsgraph.refine.graph import scaled_base_track

    case, res = rich
    rec = case.rec
    tab = compare_solutions({"closed_form": case.seed_T[:3, :3]}, res, camera_track=case.track, base_track=case.base,
                            camera=rec.camera, truth_T_base_cam=rec.T_base_cam, truth_td=rec.td)
    rows = {r["method"]: r for r in tab.rows}
    s_v, s_w = res.odometry["speed_scale"], res.odometry["turn_scale"]
    T = res.T_base_cam.copy()
    if any(a.name == "z" and a.status != "observable" for a in res.observability.axes):
        assert np.isnan(rows["refined"]["t_err_m"]) and np.isfinite(rows["refined"]["t_xy_err_m"])
        T[2, 3] = rec.T_base_cam[2, 3]
    want = solution_rms_px(case.track, scaled_base_track(case.base, s_v, s_w), rec.camera, T, res.td)
    assert rows["refined"]["rms_px"] == pytest.approx(want)


def test_levenberg_marquardt_ends_where_a_failed_step_was_expected_to_gain_less_than_the_tolerance(monkeypatch):
    """A failed step whose gain the linear model puts below the tolerance ends the solve at once; one it expects to
    gain more is retried with more damping, as before."""
    from plsgraph.refine import graph as graph_mod

    x = gtsam.symbol("x", 0)

    def residual(this, v, H=None):  # x - 1, with a bump just above the minimum that the linear model does not see
        xv = float(v.atVector(x)[0])
        if H is not None:
            H[0] = np.ones((1, 1))
        return np.array([xv - 1.0 + (0.01 if xv < 1.0007 else 0.0)])

    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [x], residual))
    start = gtsam.Values()
    start.insert(x, np.array([1.001]))
    solves = []
    real = graph_mod._damped_solve
    monkeypatch.setattr(graph_mod, "_damped_solve", lambda *a: solves.append(a[-1]) or real(*a))
    # The first step (damping 1) lands on the bump; the model expected 3.75e-7 from it.
    values, it, converged = graph_mod._levenberg_marquardt(g, start, RefinementOptions(absolute_tol=1e-6))
    assert converged and solves == [1.0] and values.atVector(x)[0] == 1.001
    solves.clear()
    values, it, converged = graph_mod._levenberg_marquardt(g, start, RefinementOptions(absolute_tol=1e-12,
                                                                                      relative_tol=1e-12))
    assert solves[:2] == [1.0, 10.0] and 1.0007 <= values.atVector(x)[0] < 1.001


def test_the_result_keeps_the_graphs_residuals_the_residual_figure_draws(rich, tmp_path):
    """The residual figure shows what the refinement fitted: the frames it solved and their residuals at the
    solution, whose RMS is the result's (drawn from the odometry as recorded instead, a skid-steer robot's turns put
    tens of pixels on a good calibration)."""
    from types import SimpleNamespace

    from plsgraph.report.figures import _fig_residuals, _graph_residuals, figure_inputs

    case, res = rich
    assert res.residual_px.shape == (res.n_frames, case.track.detections.board_points.shape[0], 2)
    assert res.residual_t.shape == (res.n_frames,) and set(res.residual_t) <= set(case.track.t)
    r = res.residual_px.astype(float)
    assert np.sqrt(np.nanmean(np.sum(r**2, axis=-1))) == pytest.approx(res.rms_px_final, rel=1e-5)
    run = SimpleNamespace(refinement=res, closed_form=None, camera_track=case.track, base_track=case.base,
                          camera=case.rec.camera, truth=None, still_frames=None)
    inputs = figure_inputs(run)
    t, rms, flat = _graph_residuals(inputs.refinement)
    assert np.array_equal(t, res.residual_t) and rms.size == res.n_frames and np.isfinite(flat).all()
    assert _fig_residuals(inputs, tmp_path) == "residuals.png"
    # What on_solution is handed carries them too, the same numbers (the speculative figures are kept only then).
    sent = {}
    again = refine(case.track, case.base, case.rec.camera, case.seed_T, case.seed_td,
                   on_solution=lambda sol: sent.setdefault("sol", sol))
    assert np.array_equal(sent["sol"].residual_t, again.residual_t)
    assert np.array_equal(sent["sol"].residual_px, again.residual_px, equal_nan=True)
    assert np.array_equal(sent["sol"].knot_t, again.knot_t)  # and the knots the trajectories figure draws
    assert np.array_equal(sent["sol"].T_world_base, again.T_world_base)
    drawn = figure_inputs(SimpleNamespace(**{**vars(run), "refinement": None}), sent["sol"]).refinement
    assert np.array_equal(drawn.T_world_base, again.T_world_base) and np.array_equal(drawn.knot_t, again.knot_t)


def test_the_focal_lengths_sensitivity_is_the_move_a_longer_focal_length_makes_and_enters_the_sigmas(rich):
    """A red-team recording whose camera info had the focal length 4 % long came out with the lever arm 59 mm off at
    4.9 sigma: a constant depth error of every view is a lever arm along the optical axis, and no sigma held it. The
    first-order move for 1 % is reported, and --focal-sigma's share of it is added to each variance."""
    import dataclasses

    from plsgraph.core.camera import CameraModel

    case, res = rich
    sens = res.inflation["focal_length_sensitivity"]
    assert sens["focal_change"] == 0.01 and sens["focal_sigma_in_sigmas"] == 0.0
    cam = case.rec.camera
    K = cam.K.copy()
    K[:2, :2] *= 1.01
    longer = refine(case.track, case.base, CameraModel(cam.width, cam.height, K, cam.dist), case.seed_T, case.seed_td)
    moved = longer.T_base_cam[:3, 3] - res.T_base_cam[:3, 3]  # base axes x, y, z
    assert abs(sens["x"]) > 5e-3  # a board 1-3 m away: centimetres per percent
    assert moved[0] == pytest.approx(sens["x"], rel=0.2, abs=1e-3)
    assert moved[1] == pytest.approx(sens["y"], rel=0.2, abs=1e-3)
    # In the sigmas: the variance plus (move per unit x 0.5 %)^2, the estimate as it was.
    held = refine(case.track, case.base, cam, case.seed_T, case.seed_td,
                  dataclasses.replace(RefinementOptions(), focal_sigma_rel=0.005))
    assert np.allclose(held.T_base_cam, res.T_base_cam, atol=1e-9) and held.td == pytest.approx(res.td, abs=1e-12)
    sig0, sig1 = np.sqrt(np.diag(res.cov_base_axes)), np.sqrt(np.diag(held.cov_base_axes))
    want = np.hypot(sig0[3], 0.5 * abs(sens["x"]))
    assert sig1[3] == pytest.approx(want, rel=1e-6)
    assert held.inflation["focal_length_sensitivity"]["focal_sigma_in_sigmas"] == 0.005
    # The effective wheel radius moves with the focal length too (the camera's distances do): its scale's variance
    # gets the same share, and the extrinsic's correlations hold the shared sign (a rank-one term).
    s_v = 0.5 * sens["speed_scale"]
    assert abs(sens["speed_scale"]) > 3e-3
    assert held.odometry["speed_scale_sigma"] ** 2 == pytest.approx(res.odometry["speed_scale_sigma"] ** 2 + s_v**2,
                                                                      rel=0.05)
    move = np.array([sens[a] for a in ("roll", "pitch", "yaw", "x", "y", "z", "td")]) * 0.5
    assert np.allclose(held.cov_base_axes - res.cov_base_axes, np.outer(move, move), atol=1e-12)
