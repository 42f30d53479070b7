"""Analytic Jacobians of every factor against central differences on the manifold (gtsam retract)."""

import gtsam
import numpy as np
import pytest

from factors.lie import so3_right_jacobian, so3_right_jacobian_inv
from factors.odometry import OdometryNoise, make_odometry_factors, odometry_covariance, path_increments
from factors.planar import make_planar_factor
from factors.priors import make_height_prior, make_rotation_prior, make_subspace_prior, make_vertical_board_prior
from factors.reprojection import (
    FrameBatch,
    OdometryDetail,
    ReprojectionFrames,
    evaluate_frames,
    make_reprojection_factors,
)
from plsgraph.core.board import load_board
from plsgraph.core.camera import davis346_default
from plsgraph.core.geometry import inv_T, make_T, se3_exp, so3_exp

X = gtsam.symbol("x", 0)


def numeric_whitened_jacobians(factor, values, eps=1e-6):
    """Central differences of the whitened error, variable by variable, through gtsam's retract."""
    cols = []
    for key in factor.keys():
        try:
            pose = values.atPose3(key)
            dim, kind = 6, "pose"
        except RuntimeError:
            vec = values.atVector(key)
            dim, kind = vec.size, "vec"
        J = []
        for j in range(dim):
            d = np.zeros(dim)
            d[j] = eps
            errs = []
            for sign in (1.0, -1.0):
                v = gtsam.Values(values)
                if kind == "pose":
                    v.update(key, pose.retract(sign * d))
                else:
                    v.update(key, vec + sign * d)
                errs.append(factor.whitenedError(v))
            J.append((errs[0] - errs[1]) / (2 * eps))
        cols.append(np.stack(J, axis=1))
    return np.concatenate(cols, axis=1)


def analytic_whitened_jacobian(factor, values):
    A, _ = factor.linearize(values).jacobian()
    return A


def assert_jacobians(factor, values, rtol=1e-5, atol=1e-6):
    A = analytic_whitened_jacobian(factor, values)
    N = numeric_whitened_jacobians(factor, values)
    scale = max(1.0, np.abs(N).max())
    assert A.shape == N.shape
    assert np.abs(A - N).max() <= atol * scale + rtol * np.abs(N).max(), np.abs(A - N).max()


def random_pose(rng, rot=np.pi, trans=2.0):
    return se3_exp(np.concatenate([rng.normal(size=3) * rot / 2, rng.normal(size=3) * trans]))


def odometry_track(rng, t0=-1.0, t1=2.0, rate=50.0):
    """A smooth full-rate odometry trajectory (constant-ish twist with wiggles)."""
    t = np.arange(t0, t1, 1.0 / rate)
    w = rng.normal(scale=0.5, size=6)
    xi = np.outer(t, w) + 0.05 * np.sin(np.outer(t, rng.uniform(1, 5, 6)))
    return t, se3_exp(xi)


def reprojection_case(rng, m=3, corr=True, holes=True):
    """m frames of a board in front of a camera mounted on a moving base, at a random state."""
    camera = davis346_default()
    board = load_board("acircles_4x11")
    P = board.points
    t = np.sort(rng.uniform(0.0, 1.0, m)) + 1e-3 * rng.uniform(0.1, 0.9)  # off the odometry sample grid
    h = rng.uniform(0.05, 0.2, m)
    t_a = t - rng.uniform(0.1, 0.9, m) * h
    t_b = t_a + h
    td = float(rng.normal(scale=0.01))
    C = make_T(so3_exp(rng.normal(size=3)), rng.normal(scale=0.3, size=3))
    Xa = np.stack([random_pose(rng) for _ in range(m)])
    Xb = Xa @ se3_exp(rng.normal(scale=0.2, size=(m, 6)))
    odo = None
    if corr:
        from plsgraph.core.geometry import interpolate_poses

        to, To = odometry_track(rng)
        odo = OdometryDetail(to, To, interpolate_poses(t_a, to, To), interpolate_poses(t_b, to, To))
    # Board about 1 m in front of the camera of frame 0, facing it.
    frames = ReprojectionFrames(t, t_a, t_b, np.zeros((m, len(P), 2)), P, camera, odo)
    T_cam_board = make_T(so3_exp(rng.normal(scale=0.2, size=3)), np.array([-0.15, -0.1, 1.0]))
    X0 = _frame_base_pose(frames, Xa, Xb, td)[0]
    B = X0 @ C @ T_cam_board
    # Measurements: the prediction at a nearby state plus noise, so residuals are small but not zero.
    pred = evaluate_frames(frames, Xa, Xb, C, B, td, jacobians=False).residual
    uv = pred + rng.normal(scale=0.5, size=pred.shape)
    if holes:
        uv[0, :5] = np.nan
    frames = ReprojectionFrames(t, t_a, t_b, uv, P, camera, odo)
    return frames, Xa, Xb, C, B, td


