"""PnP pose, its covariance and the camera track, against simulated projections with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.core.board import load_board
from plsgraph.core.camera import davis346_default
from plsgraph.core.geometry import inv_T, make_T, rotation_error_deg, se3_exp, se3_log, so3_exp, transform_points
from plsgraph.core.tracks import Detections
from plsgraph.errors import InputError, InsufficientDataError
from plsgraph.frontend.pose import camera_track_from_detections, frame_pose, reprojection_jacobian, solve_pnp

BOARD = load_board("acircles_4x11")
CAM = davis346_default()


def pose_looking_at_board(dist: float, rotvec=(0.25, -0.3, 0.1), shift=(0.0, 0.0)) -> np.ndarray:
    """T_board_cam of a camera ``dist`` m in front of the board's centre, tilted by ``rotvec``."""
    R_cam_board = so3_exp(np.asarray(rotvec, dtype=float))
    t_cam_board = np.array([shift[0], shift[1], dist]) - R_cam_board @ BOARD.points.mean(axis=0)
    return inv_T(make_T(R_cam_board, t_cam_board))


def project(T_board_cam: np.ndarray, points: np.ndarray = BOARD.points) -> np.ndarray:
    return CAM.project(transform_points(inv_T(T_board_cam), points))


def test_recovers_pose_from_noisy_pixels():
    rng = np.random.default_rng(0)
    for dist, rv in [(0.5, (0.25, -0.3, 0.1)), (0.8, (-0.4, 0.2, 1.2)), (1.2, (0.1, 0.5, -2.5))]:
        T = pose_looking_at_board(dist, rv)
        uv = project(T) + rng.normal(0.0, 0.2, (BOARD.n_points, 2))
        est = solve_pnp(uv, BOARD.points, CAM)
        err = se3_log(inv_T(T) @ est.T_board_cam)
        # Within 4 sigma of the estimator's own covariance, and a small absolute bound.
        assert np.all(np.abs(err) < 4 * np.sqrt(np.diag(est.cov)) + 1e-9)
        # A 0.2 x 0.3 m board at up to 1.2 m pins its tilt only to a fraction of a degree.
        assert rotation_error_deg(est.T_board_cam[:3, :3], T[:3, :3]) < 2.0
        assert np.linalg.norm(est.T_board_cam[:3, 3] - T[:3, 3]) < 0.03 * dist
        assert 0.1 < est.rms_px < 0.3
        assert est.inliers.all()


def test_covariance_matches_monte_carlo():
    """The (J^T J)^-1 sigma^2 covariance in the right tangent space of T_board_cam predicts the scatter."""
    rng = np.random.default_rng(1)
    T = pose_looking_at_board(0.7, (0.3, -0.2, 0.4))
    clean = project(T)
    sigma = 0.3
    errs, covs = [], []
    for _ in range(300):
        est = solve_pnp(clean + rng.normal(0.0, sigma, clean.shape), BOARD.points, CAM, sigma_px=sigma)
        errs.append(se3_log(inv_T(T) @ est.T_board_cam))  # right perturbation: T_est = T Exp(xi)
        covs.append(est.cov)
    errs = np.array(errs)
    emp = np.cov(errs.T)
    pred = np.mean(covs, axis=0)
    ratio = np.diag(emp) / np.diag(pred)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio
    # Off-diagonal structure too: correlation coefficients agree.
    corr = lambda C: C / np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.max(np.abs(corr(emp) - corr(pred))) < 0.15
    # Mahalanobis distances of a 6-dof Gaussian average 6.
    m = np.einsum("ni,ij,nj->n", errs, np.linalg.inv(pred), errs)
    assert 5.0 < m.mean() < 7.2


def test_reprojection_jacobian_matches_finite_differences():
    T = pose_looking_at_board(0.6, (0.2, 0.3, -0.5))
    uv0, J = reprojection_jacobian(T, BOARD.points, CAM)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        up, _ = reprojection_jacobian(T @ se3_exp(d), BOARD.points, CAM)
        um, _ = reprojection_jacobian(T @ se3_exp(-d), BOARD.points, CAM)
        np.testing.assert_allclose((up - um) / (2 * h), J[:, :, k], rtol=1e-5, atol=1e-3)


def test_outlier_point_is_dropped():
    rng = np.random.default_rng(2)
    T = pose_looking_at_board(0.6)
    uv = project(T) + rng.normal(0.0, 0.1, (BOARD.n_points, 2))
    uv[7] += (9.0, -6.0)
    est = solve_pnp(uv, BOARD.points, CAM)
    assert not est.inliers[7] and est.inliers.sum() == BOARD.n_points - 1
    assert est.residuals_px[7] > 5.0
    assert rotation_error_deg(est.T_board_cam[:3, :3], T[:3, :3]) < 0.2


