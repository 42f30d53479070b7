import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from plsgraph.core.geometry import rotation_error_deg, yaw_of
from plsgraph.errors import InputError, InsufficientDataError
from plsgraph.odometry.wheels import (
    base_track_from_odometry,
    base_track_from_wheels,
    diff_drive,
    in_gap,
    integrate_planar,
    resample,
    rescale_planar_track,
    velocity_at,
)
from plsgraph.sim.robot import simulate_robot

R, B = 0.098, 0.37


def wheels_for(t, v, w):
    """Wheel angles for constant forward speed v and turn rate w."""
    return (v - w * B / 2) / R * t, (v + w * B / 2) / R * t


def test_constant_twist_gives_exact_circle():
    t = np.linspace(0.0, 7.0, 36)  # coarse steps: the arc integration must still be exact
    v, w = 0.4, 0.6
    left, right = wheels_for(t, v, w)
    track = base_track_from_wheels(t, left, right, R, B)
    p = track.T_world_base[:, :3, 3]
    assert np.allclose(p[:, 0], v / w * np.sin(w * t), atol=1e-12)
    assert np.allclose(p[:, 1], v / w * (1 - np.cos(w * t)), atol=1e-12)
    assert np.allclose(np.unwrap(yaw_of(track.T_world_base[:, :3, :3])), w * t)
    assert np.allclose(track.v[:, 0], v) and np.allclose(track.omega[:, 2], w)
    assert track.info["warnings"] == []


def test_straight_line_and_spin_in_place():
    t = np.linspace(0.0, 2.0, 11)
    track = base_track_from_wheels(t, *wheels_for(t, -0.5, 0.0), R, B)
    assert np.allclose(track.T_world_base[:, 0, 3], -0.5 * t) and np.allclose(track.T_world_base[:, 1, 3], 0.0)
    spin = base_track_from_wheels(t, *wheels_for(t, 0.0, 1.0), R, B)
    assert np.allclose(spin.T_world_base[:, :3, 3], 0.0) and np.allclose(spin.omega[:, 2], 1.0)


def test_diff_drive_equations():
    v, w = diff_drive(np.array([1.0]), np.array([3.0]), R, B)
    assert v[0] == pytest.approx(R * 2.0) and w[0] == pytest.approx(R * 2.0 / B)


def test_integration_matches_simulated_truth():
    rec = simulate_robot("rich", duration=20.0, seed=2, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    track = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius, rec.track_width)
    T_true = rec.truth_base.poses_at(rec.wheel_t)
    assert np.max(np.linalg.norm(track.T_world_base[:, :3, 3] - T_true[:, :3, 3], axis=1)) < 2e-3
    assert np.max(rotation_error_deg(track.T_world_base[:, :3, :3], T_true[:, :3, :3])) < 1e-5
    v_true, w_true = velocity_at(rec.truth_base, rec.wheel_t)
    assert np.max(np.abs(track.v[:, 0] - v_true[:, 0])) < 5e-3
    assert np.max(np.abs(track.omega[:, 2] - w_true[:, 2])) < 5e-3


def test_velocity_input_matches_position_input():
    rec = simulate_robot("rich", duration=10.0, seed=1, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    t = rec.wheel_t
    rates = [np.gradient(a, t) for a in (rec.wheel_left, rec.wheel_right)]
    by_rate = base_track_from_wheels(t, *rates, R, B, kind="velocity")
    by_pos = base_track_from_wheels(t, rec.wheel_left, rec.wheel_right, R, B)
    assert np.max(np.abs(by_rate.T_world_base[:, :3, 3] - by_pos.T_world_base[:, :3, 3])) < 5e-3


def test_gyro_heading_beats_slipping_wheels():
    rec = simulate_robot("rich", duration=20.0, seed=4, slip=0.03, realism="ideal")
    wheels = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, R, B)
    gyro = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, R, B, gyro=rec.gyro(noise_rad_s=0.002))
    T_true = rec.truth_base.poses_at(rec.wheel_t)
    err_w = rotation_error_deg(wheels.T_world_base[:, :3, :3], T_true[:, :3, :3])
    err_g = rotation_error_deg(gyro.T_world_base[:, :3, :3], T_true[:, :3, :3])
    assert err_g.max() < 0.2 < err_w.max()
    assert "gyro" in gyro.info["source"]


def test_bad_streams_are_rejected():
    t = np.array([0.0, 0.1, 0.05, 0.2])
    with pytest.raises(InputError, match="sorted"):
        base_track_from_wheels(t, np.zeros(4), np.zeros(4))
    with pytest.raises(InputError, match="duplicated"):
        base_track_from_wheels(np.array([0.0, 0.1, 0.1]), np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="NaN"):
        base_track_from_wheels(np.arange(3.0), np.array([0, np.nan, 0]), np.zeros(3))
    with pytest.raises(InsufficientDataError):
        base_track_from_wheels(np.zeros(1), np.zeros(1), np.zeros(1))
    with pytest.raises(InputError):
        base_track_from_wheels(np.arange(3.0), np.zeros(3), np.zeros(3), kind="ticks")


