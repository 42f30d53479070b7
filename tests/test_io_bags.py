"""Event messages serialized by rosbags (an independent serializer) in ROS 1 .bag and ROS 2 .db3 containers."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.io import read_events, read_recording
from plsgraph.io.event_codecs import encode_evt3

ROS1_EVENT = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
ROS1_ARRAY = "Header header\nuint32 height\nuint32 width\nEvent[] events\n"
PACKET = (
    "Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\nstring encoding\n"
    "bool is_bigendian\nuint8[] events\n"
)
T0 = 1_650_000_000_000_000_000


def _stores(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    hdr = "Header header" if ros1 else "std_msgs/Header header"
    types = {}
    types.update(get_types_from_msg(ROS1_EVENT.replace("time ts", "time ts" if ros1 else "builtin_interfaces/Time ts"),
                                    "dvs_msgs/msg/Event"))
    types.update(get_types_from_msg(ROS1_ARRAY.replace("Header header", hdr), "dvs_msgs/msg/EventArray"))
    types.update(get_types_from_msg(PACKET.replace("Header header", hdr), "event_camera_msgs/msg/EventPacket"))
    ts.register(types)
    return ts


def _events(rng, n, k):
    t = T0 + k * 10_000_000 + np.sort(rng.integers(0, 10_000, n)) * 1000
    return t, rng.integers(0, 240, n), rng.integers(0, 180, n), rng.random(n) < 0.5


def _msgs(ts, rng, n_msgs=6):
    """dvs EventArray and evt3 EventPacket message objects, plus the events they hold."""
    T = ts.types
    time_t = T["builtin_interfaces/msg/Time"]
    hdr_fields = T["std_msgs/msg/Header"].__dataclass_fields__
    mk_hdr = lambda t: T["std_msgs/msg/Header"](
        **({"seq": 0} if "seq" in hdr_fields else {}), stamp=time_t(sec=t // 10**9, nanosec=t % 10**9), frame_id="cam"
    )
    arrays, packets, truth = [], [], []
    prev = None
    for k in range(n_msgs):
        t, x, y, p = _events(rng, int(rng.integers(0, 400)), k)  # empty messages included
        truth.append((t, x, y, p))
        ev = [T["dvs_msgs/msg/Event"](x=int(a), y=int(b), ts=time_t(sec=int(c) // 10**9, nanosec=int(c) % 10**9),
                                      polarity=bool(d)) for a, b, c, d in zip(x, y, t, p, strict=True)]
        stamp = int(t[-1]) if t.size else T0 + k * 10_000_000
        arrays.append((stamp, T["dvs_msgs/msg/EventArray"](header=mk_hdr(stamp), height=180, width=240, events=ev)))
        blob, prev = encode_evt3((t - T0) // 1000, x, y, p, prev) if t.size else (b"", prev)
        packets.append((stamp, T["event_camera_msgs/msg/EventPacket"](
            header=mk_hdr(stamp), height=180, width=240, seq=k, time_base=0, encoding="evt3", is_bigendian=False,
            events=np.frombuffer(blob, np.uint8).copy())))
    t, x, y, p = (np.concatenate([q[i] for q in truth]) for i in range(4))
    return arrays, packets, (t, x, y, np.where(p, 1, -1))


def _check(ev, truth, exact_time=True):
    t, x, y, p = truth
    np.testing.assert_array_equal(ev.x, x)
    np.testing.assert_array_equal(ev.y, y)
    np.testing.assert_array_equal(ev.p, p)
    if exact_time:
        np.testing.assert_array_equal(ev.t, t)
    else:  # evt3 maps the sensor clock with the first packet's stamp: same spacing, shifted by a constant
        np.testing.assert_array_equal(np.diff(ev.t), np.diff(t))
    assert (ev.width, ev.height) == (240, 180)


def test_ros1_bag_event_arrays_and_packets(tmp_path):
    from rosbags.rosbag1 import Writer

    ts = _stores(ros1=True)
    arrays, packets, truth = _msgs(ts, np.random.default_rng(0))
    p = tmp_path / "ev.bag"
    with Writer(p) as w:
        ca = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        cp = w.add_connection("/event_camera/events", "event_camera_msgs/msg/EventPacket", typestore=ts)
        for (sa, ma), (sp, mp) in zip(arrays, packets, strict=True):
            w.write(ca, sa, ts.serialize_ros1(ma, "dvs_msgs/msg/EventArray"))
            w.write(cp, sp, ts.serialize_ros1(mp, "event_camera_msgs/msg/EventPacket"))
    _check(read_events(p, topic="/dvs/events"), truth)
    _check(read_events(p, topic="/event_camera/events"), truth, exact_time=False)
    rec = read_recording(p, topics={"events": "/dvs/events"})
    assert rec.event_encoding == "dvs" and rec.warnings == ()


def test_ros2_db3_event_arrays_and_packets(tmp_path):
    from rosbags.rosbag2 import Writer

    ts = _stores(ros1=False)
    arrays, packets, truth = _msgs(ts, np.random.default_rng(1))
    d = tmp_path / "bag"
    with Writer(d, version=8) as w:
        ca = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        cp = w.add_connection("/event_camera/events", "event_camera_msgs/msg/EventPacket", typestore=ts)
        for (sa, ma), (sp, mp) in zip(arrays, packets, strict=True):
            w.write(ca, sa, ts.serialize_cdr(ma, "dvs_msgs/msg/EventArray"))
            w.write(cp, sp, ts.serialize_cdr(mp, "event_camera_msgs/msg/EventPacket"))
    _check(read_events(d, topic="/dvs/events"), truth)
    (db3,) = d.glob("*.db3")
    _check(read_events(db3, topic="/event_camera/events"), truth, exact_time=False)
    # Two event topics and none chosen: the busiest is used, with a warning naming both.
    rec = read_recording(d)
    assert rec.event_topic in ("/dvs/events", "/event_camera/events")
    assert any("several event topics" in w for w in rec.warnings)


def test_ros1_profile_mcap_odometry(tmp_path):
    """MCAP files with the ros1 profile (ROS 1 serialization, ros1msg schema) read like ROS 1 bags."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    v3 = T["geometry_msgs/msg/Vector3"]
    p = tmp_path / "ros1.mcap"
    truth = []
    with open(p, "wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="test")
        sid = w.register_schema("nav_msgs/Odometry", "ros1msg", ts.generate_msgdef("nav_msgs/msg/Odometry")[0].encode())
        cid = w.register_channel("/odom", "ros1", sid)
        for i in range(5):
            stamp = T["builtin_interfaces/msg/Time"](sec=10 + i, nanosec=5)
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(i), y=0.5, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            twist = T["geometry_msgs/msg/Twist"](linear=v3(x=1.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.1 * i))
            m = T["nav_msgs/msg/Odometry"](
                header=T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="odom"),
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
            )
            t = (10 + i) * 10**9 + 5
            truth.append((t, float(i), 0.1 * i))
            w.add_message(cid, t, bytes(ts.serialize_ros1(m, "nav_msgs/msg/Odometry")), t)
        w.finish()
    rec = read_recording(p)
    ref = np.array(truth)
    np.testing.assert_array_equal(rec.odometry.t, ref[:, 0].astype(np.int64))
    np.testing.assert_array_equal(rec.odometry.position[:, 0], ref[:, 1])
    np.testing.assert_array_equal(rec.odometry.angular[:, 2], ref[:, 2])
    assert rec.warnings == ()


