"""Wheel joint states as drivers publish them: wrapped angles, four wheels, one wheel per message."""

import numpy as np

from plsgraph.io.recording import JointStates
from plsgraph.odometry.joints import wheel_track_from_joints
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.sim.robot import simulate_robot


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _reference_and_run():
    sim = simulate_robot("rich", duration=6.0, seed=4, slip=0.0, encoder_ticks_per_rev=0, realism="ideal")
    ref = base_track_from_wheels(sim.wheel_t, sim.wheel_left, sim.wheel_right, sim.wheel_radius, sim.track_width)
    return sim, ref, (sim.wheel_radius, sim.track_width)


def test_four_wrapped_wheels_give_the_same_track():
    sim, ref, run = _reference_and_run()
    L, R = sim.wheel_left, sim.wheel_right
    pos = _wrap(np.stack([L, R, L + 1.0, R + 2.0], axis=1))  # rear wheels offset, all reported in [-pi, pi)
    names = ("front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel")
    js = JointStates((sim.wheel_t * 1e9).astype(np.int64), names, pos, np.full_like(pos, np.nan))
    track, _ = wheel_track_from_joints(js, *run)
    assert np.abs(track.T_world_base[:, :3, 3] - ref.T_world_base[:, :3, 3]).max() < 1e-6
    assert len(track.info.get("jumps", [])) == 0


def test_wheels_published_in_separate_messages_are_merged():
    sim, ref, run = _reference_and_run()
    t = sim.wheel_t
    n = t.size
    # Left at the odometry stamps, right 1 ms later, each in its own message.
    tt = np.r_[t, t + 1e-3]
    order = np.argsort(tt)
    pos = np.full((2 * n, 2), np.nan)
    pos[:n, 0] = sim.wheel_left
    right_later = np.interp(t + 1e-3, t, sim.wheel_right)
    pos[n:, 1] = right_later
    js = JointStates((tt[order] * 1e9).astype(np.int64), ("left_wheel", "right_wheel"), pos[order],
                     np.full((2 * n, 2), np.nan))
    track, _ = wheel_track_from_joints(js, *run)
    end = ref.T_world_base[-1, :3, 3]
    got = track.poses_at([ref.t[-1] - 0.01])[0, :3, 3]
    assert np.linalg.norm(got - ref.poses_at([ref.t[-1] - 0.01])[0, :3, 3]) < 1e-3
    assert np.linalg.norm(end) > 0.1  # the robot did move


def test_a_stretch_of_messages_without_wheel_values_is_a_gap_not_a_straight_line():
    """Before: 2.5 s of NaN wheel angles while the robot drove were filled by a straight line between the last angles
    before and the first after, with no warning; the same stretch of missing messages is reported as a gap."""
    sim, ref, run = _reference_and_run()
    t = sim.wheel_t
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)
    hole = (t > 2.0) & (t < 4.5)
    pos[hole] = np.nan
    js = JointStates((t * 1e9).astype(np.int64), ("left_wheel", "right_wheel"), pos, np.full_like(pos, np.nan))
    track, cleaning = wheel_track_from_joints(js, *run)
    assert cleaning.discarded["joint_states_without_wheel_values"] == np.count_nonzero(hole)
    gaps = track.info["gaps"]
    assert len(gaps) == 1 and gaps[0][0] <= 2.0 + 0.05 and gaps[0][1] >= 4.5 - 0.05
    missing = JointStates((t[~hole] * 1e9).astype(np.int64), ("left_wheel", "right_wheel"), pos[~hole],
                          np.full_like(pos[~hole], np.nan))
    same, _ = wheel_track_from_joints(missing, *run)
    assert np.array_equal(track.t, same.t) and np.allclose(track.T_world_base, same.T_world_base)


def test_a_joint_name_seen_in_two_messages_is_not_taken_for_a_wheel():
    """Before: two damaged messages whose joint names had a flipped bit ('fro.t_left_wheel_joint') added two 'wheels'
    with values in two messages only; averaged with them, the sides had no usable sample left."""
    sim, ref, run = _reference_and_run()
    t = sim.wheel_t
    names = ("front_left_wheel_joint", "front_right_wheel_joint", "fro.t_left_wheel_joint",
             "front_right_wheel_j\x8aint")
    pos = np.full((t.size, 4), np.nan)
    pos[:, 0], pos[:, 1] = sim.wheel_left, sim.wheel_right
    pos[[100, 200], 2] = 1.0  # the damaged messages: the stray names only
    pos[[100, 200], 1] = np.nan
    pos[[150], 3] = 2.0
    js = JointStates((t * 1e9).astype(np.int64), names, pos, np.full_like(pos, np.nan))
    track, cleaning = wheel_track_from_joints(js, *run)
    assert cleaning.wheel_joints == {"left": ["front_left_wheel_joint"], "right": ["front_right_wheel_joint"]}
    assert any("not taken for wheels" in w and "fro.t_left_wheel_joint" in w for w in cleaning.warnings)
    end = ref.poses_at([ref.t[-1] - 0.01])[0, :3, 3]
    assert np.linalg.norm(track.poses_at([ref.t[-1] - 0.01])[0, :3, 3] - end) < 0.01