def test_partial_and_bad_input():
    T = pose_looking_at_board(0.6)
    uv = project(T)
    part = uv.copy()
    part[10:] = np.nan
    est = solve_pnp(part, BOARD.points, CAM)
    assert est.inliers.sum() == 10 and np.isnan(est.residuals_px[10:]).all()
    assert rotation_error_deg(est.T_board_cam[:3, :3], T[:3, :3]) < 0.05
    few = uv.copy()
    few[4:] = np.nan
    with pytest.raises(InsufficientDataError):
        solve_pnp(few, BOARD.points, CAM)
    with pytest.raises(InputError):
        solve_pnp(uv[:, :1], BOARD.points, CAM)


def test_camera_track_keeps_good_frames_and_counts_rejections():
    rng = np.random.default_rng(3)
    n = 12
    t = np.arange(n) / 30.0
    Ts = np.array([pose_looking_at_board(0.6 + 0.02 * k, (0.2, -0.3 + 0.05 * k, 0.1)) for k in range(n)])
    uv = np.array([project(T) for T in Ts]) + rng.normal(0.0, 0.15, (n, BOARD.n_points, 2))
    uv[3, 6:] = np.nan  # too few points
    uv[3, :6] = np.nan
    uv[5] = rng.uniform(0, 300, (BOARD.n_points, 2))  # garbage: no pose fits
    track = camera_track_from_detections(Detections(t, uv, BOARD.points), CAM)
    assert len(track) == n - 2
    assert 3 not in np.round(track.t * 30).astype(int) and 5 not in np.round(track.t * 30).astype(int)
    assert track.info["frames_in"] == n and track.info["frames_ok"] == n - 2
    assert sum(track.info["rejected"].values()) == 2
    keep = np.setdiff1d(np.arange(n), [3, 5])
    # The track stores the camera pose in the board frame (not OpenCV's T_cam_board): errors are
    # small in the right tangent space of the true T_board_cam, within the reported covariance.
    err = se3_log(inv_T(Ts[keep]) @ track.T_board_cam)
    sd = np.sqrt(np.diagonal(track.cov, axis1=1, axis2=2))
    assert np.all(np.abs(err) < 4.5 * sd)
    np.testing.assert_allclose(track.T_board_cam[:, :3, 3], Ts[keep, :3, 3], atol=0.02)
    assert track.cov.shape == (n - 2, 6, 6) and track.detections is not None
    np.testing.assert_array_equal(track.detections.t, track.t)


def test_poses_solved_elsewhere_give_the_same_track():
    """Poses solved frame by frame beforehand (as the streaming front end's workers do) give the track PnP on the
    whole set gives, refusals included; a list of the wrong length is refused."""
    rng = np.random.default_rng(5)
    n = 8
    t = np.arange(n) / 30.0
    Ts = np.array([pose_looking_at_board(0.7, (0.2, -0.3 + 0.05 * k, 0.1)) for k in range(n)])
    uv = np.array([project(T) for T in Ts]) + rng.normal(0.0, 0.15, (n, BOARD.n_points, 2))
    uv[2] = np.nan  # no points: refused
    uv[6] = rng.uniform(0, 300, (BOARD.n_points, 2))  # garbage
    dets = Detections(t, uv, BOARD.points)
    est = [frame_pose(u, BOARD.points, CAM) for u in uv]
    assert isinstance(est[2], str) and "points" in est[2]
    a = camera_track_from_detections(dets, CAM)
    b = camera_track_from_detections(dets, CAM, estimates=est)
    assert len(a) == len(b) == n - 2 and a.info == b.info
    for x, y in [(a.t, b.t), (a.T_board_cam, b.T_board_cam), (a.cov, b.cov), (a.rms_px, b.rms_px),
                 (a.detections.uv, b.detections.uv)]:
        np.testing.assert_array_equal(x, y)
    with pytest.raises(InputError):
        camera_track_from_detections(dets, CAM, estimates=est[:-1])
    # Any other error of a frame solved ahead is raised when the frame is used (as solving it then would).
    with pytest.raises(RuntimeError, match="solver broke"):
        camera_track_from_detections(dets, CAM, estimates=[*est[:4], RuntimeError("solver broke"), *est[5:]])


def test_camera_track_raises_when_nothing_fits():
    uv = np.full((3, BOARD.n_points, 2), np.nan)
    with pytest.raises(InsufficientDataError):
        camera_track_from_detections(Detections(np.arange(3.0), uv, BOARD.points), CAM)