def test_unknown_encoding_first_is_fatal_later_is_skipped(tmp_path):
    from rosbags.rosbag2 import Writer

    from plsgraph.errors import RecordingError

    ts = _stores(ros1=False)
    _, packets, truth = _msgs(ts, np.random.default_rng(2), n_msgs=5)
    for name, bad_index in (("later", 3), ("first", 0)):
        d = tmp_path / name
        with Writer(d, version=8) as w:
            c = w.add_connection("/event_camera/events", "event_camera_msgs/msg/EventPacket", typestore=ts)
            for k, (stamp, msg) in enumerate(packets):
                if k == bad_index:
                    msg = type(msg)(**{**msg.__dict__, "encoding": "evt2"})
                w.write(c, stamp, ts.serialize_cdr(msg, "event_camera_msgs/msg/EventPacket"))
        if bad_index == 0:
            with pytest.raises(RecordingError, match="evt2.*supported"):
                read_events(d)
        else:
            rec = read_recording(d)
            assert any("skipped an unreadable event message" in w and "evt2" in w for w in rec.warnings)
            assert 0 < len(rec.events) < len(truth[0])


def test_overlapping_messages_are_sorted_with_warning(tmp_path):
    from rosbags.rosbag2 import Writer

    ts = _stores(ros1=False)
    arrays, _, truth = _msgs(ts, np.random.default_rng(4), n_msgs=4)
    d = tmp_path / "ov"
    with Writer(d, version=8) as w:
        c = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        # The second message's payload is logged first: its events come before the first one's.
        order = [(arrays[0][0], arrays[1][1]), (arrays[1][0], arrays[0][1]), arrays[2], arrays[3]]
        for stamp, msg in order:
            w.write(c, stamp, ts.serialize_cdr(msg, "dvs_msgs/msg/EventArray"))
    from plsgraph.io import read_events_with_log

    res = read_events_with_log(d)
    assert any("not in time order across messages" in w for w in res.warnings)
    order = np.argsort(truth[0], kind="stable")
    np.testing.assert_array_equal(res.events.t, truth[0][order])
    assert np.all(np.diff(res.events.t) >= 0)


