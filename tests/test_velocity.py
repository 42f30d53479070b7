"""Camera velocities from pose tracks with known twist."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.calib.velocity import camera_velocities, split_at_gaps
from plsgraph.core.geometry import make_T, se3_exp, so3_exp
from plsgraph.core.tracks import CameraTrack
from plsgraph.errors import InsufficientDataError

T0 = make_T(so3_exp(np.array([0.3, -1.2, 0.5])), np.array([0.1, -0.2, -0.8]))


def constant_twist_track(t: np.ndarray, xi: np.ndarray) -> CameraTrack:
    """T_board_cam(t) = T0 Exp(t xi): the body (camera-frame) velocity is xi for all t."""
    return CameraTrack(t, T0 @ se3_exp(t[:, None] * xi[None, :]))


def test_constant_twist_recovered():
    xi = np.array([0.4, -0.9, 1.3, 0.25, -0.1, 0.4])  # fast turn with a helical translation
    t = np.arange(90) / 30.0
    tv, w, v = camera_velocities(constant_twist_track(t, xi), window_s=0.2, polyorder=3)
    np.testing.assert_array_equal(tv, t)
    np.testing.assert_allclose(w, np.broadcast_to(xi[:3], w.shape), atol=1e-6)
    np.testing.assert_allclose(v, np.broadcast_to(xi[3:], v.shape), atol=2e-4)


def test_irregular_sampling_and_noise():
    rng = np.random.default_rng(4)
    xi = np.array([0.0, 0.0, 0.8, 0.3, 0.0, 0.05])
    t = np.cumsum(rng.uniform(0.025, 0.04, 150))
    track = constant_twist_track(t, xi)
    noisy = track.T_board_cam @ se3_exp(rng.normal(0, [1e-3] * 3 + [5e-4] * 3, (t.size, 6)))
    tv, w, v = camera_velocities(CameraTrack(t, noisy), window_s=0.4)
    # Noise 1 mrad over a 0.4 s window: slope error of order 1e-3 / 0.2 / sqrt(13) ~ 3e-3 rad/s.
    assert np.median(np.linalg.norm(w - xi[:3], axis=1)) < 0.02
    assert np.median(np.linalg.norm(v - xi[3:], axis=1)) < 0.01


def test_time_varying_twist():
    """Angular velocity ramps linearly in time about a fixed axis: the estimate follows it."""
    t = np.arange(120) / 30.0
    axis = np.array([0.2, 0.9, -0.4]) / np.linalg.norm([0.2, 0.9, -0.4])
    angle = 0.5 * t + 0.1 * t**2  # rate 0.5 + 0.2 t
    T = T0 @ make_T(so3_exp(angle[:, None] * axis), np.stack([np.sin(t), 0.1 * t, 0.0 * t], axis=1))
    tv, w, v = camera_velocities(CameraTrack(t, T), window_s=0.2, polyorder=2)
    np.testing.assert_allclose(w, (0.5 + 0.2 * t)[:, None] * axis, atol=1e-6)
    # v_cam = R^T dp/dt, with dp/dt the board-frame derivative of the analytic position.
    R = T[:, :3, :3]
    p_dot = np.stack([np.cos(t), np.full_like(t, 0.1), np.zeros_like(t)], axis=1) @ T0[:3, :3].T
    np.testing.assert_allclose(v, np.einsum("nji,nj->ni", R, p_dot), atol=5e-3)


def test_gaps_are_not_differentiated_across():
    xi1 = np.array([0.0, 0.0, 1.0, 0.2, 0.0, 0.0])
    t = np.arange(100) / 30.0
    T = T0 @ se3_exp(t[:, None] * xi1[None, :])
    # Frames 40..59 missing, and the motion after the gap jumps (as if the board was lost and found again).
    keep = np.r_[0:40, 60:100]
    T = T[keep]
    T[40:] = T[40:] @ se3_exp(np.array([0.3, 0, 0, 0.1, 0, 0]))
    # A short piece of 3 frames after another gap is too short for a window and is dropped.
    t_k = t[keep].copy()
    t_k[-3:] += 1.0
    tv, w, v = camera_velocities(CameraTrack(t_k, T), window_s=0.2)
    assert tv.size == 77
    assert not np.isin(t_k[-3:], tv).any()
    # Frames either side of the gap are still exact: no window mixed poses across it.
    np.testing.assert_allclose(w[:40], np.broadcast_to(xi1[:3], (40, 3)), atol=1e-6)
    assert split_at_gaps(t_k, 0.05) == [(0, 40), (40, 77), (77, 80)]


def test_too_short_raises():
    t = np.arange(4) / 30.0
    with pytest.raises(InsufficientDataError):
        camera_velocities(constant_twist_track(t, np.ones(6) * 0.1), window_s=0.5)
