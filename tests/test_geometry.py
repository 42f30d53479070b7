import numpy as np
import pytest

from plsgraph.core.board import Board, load_board
from plsgraph.core.camera import CameraModel, davis346_default
from plsgraph.core.geometry import (
    interpolate_poses,
    inv_T,
    is_rotation,
    make_T,
    rotation_error_deg,
    se3_exp,
    se3_log,
    so3_exp,
)
from plsgraph.errors import InputError


def test_se3_exp_log_round_trip():
    rng = np.random.default_rng(0)
    xi = rng.normal(size=(50, 6))
    xi[:3] *= 1e-10  # include tiny rotations
    assert np.allclose(se3_log(se3_exp(xi)), xi, atol=1e-9)


def test_inverse_and_rotation_error():
    rng = np.random.default_rng(1)
    T = se3_exp(rng.normal(size=(10, 6)))
    assert np.allclose(T @ inv_T(T), np.eye(4), atol=1e-12)
    R = so3_exp(np.array([0.0, 0.0, np.radians(30.0)]))
    assert rotation_error_deg(R, np.eye(3)) == pytest.approx(30.0)
    assert is_rotation(R) and not is_rotation(2 * R)


def test_interpolate_poses_midpoint_and_range():
    T0 = make_T(np.eye(3), [0, 0, 0])
    T1 = make_T(so3_exp([0, 0, 0.4]), [2.0, 0, 0])
    Tm = interpolate_poses([0.5], np.array([0.0, 1.0]), np.stack([T0, T1]))[0]
    assert np.allclose(Tm[:3, 3], [1.0, 0, 0])
    assert rotation_error_deg(Tm[:3, :3], so3_exp([0, 0, 0.2])) < 1e-9
    with pytest.raises(ValueError):
        interpolate_poses([1.5], np.array([0.0, 1.0]), np.stack([T0, T1]))


def test_projection_jacobian_matches_numeric():
    cam = davis346_default()
    rng = np.random.default_rng(2)
    p = np.column_stack([rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.2, 0.2, 20), rng.uniform(0.6, 2.0, 20)])
    uv, J = cam.project(p, with_jacobian=True)
    h = 1e-7
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h
        num = (cam.project(p + dp) - cam.project(p - dp)) / (2 * h)
        assert np.allclose(J[:, :, k], num, atol=1e-4)
    assert np.allclose(cam.undistort_pixels(uv), p[:, :2] / p[:, 2:], atol=1e-8)


def test_camera_rejects_bad_intrinsics():
    with pytest.raises(InputError):
        CameraModel(346, 260, np.diag([-1.0, 1.0, 1.0]), np.zeros(5))


def test_board_layout_matches_opencv_convention():
    b = load_board("acircles_4x11")
    pts = b.points
    assert pts.shape == (44, 3)
    assert np.allclose(pts[1], [2 * 0.025, 0, 0])  # row 0, col 1
    assert np.allclose(pts[4], [0.025, 0.025, 0])  # row 1, col 0 is shifted by one square
    with pytest.raises(InputError):
        Board(pattern="asymmetric_circles", cols=4, rows=11, square_size=0.01, circle_diameter=0.03)
    with pytest.raises(InputError):
        load_board("no_such_board")


def test_a_tracks_interpolator_is_made_once_gives_the_same_poses_and_is_not_pickled():
    import pickle

    from plsgraph.core.geometry import interpolate_poses
    from plsgraph.core.tracks import BaseTrack, CameraTrack

    rng = np.random.default_rng(3)
    n = 50
    t = np.cumsum(rng.uniform(0.01, 0.03, n))
    R = np.stack([so3_exp(rng.normal(scale=0.5, size=3)) for _ in range(n)])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = rng.normal(size=(n, 3))
    base = BaseTrack(t, T, np.zeros((n, 3)), np.zeros((n, 3)))
    cam = CameraTrack(t, T)
    tq = np.linspace(t[0], t[-1], 77)
    for track in (base, cam):
        first = track.poses_at(tq)
        np.testing.assert_array_equal(first, interpolate_poses(tq, t, T))
        made = track.__dict__["_pose_interpolator"]
        np.testing.assert_array_equal(track.poses_at(tq[::-1]), first[::-1])
        assert track.__dict__["_pose_interpolator"] is made  # made once
        again = pickle.loads(pickle.dumps(track))
        assert "_pose_interpolator" not in again.__dict__
        np.testing.assert_array_equal(again.poses_at(tq), first)
        with pytest.raises(ValueError, match="outside"):
            track.poses_at(np.array([t[-1] + 1.0]))