def _frame_base_pose(frames, Xa, Xb, td):
    from factors.reprojection import interpolation_jacobians, odometry_detail

    s = (frames.t + td - frames.t_a) / (frames.t_b - frames.t_a)
    Y = interpolation_jacobians(Xa, Xb, s)[0]
    if frames.odometry is None:
        return Y
    return Y @ odometry_detail(frames.odometry, frames.t + td, s)[0]


def reprojection_values(frames, Xa, Xb, C, B, td):
    m = len(frames)
    knot_keys = np.array([gtsam.symbol("x", k) for k in range(2 * m)])
    knot_index = np.stack([np.arange(0, 2 * m, 2), np.arange(1, 2 * m, 2)], axis=1)
    v = gtsam.Values()
    for i in range(m):
        v.insert(int(knot_keys[2 * i]), gtsam.Pose3(Xa[i]))
        v.insert(int(knot_keys[2 * i + 1]), gtsam.Pose3(Xb[i]))
    ck, bk, tk = gtsam.symbol("c", 0), gtsam.symbol("b", 0), gtsam.symbol("t", 0)
    v.insert(ck, gtsam.Pose3(C))
    v.insert(bk, gtsam.Pose3(B))
    v.insert(tk, np.array([td]))
    batch = FrameBatch(frames, knot_keys, knot_index, ck, bk, tk)
    return batch, v


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reprojection_jacobians_at_random_states(seed):
    rng = np.random.default_rng(seed)
    frames, Xa, Xb, C, B, td = reprojection_case(rng, m=1, corr=seed > 0, holes=seed == 2)
    batch, values = reprojection_values(frames, Xa, Xb, C, B, td)
    (factor,) = make_reprojection_factors(batch, sigma_px=1.0, robust=None)
    # Only the frame's own visible points are in the residual.
    assert factor.dim() == 2 * int(frames.valid[0].sum())
    assert_jacobians(factor, values, rtol=1e-5)


def test_reprojection_residual_zero_at_truth_and_nan_points_dropped():
    rng = np.random.default_rng(5)
    frames, Xa, Xb, C, B, td = reprojection_case(rng, m=2, holes=False)
    clean = evaluate_frames(frames, Xa, Xb, C, B, td, jacobians=False).residual + frames.uv
    uv = clean.copy()
    uv[1, [3, 7]] = np.nan
    frames = ReprojectionFrames(frames.t, frames.t_a, frames.t_b, uv, frames.board_points, frames.camera,
                                frames.odometry)
    batch, values = reprojection_values(frames, Xa, Xb, C, B, td)
    f0, f1 = make_reprojection_factors(batch, sigma_px=1.0, robust=None)
    assert np.abs(f0.unwhitenedError(values)).max() < 1e-9
    assert f1.dim() == 2 * (frames.board_points.shape[0] - 2)
    assert np.all(np.isfinite(f1.unwhitenedError(values)))