def test_ros2_robot_topics_serialized_by_rosbags(tmp_path):
    """JointState / Odometry / Imu written by rosbags' CDR serializer read back exactly (fast CDR path)."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rng = np.random.default_rng(5)
    n = 20
    stamps = T0 + np.arange(n) * 20_000_000
    stamps[3] = 0  # a zero stamp falls back to the log time
    log_times = T0 + np.arange(n) * 20_000_000 + 1000
    pos, vel = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    odo = rng.normal(size=(n, 13))
    imu = rng.normal(size=(n, 6))
    hdr = lambda t, f: T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=int(t) // 10**9, nanosec=int(t) % 10**9), frame_id=f
    )
    v3 = lambda a: T["geometry_msgs/msg/Vector3"](x=a[0], y=a[1], z=a[2])
    d = tmp_path / "robot"
    with Writer(d, version=8) as w:
        cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        co = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        ci = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        for i in range(n):
            js = T["sensor_msgs/msg/JointState"](header=hdr(stamps[i], ""), name=["wheel_left", "wheel_right"],
                                                 position=pos[i], velocity=vel[i], effort=np.zeros(0))
            w.write(cj, int(log_times[i]), ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))
            o = odo[i]
            pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=o[0], y=o[1], z=o[2]),
                                               orientation=T["geometry_msgs/msg/Quaternion"](x=o[3], y=o[4], z=o[5],
                                                                                              w=o[6]))
            od = T["nav_msgs/msg/Odometry"](
                header=hdr(stamps[i], "odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=rng.normal(size=36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=v3(o[7:10]), angular=v3(o[10:13])),
                    covariance=rng.normal(size=36)))
            w.write(co, int(log_times[i]), ts.serialize_cdr(od, "nav_msgs/msg/Odometry"))
            im = T["sensor_msgs/msg/Imu"](
                header=hdr(stamps[i], "imu_link"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=rng.normal(size=9), angular_velocity=v3(imu[i, :3]),
                angular_velocity_covariance=rng.normal(size=9), linear_acceleration=v3(imu[i, 3:]),
                linear_acceleration_covariance=rng.normal(size=9))
            w.write(ci, int(log_times[i]), ts.serialize_cdr(im, "sensor_msgs/msg/Imu"))
    rec = read_recording(d)
    want_t = np.where(stamps > 0, stamps, log_times)
    order = np.argsort(want_t, kind="stable")
    np.testing.assert_array_equal(rec.joints.t, want_t[order])
    np.testing.assert_array_equal(rec.joints.position, pos[order])
    np.testing.assert_array_equal(rec.joints.velocity, vel[order])
    o = rec.odometry
    np.testing.assert_array_equal(np.c_[o.position, o.orientation, o.linear, o.angular], odo[order])
    assert (o.frame_id, o.child_frame_id) == ("odom", "base_link")
    np.testing.assert_array_equal(np.c_[rec.imu.gyro, rec.imu.accel], imu[order])
    assert any("zero header stamp" in w for w in rec.warnings)


def _chunked_bag(path, n_msgs: int = 400, compression: str = "bz2", chunk_bytes: int = 8 * 1024):
    """A ROS 1 bag of odometry-sized messages (std_msgs/String of 200 bytes) in chunks of about ``chunk_bytes``,
    ``compression`` "bz2", "lz4" or "none"."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    w = Writer(path)
    if compression != "none":
        w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    w.chunk_threshold = chunk_bytes
    with w:
        c = w.add_connection("/odom_text", "std_msgs/msg/String", typestore=ts)
        for k in range(n_msgs):
            text = f"{k:06d}" + "".join(chr(65 + (k * 7 + i) % 26) for i in range(194))
            w.write(c, T0 + k * 20_000_000, ts.serialize_ros1(ts.types["std_msgs/msg/String"](data=text),
                                                               "std_msgs/msg/String"))
    return n_msgs


