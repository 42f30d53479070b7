"""Camera velocities (the time offset's and closed form's input) from pose tracks with known twist."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.calib.time_offset import camera_velocities_on_grid
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
    cv = camera_velocities_on_grid(constant_twist_track(t, xi), window_s=0.2, polyorder=3, outlier_sigma=None)
    np.testing.assert_allclose(cv.t, t[: cv.t.size])
    ok = cv.valid
    assert ok.sum() > 80
    np.testing.assert_allclose(cv.omega[ok], np.broadcast_to(xi[:3], cv.omega[ok].shape), atol=1e-6)
    np.testing.assert_allclose(cv.v[ok], np.broadcast_to(xi[3:], cv.v[ok].shape), atol=2e-3)


def test_irregular_sampling_and_noise():
    rng = np.random.default_rng(4)
    xi = np.array([0.0, 0.0, 0.8, 0.3, 0.0, 0.05])
    t = np.cumsum(rng.uniform(0.025, 0.04, 150))
    track = constant_twist_track(t, xi)
    noisy = track.T_board_cam @ se3_exp(rng.normal(0, [1e-3] * 3 + [5e-4] * 3, (t.size, 6)))
    cv = camera_velocities_on_grid(CameraTrack(t, noisy), window_s=0.4)
    ok = cv.valid
    assert np.median(np.linalg.norm(cv.omega[ok] - xi[:3], axis=1)) < 0.02
    assert np.median(np.linalg.norm(cv.v[ok] - xi[3:], axis=1)) < 0.01


def test_time_varying_twist():
    """Angular velocity ramps linearly in time about a fixed axis: the estimate follows it."""
    t = np.arange(120) / 30.0
    axis = np.array([0.2, 0.9, -0.4]) / np.linalg.norm([0.2, 0.9, -0.4])
    angle = 0.5 * t + 0.1 * t**2  # rate 0.5 + 0.2 t
    T = T0 @ make_T(so3_exp(angle[:, None] * axis), np.stack([np.sin(t), 0.1 * t, 0.0 * t], axis=1))
    cv = camera_velocities_on_grid(CameraTrack(t, T), window_s=0.2, polyorder=2, outlier_sigma=None)
    ok = cv.valid
    np.testing.assert_allclose(cv.omega[ok], (0.5 + 0.2 * cv.t[ok])[:, None] * axis, atol=1e-6)
    R = T[: cv.t.size, :3, :3][ok]
    tt = cv.t[ok]
    p_dot = np.stack([np.cos(tt), np.full_like(tt, 0.1), np.zeros_like(tt)], axis=1) @ T0[:3, :3].T
    np.testing.assert_allclose(cv.v[ok], np.einsum("nji,nj->ni", R, p_dot), atol=5e-3)


def test_holes_are_not_differentiated_across():
    xi1 = np.array([0.0, 0.0, 1.0, 0.2, 0.0, 0.0])
    t = np.arange(100) / 30.0
    T = T0 @ se3_exp(t[:, None] * xi1[None, :])
    keep = np.r_[0:40, 60:100]  # frames 40..59 missing, and the motion after the hole jumps
    T = T[keep]
    T[40:] = T[40:] @ se3_exp(np.array([0.3, 0, 0, 0.1, 0, 0]))
    cv = camera_velocities_on_grid(CameraTrack(t[keep], T), window_s=0.2, outlier_sigma=None)
    assert cv.info["holes"] == 1
    inside = (cv.t > t[39] - 0.1) & (cv.t < t[60] + 0.1)
    assert not cv.valid[inside].any()
    # Samples away from the hole are exact: no window mixed poses across it.
    before = cv.valid & (cv.t < t[39])
    np.testing.assert_allclose(cv.omega[before], np.broadcast_to(xi1[:3], (before.sum(), 3)), atol=1e-6)


def test_too_short_raises():
    t = np.arange(4) / 30.0
    with pytest.raises(InsufficientDataError):
        camera_velocities_on_grid(constant_twist_track(t, np.ones(6) * 0.1), window_s=0.5)


@pytest.mark.parametrize("n,window,order,deriv,delta", [
    (50, 5, 2, 0, 1.0), (50, 5, 2, 1, 0.03), (300, 31, 2, 1, 1 / 30), (40, 7, 3, 2, 0.5), (7, 7, 2, 1, 1.0)])
def test_savitzky_golay_matches_scipy(n, window, order, deriv, delta):
    """The project's own Savitzky-Golay filter (scipy.signal costs most of a second to import) gives scipy's
    default filter, edges included, along either axis."""
    from scipy.signal import savgol_filter as scipy_savgol

    from plsgraph.calib.time_offset import savgol_filter

    x = np.cumsum(np.random.default_rng(n).standard_normal((n, 3)), axis=0)
    want = scipy_savgol(x, window, order, deriv=deriv, delta=delta, axis=0)
    np.testing.assert_allclose(savgol_filter(x, window, order, deriv=deriv, delta=delta), want,
                               atol=1e-10 * np.abs(want).max())
    np.testing.assert_allclose(savgol_filter(x.T, window, order, deriv=deriv, delta=delta, axis=1), want.T,
                               atol=1e-10 * np.abs(want).max())
    with pytest.raises(ValueError):
        savgol_filter(x, window + 1, order)


def test_velocities_do_not_import_scipy_signal():
    import subprocess
    import sys

    code = ("import sys, numpy as np; from plsgraph.calib.time_offset import body_velocities; "
            "T = np.broadcast_to(np.eye(4), (40, 4, 4)).copy(); T[:, 0, 3] = np.arange(40) * 0.1; "
            "w, v = body_velocities(T, 10.0, 3); assert np.allclose(v[:, 0], 1.0); "
            "print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"
