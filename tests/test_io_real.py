"""The real sample recordings decode, checked against independent slow decoders and the containers' own tools."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from realdata import SHARED_REAL_DIR

DAVIS = SHARED_REAL_DIR / "davis346_tagboard.mcap"
JACKAL = SHARED_REAL_DIR / "jackal_odometry.bag"

pytestmark = pytest.mark.skipif(not DAVIS.exists(), reason="shared real recordings not present")


def _slow_event_packet(data: bytes):
    """Deliberately plain CDR walk of an EventPacket: (width, height, time_base, encoding, blob)."""
    o = 4 + 8  # encapsulation, stamp
    (n,) = struct.unpack_from("<I", data, o)
    o += 4 + n
    o += (-(o - 4)) % 4
    height, width = struct.unpack_from("<II", data, o)
    o += 8
    o += (-(o - 4)) % 8
    _seq, time_base = struct.unpack_from("<QQ", data, o)
    o += 16
    (n,) = struct.unpack_from("<I", data, o)
    enc = data[o + 4 : o + 4 + n].rstrip(b"\0").decode()
    o += 4 + n + 1
    o += (-(o - 4)) % 4
    (n,) = struct.unpack_from("<I", data, o)
    return width, height, time_base, enc, data[o + 4 : o + 4 + n]


def _slow_libcaer_cmp(blob: bytes, time_base: int, width: int, height: int, ex: int):
    """One word at a time, as a sequential decoder would: list of (t, x, y, p) and the x state."""
    out = []
    high = low = 0
    base_y = pol = 0
    for (w,) in struct.iter_unpack("<H", blob):
        code, rest = w >> 12, w & 0xFFF
        if code == 0:
            high = rest << 12
        elif code == 1:
            low = rest
        elif code == 2:
            ex = w & 0x7FF
        elif code == 3:
            y = w & 0x7FF
            if ex < width and y < height:
                out.append((time_base + (high | low) * 1000, ex, y, 1 if (w >> 11) & 1 else -1))
        elif code == 4:
            base_y, pol = w & 0x7FF, (w >> 11) & 1
        elif code == 5:
            for i in range(8):
                if w & (1 << i) and ex < width and base_y + i < height:
                    out.append((time_base + (high | low) * 1000, ex, base_y + i, 1 if pol else -1))
            base_y += 8
    return out, ex


def test_davis_libcaer_cmp_matches_slow_reference_and_summary():
    from mcap.reader import make_reader

    from plsgraph.io import read_events_with_log

    res = read_events_with_log(DAVIS)
    ev = res.events
    assert res.encoding == "libcaer_cmp" and res.topic == "/event_camera/events"
    assert (ev.width, ev.height) == (346, 260)
    assert res.warnings == ()

    with open(DAVIS, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 100
        ref, ex, n_msgs, first_tb = [], 0, 0, None
        for _s, _c, m in reader.iter_messages():
            n_msgs += 1
            if n_msgs > 4:
                continue
            w, h, tb, enc, blob = _slow_event_packet(m.data)
            assert enc == "libcaer_cmp"
            first_tb = tb if first_tb is None else first_tb
            evs, ex = _slow_libcaer_cmp(blob, tb, w, h, ex)
            ref += evs
    assert n_msgs == 100
    ref = np.array(ref, dtype=np.int64)
    n = len(ref)
    assert n > 10_000
    np.testing.assert_array_equal(ev.t[:n], ref[:, 0])
    np.testing.assert_array_equal(ev.x[:n], ref[:, 1])
    np.testing.assert_array_equal(ev.y[:n], ref[:, 2])
    np.testing.assert_array_equal(ev.p[:n], ref[:, 3])
    # Whole file: time-ordered, spanning the 1.0 s recording, starting at the first packet's time base.
    assert ev.t[0] == first_tb
    assert np.all(np.diff(ev.t) >= 0)
    assert 0.95 < ev.duration_s <= 1.01
    # Each event costs at least one 2-byte word, which bounds the count from the raw payload size.
    assert 400_000 < len(ev) < 3_118_257 / 2


def test_davis_chunks_equal_whole_and_window():
    from plsgraph.io import iter_event_chunks, read_events

    whole = read_events(DAVIS)
    chunks = list(iter_event_chunks(DAVIS, chunk_events=100_000))
    assert len(chunks) > 3
    assert all(len(c) < 200_000 for c in chunks)
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), whole.t)
    np.testing.assert_array_equal(np.concatenate([c.x for c in chunks]), whole.x)
    t0, t1 = whole.t_first + 200_000_000, whole.t_first + 300_000_000
    win = read_events(DAVIS, t0=t0, t1=t1)
    ref = whole.slice_time(t0, t1)
    np.testing.assert_array_equal(win.t, ref.t)
    np.testing.assert_array_equal(win.y, ref.y)


@pytest.mark.skipif(not JACKAL.exists(), reason="shared real recordings not present")
def test_jackal_bag_matches_rosbags_deserializer():
    from rosbags.highlevel import AnyReader

    from plsgraph.io import read_recording

    rec = read_recording(JACKAL)
    assert rec.warnings == () and rec.events is None and rec.camera is None
    assert rec.used_topics == {"odometry": "/jackal_velocity_controller/odom", "imu": "/imu/data"}
    ref_odom, ref_imu = [], []
    with AnyReader([JACKAL]) as r:
        for c, _t, raw in r.messages():
            m = r.deserialize(raw, c.msgtype)
            st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            if c.topic == "/imu/data":
                ref_imu.append((st, m.angular_velocity.z, m.linear_acceleration.x))
            else:
                p, tw = m.pose.pose, m.twist.twist
                ref_odom.append((st, p.position.x, p.position.y, p.orientation.w, tw.linear.x, tw.angular.z))
    ref_odom = np.array(sorted(ref_odom))
    ref_imu = np.array(sorted(ref_imu))
    o = rec.odometry
    assert len(o) == len(ref_odom) == 3060 and len(rec.imu) == len(ref_imu) == 3061
    np.testing.assert_array_equal(o.t, ref_odom[:, 0].astype(np.int64))
    np.testing.assert_array_equal(np.c_[o.position[:, :2], o.orientation[:, 3], o.linear[:, 0], o.angular[:, 2]],
                                  ref_odom[:, 1:])
    np.testing.assert_array_equal(np.c_[rec.imu.gyro[:, 2], rec.imu.accel[:, 0]], ref_imu[:, 1:])
    # 50 Hz wheel odometry over about a minute.
    assert abs(np.median(np.diff(o.t)) * 1e-9 - 0.02) < 1e-3
    assert 60 < (o.t[-1] - o.t[0]) * 1e-9 < 62
    assert (o.frame_id, o.child_frame_id) == ("odom", "base_link")


def test_davis_inspect_agrees_with_reader():
    from plsgraph.io import inspect_recording, read_events, render_inspection

    info = inspect_recording(DAVIS)
    (row,) = info["topics"]
    ev = read_events(DAVIS)
    assert row["messages"] == 100 and row["encoding"] == "libcaer_cmp"
    assert (row["events"], row["events_on"], row["events_off"]) == (len(ev), ev.n_on, ev.n_off)
    assert (row["t_first_ns"], row["t_last_ns"]) == (ev.t_first, ev.t_last)
    table = render_inspection(info)
    assert "/event_camera/events" in table and f"{len(ev):,}" in table