def test_frame_batch_serves_each_factor_its_own_values():
    """The batch cache must give the same answer as evaluating each frame alone, whatever the call order."""
    rng = np.random.default_rng(7)
    frames, Xa, Xb, C, B, td = reprojection_case(rng, m=4)
    batch, values = reprojection_values(frames, Xa, Xb, C, B, td)
    factors = make_reprojection_factors(batch, sigma_px=1.0, robust=None)
    v2 = gtsam.Values(values)
    v2.update(gtsam.symbol("c", 0), gtsam.Pose3(C @ se3_exp(rng.normal(scale=0.01, size=6))))
    v2.update(gtsam.symbol("t", 0), np.array([td + 0.003]))
    for vals in (values, v2, values, v2):
        for i, f in enumerate(factors):
            sub = frames.take(i)
            ev = evaluate_frames(sub, Xa[i : i + 1], Xb[i : i + 1], vals.atPose3(gtsam.symbol("c", 0)).matrix(), B,
                                 float(vals.atVector(gtsam.symbol("t", 0))[0]), jacobians=False)
            expect = ev.residual[0][sub.valid[0]].ravel()
            assert np.allclose(f.unwhitenedError(vals), expect, atol=1e-10)
    # Alternating values for every call exercises the one-frame path too.
    for f in factors:
        for vals in (values, v2):
            A = analytic_whitened_jacobian(f, vals)
            assert np.isfinite(A).all()
    assert batch.n_single > 0


def test_a_graph_evaluated_at_its_values_gives_the_same_error_and_linearization():
    """Inside FrameBatch.evaluated_at the factors skip reading their values: a whole graph's error and linear system
    are the same numbers as with the per-factor checks, and after it the checks are back (other values answered)."""
    rng = np.random.default_rng(11)
    frames, Xa, Xb, C, B, td = reprojection_case(rng, m=5, corr=True, holes=True)
    batch, values = reprojection_values(frames, Xa, Xb, C, B, td)
    graph = gtsam.NonlinearFactorGraph()
    for f in make_reprojection_factors(batch, sigma_px=0.7, robust="huber"):
        graph.add(f)
    v2 = gtsam.Values(values)
    v2.update(gtsam.symbol("c", 0), gtsam.Pose3(C @ se3_exp(rng.normal(scale=0.02, size=6))))
    v2.update(gtsam.symbol("t", 0), np.array([td - 0.004]))
    plain_errs = []
    for vals in (values, v2):
        plain_err = graph.error(vals)
        plain_errs.append(plain_err)
        plain_lin = graph.linearize(vals).jacobian()
        with batch.evaluated_at(vals, jacobians=False):
            fast_err = graph.error(vals)
        with batch.evaluated_at(vals, jacobians=True):
            fast_lin = graph.linearize(vals).jacobian()
        assert fast_err == plain_err
        assert np.array_equal(fast_lin[0], plain_lin[0]) and np.array_equal(fast_lin[1], plain_lin[1])
    # Left the context: a factor asked about other values than the last evaluation's evaluates them.
    with batch.evaluated_at(v2, jacobians=False):
        pass
    assert graph.error(values) == plain_errs[0] != plain_errs[1]
    # Left through an exception: the checks are back as well.
    with pytest.raises(KeyError), batch.evaluated_at(v2, jacobians=False):
        raise KeyError("stop")
    assert graph.error(values) == plain_errs[0]
    # A linearization inside a context evaluated without Jacobians evaluates them (the checked path).
    with batch.evaluated_at(values, jacobians=False):
        lin = graph.linearize(values).jacobian()
    assert np.array_equal(lin[0], graph.linearize(values).jacobian()[0])


def test_robust_reprojection_noise_keeps_inliers_at_full_weight():
    rng = np.random.default_rng(3)
    frames, Xa, Xb, C, B, td = reprojection_case(rng, m=1, holes=False)
    batch, values = reprojection_values(frames, Xa, Xb, C, B, td)
    (plain,) = make_reprojection_factors(batch, sigma_px=0.5, robust=None)
    (huber,) = make_reprojection_factors(batch, sigma_px=0.5, robust="huber", robust_k=1.5)
    # An inlier frame (0.5 px noise): Huber leaves the error unchanged.
    assert huber.error(values) == pytest.approx(plain.error(values), rel=1e-9)