def test_joint_states_that_all_carry_one_stamp_are_named_as_such():
    """Before: 'wheel odometry: need at least 2 samples, got 1', of 751 messages that all carried one stamp."""
    import pytest

    from plsgraph.errors import InputError

    sim, _, run = _reference_and_run()
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)
    js = JointStates(np.full(sim.wheel_t.size, 1_700_000_000_000_000_000, np.int64), ("left_wheel", "right_wheel"),
                     pos, np.full_like(pos, np.nan))
    with pytest.raises(InputError, match=f"all {sim.wheel_t.size} joint state messages carry the same header stamp"):
        wheel_track_from_joints(js, *run)


def test_wheel_positions_that_jump_every_step_are_refused_with_both_likely_causes():
    """Encoder ticks instead of radians, or messages sorted by scrambled stamps: each step jumps."""
    import pytest

    from plsgraph.errors import InputError

    sim, _, run = _reference_and_run()
    rng = np.random.default_rng(0)
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)[rng.permutation(sim.wheel_t.size)]  # scrambled order
    js = JointStates((sim.wheel_t * 1e9).astype(np.int64), ("left_wheel", "right_wheel"), pos,
                     np.full_like(pos, np.nan))
    with pytest.raises(InputError, match="implausibly large.*encoder ticks.*stamps are wrong"):
        wheel_track_from_joints(js, *run)


def test_joint_stamps_in_another_unit_than_nanoseconds_are_named_as_the_cause():
    """Before: stamps divided by 1000 (microseconds read as nanoseconds) were blamed on the angles: encoder ticks?"""
    import pytest

    from plsgraph.errors import InputError

    sim, _, run = _reference_and_run()
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)
    t_ns = (sim.wheel_t * 1e9).astype(np.int64)
    js = JointStates(t_ns[0] + (t_ns - t_ns[0]) // 1000, ("left_wheel", "right_wheel"), pos, np.full_like(pos, np.nan))
    with pytest.raises(InputError, match=r"stamped \d+(\.\d+)? us apart \(median\).*likely in another unit than "
                                         r"nanoseconds"):
        wheel_track_from_joints(js, *run)
    # The same angles on their true stamps make a track.
    track, _ = wheel_track_from_joints(JointStates(t_ns, ("left_wheel", "right_wheel"), pos, np.full_like(pos, np.nan)),
                                       *run)
    assert len(track) == t_ns.size


def _topic_mcap(path, topic, msgtype, payloads, t0):
    """An MCAP of one topic's messages (CDR ``payloads``) written in the given order, log times increasing from
    ``t0`` every 20 ms, whatever the stamps inside them say."""
    from mcap.writer import Writer

    from plsgraph.io.writer import message_definition

    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(msgtype, "ros2msg", message_definition(msgtype).encode())
        cid = w.register_channel(topic, "cdr", sid)
        for k, data in enumerate(payloads):
            w.add_message(cid, log_time=t0 + k * 20_000_000, publish_time=t0 + k * 20_000_000, data=data, sequence=k)
        w.finish()


def _joint_mcap(path, stamps, pos, names=("left_wheel", "right_wheel")):
    """An MCAP of JointState messages written in the given order (log times increasing), with the given stamps."""
    from plsgraph.io.writer import _joint_bytes

    payloads = [_joint_bytes(int(t), names, np.asarray(p, float), np.zeros(len(names)))
                for t, p in zip(stamps, pos, strict=True)]
    _topic_mcap(path, "/joint_states", "sensor_msgs/msg/JointState", payloads, int(min(stamps)))


def test_wrong_stamps_are_told_from_messages_recorded_out_of_order(tmp_path):
    """A review's recording with neighbouring JointState stamps swapped passed (ok, weak sigmas) after "header stamps
    go backwards 250 times; sorted by stamp". Stamps that are wrong make the angles jump back and forth in their order;
    messages that only arrived out of order are smoother in stamp order. The first is an input problem (flagged)."""
    from plsgraph.io.recording import read_recording
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, build_base_track

    sim, _, _ = _reference_and_run()
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)[:300]
    t = (sim.wheel_t[:300] * 1e9).astype(np.int64) + 1_700_000_000_000_000_000
    swapped = t.copy()
    swapped[0:-1:2], swapped[1::2] = t[1::2], t[0:-1:2]  # neighbours' stamps exchanged, the messages in order
    _joint_mcap(tmp_path / "wrong.mcap", swapped, pos)
    order = np.arange(t.size)
    for i in range(0, t.size - 1, 7):  # every seventh pair arrived the wrong way round, stamps right
        order[[i, i + 1]] = order[[i + 1, i]]
    _joint_mcap(tmp_path / "late.mcap", t[order], pos[order])
    wrong, late = read_recording(tmp_path / "wrong.mcap"), read_recording(tmp_path / "late.mcap")
    assert any("go backwards" in w for w in wrong.warnings) and any("go backwards" in w for w in late.warnings)
    assert wrong.joints.stamps_rougher is not None and wrong.joints.stamps_rougher > 10
    assert late.joints.stamps_rougher is None
    np.testing.assert_array_equal(late.joints.position, pos)  # sorted back into place
    opts = CalibrationOptions(board="acircles_4x11_a2")
    run = Run(tmp_path / "wrong.mcap", opts)
    build_base_track(run, wrong)
    assert any("the stamps are likely wrong" in p for p in run.input_problems), run.input_problems
    run = Run(tmp_path / "late.mcap", opts)
    build_base_track(run, late)
    assert run.input_problems == []


