import cv2
import numpy as np
import pytest

from plsgraph.core.geometry import inv_T, rotation_error_deg
from plsgraph.errors import InputError
from plsgraph.sim.robot import MOTIONS, default_T_base_cam, simulate_robot


@pytest.fixture(scope="module", params=[(m, "ideal") for m in MOTIONS] + [("rich", "realistic")])
def rec(request):
    motion, realism = request.param
    return simulate_robot(motion, duration=30.0, seed=7, realism=realism)


def test_board_in_view_and_in_range(rec):
    # The ideal motions keep the board in view; a joystick driver lets it leave the image at times.
    assert rec.info["visible_fraction"] >= (0.95 if rec.realism.name == "ideal" else 0.6)
    lo, hi = rec.info["range_m"]
    assert 0.6 <= lo and hi <= 2.5


def test_camera_truth_closes_the_loop(rec):
    # T_world_board T_board_cam(t_cam) must equal T_world_base(t_cam + td) T_base_cam.
    lhs = rec.T_world_board @ rec.T_board_cam
    rhs = rec.truth_base.poses_at(rec.cam_t + rec.td) @ rec.T_base_cam
    assert np.allclose(lhs, rhs, atol=1e-9)
    assert np.all(rec.cam_t + rec.td >= rec.truth_base.t[0]) and np.all(rec.cam_t + rec.td <= rec.truth_base.t[-1])
    assert rec.cam_t.min() >= 0.0 and rec.wheel_t.min() >= 0.0


def test_truth_velocities_match_pose_derivatives(rec):
    tb = rec.truth_base
    T = tb.T_world_base
    dt = np.diff(tb.t)
    d = np.einsum("nji,nj->ni", T[:-1, :3, :3], T[1:, :3, 3] - T[:-1, :3, 3]) / dt[:, None]
    v_mid = 0.5 * (tb.v[1:] + tb.v[:-1])
    assert np.allclose(d[:, :2], v_mid[:, :2], atol=2e-4)
    yaw = np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
    assert np.allclose(np.diff(yaw) / dt, 0.5 * (tb.omega[1:, 2] + tb.omega[:-1, 2]), atol=2e-4)
    assert np.allclose(tb.v[:, 1:], 0.0) and np.allclose(tb.omega[:, :2], 0.0)
    # The base is on the floor: z = 0 on a flat one, a few millimetres up and down on an undulating one.
    assert np.abs(T[:, 2, 3]).max() < (1e-12 if rec.realism.scene.floor_slope_deg == 0 else 0.02)


def test_motion_profiles_have_their_character():
    straight = simulate_robot("straight", duration=10.0, seed=1, realism="ideal")
    spin = simulate_robot("spin", duration=10.0, seed=1, realism="ideal")
    assert np.allclose(straight.truth_base.omega, 0.0) and np.ptp(straight.truth_base.v[:, 0]) > 0.3
    assert np.allclose(spin.truth_base.v, 0.0) and np.ptp(spin.truth_base.omega[:, 2]) > 0.3
    assert np.allclose(spin.truth_base.T_world_base[:, :3, 3], 0.0)
    rich = simulate_robot("rich", duration=10.0, seed=1, realism="ideal")
    assert np.any(rich.truth_base.v[:, 0] > 0.1) and np.any(rich.truth_base.v[:, 0] < -0.1)
    assert np.ptp(rich.truth_base.omega[:, 2]) > 0.3


def test_wheel_angles_are_differential_drive_without_slip():
    rec = simulate_robot("rich", duration=10.0, seed=3, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    r, b = rec.wheel_radius, rec.track_width
    s = r * (rec.wheel_right + rec.wheel_left) / 2
    yaw = r * (rec.wheel_right - rec.wheel_left) / b
    T = rec.truth_base.poses_at(rec.wheel_t)
    assert np.allclose(yaw, np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0])), atol=1e-9)
    v = np.gradient(s, rec.wheel_t)
    v_true = np.interp(rec.wheel_t, rec.truth_base.t, rec.truth_base.v[:, 0])
    assert np.allclose(v[1:-1], v_true[1:-1], atol=5e-3)