def test_fast_projection_matches_camera_model():
    from factors.reprojection import _project_with_jacobian

    rng = np.random.default_rng(13)
    cam = davis346_default()
    p = np.c_[rng.normal(scale=0.4, size=(50, 2)), rng.uniform(0.5, 3.0, 50)]
    uv, J = cam.project(p, with_jacobian=True)
    uv2, J2 = _project_with_jacobian(cam, p)
    assert np.allclose(uv, uv2, atol=1e-10) and np.allclose(J, J2, atol=1e-10)


def test_so3_jacobians_match_gtsam_and_are_inverse():
    rng = np.random.default_rng(11)
    w = np.concatenate([rng.normal(size=(5, 3)), 1e-9 * rng.normal(size=(2, 3))])
    Jr = so3_right_jacobian(w)
    for k in range(len(w)):
        assert np.allclose(Jr[k], gtsam.Rot3.ExpmapDerivative(w[k]), atol=1e-9)
    assert np.allclose(Jr @ so3_right_jacobian_inv(w), np.eye(3), atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_planar_prior_jacobian(seed):
    rng = np.random.default_rng(seed)
    values = gtsam.Values()
    values.insert(X, gtsam.Pose3(random_pose(rng, rot=0.5)))
    f = make_planar_factor(X, sigma_z=0.01, sigma_tilt=0.02, z0=0.1)
    assert_jacobians(f, values)


def test_planar_prior_zero_on_the_floor_whatever_the_heading():
    values = gtsam.Values()
    values.insert(X, gtsam.Pose3(make_T(so3_exp(np.array([0, 0, 2.3])), np.array([4.0, -1.0, 0.0]))))
    assert np.abs(make_planar_factor(X).unwhitenedError(values)).max() < 1e-12


@pytest.mark.parametrize("seed", [0, 1])
def test_prior_jacobians(seed):
    rng = np.random.default_rng(seed)
    values = gtsam.Values()
    values.insert(X, gtsam.Pose3(random_pose(rng)))
    R_prior = so3_exp(rng.normal(size=3))
    for f in (
        make_rotation_prior(X, R_prior, 0.1),
        make_height_prior(X, 0.3, 0.01),
        make_vertical_board_prior(X, 0.02),
    ):
        assert_jacobians(f, values)


def test_subspace_prior_jacobian_and_zero_at_reference():
    rng = np.random.default_rng(12)
    T0 = random_pose(rng)
    W = rng.normal(size=(2, 7))
    tk = gtsam.symbol("t", 0)
    values = gtsam.Values()
    values.insert(X, gtsam.Pose3(T0))
    values.insert(tk, np.array([0.02]))
    f = make_subspace_prior(X, tk, T0, [0.02], W, 0.1)
    assert np.abs(f.unwhitenedError(values)).max() < 1e-12
    values.update(X, gtsam.Pose3(T0 @ se3_exp(rng.normal(scale=0.3, size=6))))
    values.update(tk, np.array([0.05]))
    assert_jacobians(f, values)


def test_odometry_covariance_grows_with_distance_and_angle():
    noise = OdometryNoise(sigma_per_metre=0.05, yaw_per_radian=0.03, yaw_per_metre=0.01)
    c = odometry_covariance([0.0, 1.0, 4.0, 1.0], [0.0, 0.0, 0.0, 2.0], noise)
    assert c.shape == (4, 6, 6)
    assert np.all(np.linalg.eigvalsh(c) > 0)  # positive definite even standing still
    assert c[2, 3, 3] == pytest.approx(4 * c[1, 3, 3], rel=1e-3)  # along-track variance linear in distance
    assert c[3, 2, 2] - c[1, 2, 2] == pytest.approx(0.03**2 * 2.0)  # heading variance linear in the angle
    # Sideways drift comes from driving with a wrong heading: var_y = d^2 var_yaw / 3 (+ skid), far below var_x.
    assert c[1, 4, 4] == pytest.approx(c[1, 2, 2] / 3 + noise.lateral_per_metre**2 + noise.floor_m**2)
    assert c[1, 4, 4] < 0.1 * c[1, 3, 3]


def test_odometry_between_factors_zero_on_odometry_and_path_increments():
    rng = np.random.default_rng(4)
    yaw = np.cumsum(rng.normal(scale=0.05, size=50))
    step = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(50)], axis=1) * 0.02
    T = make_T(so3_exp(np.stack([np.zeros(50), np.zeros(50), yaw], 1)), np.cumsum(step, axis=0))
    knots = np.arange(0, 50, 7)
    d, a = path_increments(np.arange(50) * 0.02, T, knots)
    assert d.sum() == pytest.approx(0.02 * (knots[-1] - knots[0]), rel=1e-9)
    assert a.sum() == pytest.approx(np.abs(np.diff(yaw[knots[0] : knots[-1] + 1])).sum(), rel=1e-6)
    keys = [gtsam.symbol("x", k) for k in range(len(knots))]
    values = gtsam.Values()
    for k, i in zip(keys, knots, strict=True):
        values.insert(k, gtsam.Pose3(T[i]))
    fs = make_odometry_factors(keys, T[knots], d, a)
    assert len(fs) == len(knots) - 1
    assert max(abs(f.error(values)) for f in fs) < 1e-12
    v2 = gtsam.Values(values)
    v2.update(keys[2], gtsam.Pose3(T[knots[2]] @ make_T(np.eye(3), np.array([0.01, 0, 0]))))
    assert fs[1].error(v2) > 0


