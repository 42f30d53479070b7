"""Event messages serialized by rosbags (an independent serializer) in ROS 1 .bag and ROS 2 .db3 containers."""

from __future__ import annotations

import numpy as np

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