def test_quantization_and_slip_are_bounded():
    clean = simulate_robot("rich", duration=10.0, seed=3, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    q = simulate_robot("rich", duration=10.0, seed=3, slip=0.0, encoder_ticks_per_rev=1024, realism="ideal")
    step = 2 * np.pi / 1024
    assert np.max(np.abs(q.wheel_left - clean.wheel_left)) <= step / 2 + 1e-12
    assert np.allclose(np.round(q.wheel_left / step) * step, q.wheel_left)
    slipping = simulate_robot("rich", duration=10.0, seed=3, slip=0.01, encoder_ticks_per_rev=0, realism="ideal")
    rel = np.abs(np.diff(slipping.wheel_left) - np.diff(clean.wheel_left)) / (np.abs(np.diff(clean.wheel_left)) + 1e-9)
    assert 0.0 < np.median(rel) < 0.05


def test_detections_project_and_pnp_recovers_pose():
    rec = simulate_robot("rich", duration=5.0, seed=4, realism="ideal")
    det = rec.detections(noise_px=0.0)
    assert det.uv.shape == (rec.cam_t.size, rec.board.n_points, 2)
    k = det.t.size // 2
    ok, rvec, tvec = cv2.solvePnP(det.board_points, det.uv[k], rec.camera.K, rec.camera.dist)
    assert ok
    R = cv2.Rodrigues(rvec)[0]
    T_cam_board = inv_T(rec.T_board_cam[k])
    assert rotation_error_deg(R, T_cam_board[:3, :3]) < 1e-3
    assert np.allclose(tvec.ravel(), T_cam_board[:3, 3], atol=1e-5)
    noisy = rec.detections(noise_px=0.5, seed=9)
    resid = noisy.uv - det.uv
    assert 0.4 < np.nanstd(resid) < 0.6


def test_camera_track_noise_level():
    rec = simulate_robot("rich", duration=10.0, seed=5, realism="ideal")
    track = rec.camera_track(noise_rot_deg=0.2, noise_trans_m=0.003, seed=1)
    assert len(track) == int(round(rec.info["visible_fraction"] * rec.cam_t.size))
    idx = np.searchsorted(rec.cam_t, track.t)
    err = rotation_error_deg(track.T_board_cam[:, :3, :3], rec.T_board_cam[idx, :3, :3])
    # The geodesic angle of isotropic noise with 0.2 deg per axis has an RMS of 0.2 sqrt(3) deg.
    assert np.sqrt(np.mean(err**2)) == pytest.approx(0.2 * np.sqrt(3), rel=0.15)
    assert track.cov.shape == (len(track), 6, 6)


def test_default_mount_looks_forward_and_down():
    T = default_T_base_cam()
    z_cam_in_base = T[:3, 2]
    assert z_cam_in_base[0] > 0.95 and z_cam_in_base[2] < -0.05  # forward, pitched down
    assert np.allclose(T[:3, 3], [0.15, 0.02, 0.25])


def test_bad_arguments_raise():
    with pytest.raises(InputError):
        simulate_robot("zigzag")
    with pytest.raises(InputError):
        simulate_robot(duration=0.5)
    with pytest.raises(InputError):
        simulate_robot(T_base_cam=np.eye(3))


@pytest.mark.parametrize("realism", ["ideal", "realistic"])
def test_events_follow_the_board_in_the_camera_clock(realism):
    rec = simulate_robot("rich", duration=1.2, seed=2, realism=realism)
    ev = rec.events(seed=1)
    t = ev.t * 1e-9
    assert len(ev) > 1000 and t.min() >= rec.cam_t[0] - 1e-6 and t.max() <= rec.cam_t[-1] + 1e-6
    if realism == "realistic":
        # A joystick driver starts from rest: mostly sensor noise so far, stamped in whole microseconds.
        assert np.all(ev.t % 1000 == 0)
        counts = np.bincount(ev.y.astype(np.int64) * rec.camera.width + ev.x)
        assert np.sum(counts > 20) >= 5  # hot pixels
        return
    # Around a mid stamp the events crowd on the projected board (the textured wall around it fires less).
    tm = rec.cam_t[len(rec.cam_t) // 2]
    sel = np.abs(t - tm) < 0.01
    T_cam_board = inv_T(rec.camera_poses_at(np.array([tm]))[0])
    uv = rec.camera.project(rec.board.points @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])
    lo, hi = uv.min(axis=0) - 8, uv.max(axis=0) + 8
    x, y = ev.x[sel], ev.y[sel]
    inside = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
    area = np.prod(hi - lo) / (rec.camera.width * rec.camera.height)
    assert inside.mean() / area > 3.0
    assert np.allclose(rec.camera_poses_at(rec.cam_t), rec.T_board_cam, atol=1e-12)