def test_odometry_detail_makes_the_base_pose_follow_the_odometry():
    """With the graph knots equal to the odometry's, a frame's base pose is the odometry pose at t + td."""
    from plsgraph.core.geometry import interpolate_poses

    rng = np.random.default_rng(21)
    to, To = odometry_track(rng)
    t = np.array([0.1234, 0.5678])
    t_a, t_b = t - 0.06, t + 0.05
    odo = OdometryDetail(to, To, interpolate_poses(t_a, to, To), interpolate_poses(t_b, to, To))
    P = load_board("acircles_4x11").points
    frames = ReprojectionFrames(t, t_a, t_b, np.zeros((2, len(P), 2)), P, davis346_default(), odo)
    for td in (0.0, 0.013, -0.02):
        X = _frame_base_pose(frames, odo.T_a, odo.T_b, td)
        assert np.allclose(X, interpolate_poses(t + td, to, To), atol=1e-12)


def test_inv_T_consistent_with_corr_adjoint():
    # Sanity check of the correction algebra used in the reprojection factor: X = Y K.
    rng = np.random.default_rng(9)
    Y, K = random_pose(rng), random_pose(rng, rot=0.1, trans=0.05)
    xi = rng.normal(scale=1e-7, size=6)
    from factors.lie import pose_adjoint

    lhs = inv_T(Y @ K) @ (Y @ se3_exp(xi) @ K)
    assert np.allclose(lhs, se3_exp(pose_adjoint(inv_T(K)) @ xi), atol=1e-12)


def test_lie_maps_match_scipy_including_near_pi():
    from scipy.spatial.transform import Rotation

    from factors.lie import inv_T, make_T, so3_exp, so3_log

    rng = np.random.default_rng(7)
    w = rng.normal(size=(500, 3))
    w *= rng.uniform(0.0, np.pi, (500, 1)) / np.linalg.norm(w, axis=1, keepdims=True)
    w = np.r_[w, [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [np.pi, 0.0, 0.0], [0.0, np.pi - 1e-7, 0.0]]]
    R = so3_exp(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(so3_exp(so3_log(R)), R, atol=1e-8)
    T = make_T(R[:3], rng.normal(size=(3, 3)))
    np.testing.assert_allclose(inv_T(T) @ T, np.broadcast_to(np.eye(4), (3, 4, 4)), atol=1e-12)


def test_factor_library_stands_alone():
    """factors imports gtsam and numpy only: importing every module loads nothing of plsgraph (nor scipy)."""
    import subprocess
    import sys

    code = ("import sys, factors.lie, factors.odometry, factors.planar, factors.priors, factors.reprojection; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'plsgraph', 'scipy', 'cv2'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"