def test_gaps_and_jumps_are_reported():
    t = np.r_[np.arange(0, 5, 0.02), np.arange(6.0, 8.0, 0.02)]  # a 1 s gap
    left, right = wheels_for(t, 0.3, 0.2)
    right = right.copy()
    right[300:] += 50.0  # encoder reset / jump
    track = base_track_from_wheels(t, left, right, R, B)
    assert len(track.info["gaps"]) == 1 and track.info["gaps"][0, 1] - track.info["gaps"][0, 0] > 0.9
    assert track.info["jumps"].size == 1 and len(track.info["warnings"]) == 2
    # The jump adds no motion: the heading keeps following the true turn rate except over the jump step.
    assert float(yaw_of(track.T_world_base[-1, :3, :3])) == pytest.approx(0.2 * (t[-1] - 0.02), abs=1e-9)
    mask = in_gap(track, np.array([2.0, 5.5, t[300], 7.5]))
    assert mask.tolist() == [False, True, True, False]


def test_wheel_messages_stamped_in_bursts_keep_their_motion():
    # Stamps given on arrival: a late message pulls the next one to just after it (1 us apart). The wheel angles are
    # cumulative, so merging the pair loses nothing; taken as a 1 us step of 20 ms of driving it was a "reset" that
    # dropped that motion, and heading and distance came out short.
    t_true = np.arange(0, 10, 0.02)
    left, right = wheels_for(t_true, 0.4, 0.3)
    stamps = t_true.copy()
    late = np.arange(20, t_true.size - 1, 37)
    stamps[late] += 0.0199  # each of these is stamped just before the next message ...
    stamps[late + 1] = stamps[late] + 1e-6  # ... which is stamped right after it
    track = base_track_from_wheels(stamps, left, right, R, B)
    clean = base_track_from_wheels(t_true, left, right, R, B)
    assert track.info["jumps"].size == 0
    assert any(f"{late.size} wheel message(s) stamped within" in w for w in track.info["warnings"])
    assert float(yaw_of(track.T_world_base[-1, :3, :3])) == pytest.approx(float(yaw_of(clean.T_world_base[-1, :3, :3])),
                                                                           abs=1e-9)
    assert np.allclose(track.T_world_base[-1, :2, 3], clean.T_world_base[-1, :2, 3], atol=2e-3)
    assert track.t.size == t_true.size - late.size and np.all(np.abs(track.v[:, 0]) < 1.0)
    # Every message in a burst of three (stamped on arrival of the last): most steps are bursts, and the typical
    # step is still the messages' interval, not a burst's microsecond.
    n3 = t_true.size - t_true.size % 3
    burst = np.repeat(t_true[2:n3:3], 3) + 1e-6 * np.tile(np.arange(3), n3 // 3)
    tr3 = base_track_from_wheels(burst, left[:n3], right[:n3], R, B)
    last = slice(2, n3, 3)  # each burst's last message stays; the others merge into it
    clean3 = base_track_from_wheels(t_true[last], left[last], right[last], R, B)
    assert tr3.info["jumps"].size == 0 and tr3.t.size == n3 // 3
    assert np.allclose(tr3.T_world_base[-1, :2, 3], clean3.T_world_base[-1, :2, 3], atol=1e-6)
    # A reset right after a bunched stamp is still a jump, not merged motion.
    right2 = right.copy()
    right2[late[0] + 1:] += 50.0
    assert base_track_from_wheels(stamps, left, right2, R, B).info["jumps"].size == 1


def test_odometry_messages_round_trip_and_jump():
    rec = simulate_robot("rich", duration=10.0, seed=5, realism="ideal")
    t = rec.wheel_t
    T = rec.truth_base.poses_at(t)
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    v, w = velocity_at(rec.truth_base, t)
    track = base_track_from_odometry(t, T[:, :3, 3], q, v, w)
    assert np.allclose(track.T_world_base, T) and track.info["warnings"] == []
    derived = base_track_from_odometry(t, T[:, :3, 3], q)  # no twist: differentiated poses
    assert np.max(np.abs(derived.v[:, 0] - v[:, 0])) < 5e-3
    assert np.max(np.abs(derived.omega[:, 2] - w[:, 2])) < 5e-3
    p = T[:, :3, 3].copy()
    p[200:, 0] += 0.5
    jumped = base_track_from_odometry(t, p, q, v, w)
    assert jumped.info["jumps"].size == 1 and np.isclose(jumped.info["jumps"][0], t[200])
    with pytest.raises(InputError, match="quaternion"):
        base_track_from_odometry(t, T[:, :3, 3], 2 * q)


def test_resample_and_velocity_at():
    t = np.linspace(0.0, 4.0, 81)
    track = base_track_from_wheels(t, *wheels_for(t, 0.4, 0.5), R, B)
    tq = np.linspace(0.1, 3.9, 17)
    res = resample(track, tq)
    assert np.allclose(res.T_world_base[:, 0, 3], 0.4 / 0.5 * np.sin(0.5 * tq), atol=2e-4)
    assert np.allclose(res.v[:, 0], 0.4) and np.allclose(res.omega[:, 2], 0.5)
    with pytest.raises(InputError):
        velocity_at(track, np.array([5.0]))
    with pytest.raises(InputError):
        resample(track, np.array([-1.0]))


def test_integrate_planar_matches_small_step_limit():
    ds = np.full(1000, 0.001)
    dth = np.full(1000, 0.002)
    x, y, th = integrate_planar(ds, dth)
    assert th[-1] == pytest.approx(2.0)
    assert x[-1] == pytest.approx(0.5 * np.sin(2.0), abs=1e-12) and y[-1] == pytest.approx(0.5 * (1 - np.cos(2.0)))


@pytest.fixture(scope="module")
def jackal_odometry():
    """Real Clearpath Jackal odometry (50 Hz nav_msgs/Odometry) from /work/shared/data/real."""
    from realdata import SHARED_REAL_DIR

    path = SHARED_REAL_DIR / "jackal_odometry.bag"
    if not path.is_file():
        pytest.skip(f"{path} not available")
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    rows = []
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.msgtype == "nav_msgs/msg/Odometry"]
        for c, _, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, c.msgtype)
            p, q = m.pose.pose.position, m.pose.pose.orientation
            lin, ang = m.twist.twist.linear, m.twist.twist.angular
            stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            rows.append([stamp, p.x, p.y, p.z, q.x, q.y, q.z, q.w, lin.x, lin.y, lin.z, ang.x, ang.y, ang.z])
    return np.array(rows)