def test_wrong_odometry_stamps_are_told_from_messages_recorded_out_of_order(tmp_path):
    from plsgraph.io.recording import OdometryMsgs, read_recording
    from plsgraph.io.writer import _odom_bytes

    sim, ref, _ = _reference_and_run()
    n = 300
    t = (sim.wheel_t[:n] * 1e9).astype(np.int64) + 1_700_000_000_000_000_000
    q = np.zeros((n, 4))
    q[:, 3] = 1.0
    odo = OdometryMsgs(t, ref.T_world_base[:n, :3, 3], q, np.zeros((n, 3)), np.zeros((n, 3)))

    def write(path, stamps, rows):
        msgs = OdometryMsgs(stamps, odo.position[rows], q, np.zeros((n, 3)), np.zeros((n, 3)))
        _topic_mcap(path, "/odom", "nav_msgs/msg/Odometry", [_odom_bytes(msgs, k) for k in range(n)], int(t[0]))

    swapped = t.copy()
    swapped[0:-1:2], swapped[1::2] = t[1::2], t[0:-1:2]
    write(tmp_path / "wrong.mcap", swapped, np.arange(n))
    order = np.arange(n)
    for i in range(0, n - 1, 7):
        order[[i, i + 1]] = order[[i + 1, i]]
    write(tmp_path / "late.mcap", t[order], order)
    wrong, late = read_recording(tmp_path / "wrong.mcap"), read_recording(tmp_path / "late.mcap")
    assert wrong.odometry.stamps_rougher is not None and wrong.odometry.stamps_rougher > 10
    assert late.odometry.stamps_rougher is None
    np.testing.assert_allclose(late.odometry.position, odo.position)


def test_a_few_stamps_jittering_past_a_neighbour_are_not_taken_for_wrong_stamps(tmp_path):
    """A review: a fast driver's stamps that jitter past a neighbour now and then (3 of 10,000 at 1 kHz) roughened
    smooth angles many times over and were flagged as wrong; under a twentieth of the messages stepping back is
    jitter."""
    from plsgraph.io.recording import read_recording

    sim, _, _ = _reference_and_run()
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)[:300]
    t = (sim.wheel_t[:300] * 1e9).astype(np.int64) + 1_700_000_000_000_000_000
    jittered = t.copy()
    for i in (50, 150, 250):  # three stamps past their neighbour
        jittered[i], jittered[i + 1] = t[i + 1], t[i]
    _joint_mcap(tmp_path / "jitter.mcap", jittered, pos)
    rec = read_recording(tmp_path / "jitter.mcap")
    assert any("go backwards 3 times" in w for w in rec.warnings) and rec.joints.stamps_rougher is None