def test_a_ros1_bag_with_one_damaged_chunk_keeps_the_chunks_after_it(tmp_path):
    """Before: one flipped byte in a chunk's compressed data, or in its record header, lost every later chunk too,
    although the bag's index says where each chunk starts."""
    from plsgraph.io.ros1_scan import _OP_CHUNK, MAGIC, _records
    from plsgraph.io.source import open_source

    p = tmp_path / "good.bag"
    n = _chunked_bag(p)
    data = p.read_bytes()
    chunks = [(off, len(body)) for op, _, body, off in _records(data, len(MAGIC), len(data)) if op == _OP_CHUNK]
    assert len(chunks) >= 6
    off, size = chunks[2]
    middle = data.index(b"BZh", off) + size // 2  # in the middle of the chunk's bz2 stream
    for name, at in (("inside", middle), ("header", off + 2)):
        bad = bytearray(data)
        bad[at] ^= 0x5A
        q = tmp_path / f"{name}.bag"
        q.write_bytes(bytes(bad))
        src = open_source(q)
        times = [m.log_time_ns for m in src.iter_raw({"/odom_text"})]
        last = (T0 + (n - 1) * 20_000_000)
        assert times[-1] == last, name  # the chunks after the damaged one are read
        assert n // 2 < len(times) < n and len(set(times)) == len(times), name  # one chunk lost, nothing twice
        assert any("chunk" in w for w in src.log.warnings), name


@pytest.mark.parametrize("compression", ["none", "lz4"])
def test_a_ros1_bag_cut_inside_its_last_chunk_keeps_that_chunks_messages_before_the_cut(tmp_path, compression):
    """Before: a bag cut inside a chunk (a recorder stopped while writing it) lost the whole chunk, though an
    uncompressed chunk's records before the cut are all there (and an lz4 stream's complete blocks can be read)."""
    import struct

    from plsgraph.io.ros1_scan import _OP_CHUNK, _OP_MSG, MAGIC, _decompress, _records
    from plsgraph.io.source import open_source

    p = tmp_path / "whole.bag"
    n = _chunked_bag(p, n_msgs=2000, compression=compression, chunk_bytes=256 * 1024)  # lz4 blocks: 64 kB
    data = p.read_bytes()
    chunks = [(hdr, body, off) for op, hdr, body, off in _records(data, len(MAGIC), len(data)) if op == _OP_CHUNK]
    assert len(chunks) >= 2
    in_whole_chunks = 0
    for hdr, body, _ in chunks[:-1]:
        inner = _decompress(hdr, body)
        in_whole_chunks += sum(1 for op, *_ in _records(inner, 0, len(inner)) if op == _OP_MSG)
    _, body, off = chunks[-1]
    start = off + 4 + struct.unpack_from("<I", data, off)[0] + 4  # where the last chunk's data begins
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: start + len(body) * 3 // 4])  # three quarters into the last chunk; the index is gone
    src = open_source(cut)
    times = [m.log_time_ns for m in src.iter_raw({"/odom_text"})]
    whole = [m.log_time_ns for m in open_source(p).iter_raw({"/odom_text"})]
    assert len(whole) == n and times == whole[: len(times)]  # in order, nothing twice, nothing invented
    assert in_whole_chunks < len(times) < n  # the cut chunk's messages before the cut are kept
    assert any("cut short" in w and f"/odom_text {len(times)};" in w for w in src.log.warnings)  # per topic