def test_real_jackal_odometry_is_consistent(jackal_odometry):
    o = jackal_odometry
    track = base_track_from_odometry(o[:, 0], o[:, 1:4], o[:, 4:8], o[:, 8:11], o[:, 11:14])
    assert track.info["warnings"] == [] and track.info["jumps"].size == 0 and len(track) > 3000
    # The published poses are the integral of the published twist: our exact-arc integration reproduces them
    # to within 1 % of the distance driven.
    dt = np.diff(o[:, 0])
    v, w = o[:, 8], o[:, 13]
    yaw0 = float(yaw_of(track.T_world_base[0, :3, :3]))
    x, y, _ = integrate_planar(0.5 * (v[1:] + v[:-1]) * dt, 0.5 * (w[1:] + w[:-1]) * dt, o[0, 1], o[0, 2], yaw0)
    driven = np.sum(np.linalg.norm(np.diff(o[:, 1:3], axis=0), axis=1))
    assert driven > 10.0
    assert np.max(np.hypot(x - o[:, 1], y - o[:, 2])) < 0.01 * driven
    # Velocities differentiated from the poses alone agree with the twist.
    derived = base_track_from_odometry(o[:, 0], o[:, 1:4], o[:, 4:8])
    assert np.median(np.abs(derived.v[:, 0] - v)) < 0.01
    assert np.median(np.abs(derived.omega[:, 2] - w)) < 0.02


def test_rescale_planar_track_corrects_track_width_and_radius():
    rec = simulate_robot("rich", duration=10.0, seed=9, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    t, left, right = rec.wheel_t, rec.wheel_left, rec.wheel_right
    true = base_track_from_wheels(t, left, right, 0.10, 0.42)
    nominal = base_track_from_wheels(t, left, right, 0.098, 0.37)
    # v scales with r, omega with r / b.
    fixed = rescale_planar_track(nominal, 0.10 / 0.098, (0.10 / 0.098) * (0.37 / 0.42))
    assert np.allclose(fixed.T_world_base, true.T_world_base, atol=1e-9)
    assert np.allclose(fixed.v, true.v) and np.allclose(fixed.omega, true.omega)
    same = rescale_planar_track(nominal)
    assert np.allclose(same.T_world_base, nominal.T_world_base, atol=1e-12)
    with pytest.raises(InputError):
        rescale_planar_track(nominal, 0.0, 1.0)


def test_a_wheel_order_hypothesis_does_not_log_its_jumps(caplog):
    # Under "one wheel reversed" driving becomes turning, which can pass for jumps: those are not the recording's, and
    # only the track that is used says its warnings.
    from plsgraph.odometry.wheel_order import WheelSignals

    t = np.arange(0, 4, 0.02)
    left, right = wheels_for(t, 0.4, 0.0)
    stamps = t.copy()
    stamps[50] = stamps[51] - 0.006  # a step of 6 ms: 4x the median speed as driving, far more as turning
    sig = WheelSignals(stamps, left, right, "position", R, B)
    with caplog.at_level("WARNING"):
        rev = sig.base_track("left_reversed")
    assert rev.info["jumps"].size and not caplog.records
    with caplog.at_level("WARNING"):
        base_track_from_wheels(stamps, -left, right, R, B)
    assert any("treated as resets" in r.getMessage() for r in caplog.records)
