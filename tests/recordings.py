"""Small random recordings for reader tests: events, wheel joint states, odometry and camera intrinsics."""

from __future__ import annotations

import numpy as np

from plsgraph.core.camera import CameraModel
from plsgraph.core.events import EventStream
from plsgraph.io import JointStates, OdometryMsgs

T0 = 1_700_000_000_000_000_000  # a live-clock-like stamp origin (ns)


def random_streams(n: int, seconds: float, seed: int, fy: float = 320.0, dist=None):
    """(events, joints, odometry, camera) of ``n`` random events and 50 Hz wheel/odometry messages over ``seconds``."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, int(seconds * 1e6), n)) * 1000 + T0
    ev = EventStream.from_arrays(t, rng.integers(0, 346, n), rng.integers(0, 260, n), rng.random(n) < 0.5, 346, 260)
    tj = T0 + np.arange(0, int(seconds * 1e9), 20_000_000)
    js = JointStates(tj, ("left_wheel", "right_wheel"), rng.normal(size=(tj.size, 2)), rng.normal(size=(tj.size, 2)))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (tj.size, 1))
    v3 = lambda: rng.normal(size=(tj.size, 3))
    od = OdometryMsgs(tj, v3(), q, v3(), v3())
    cam = CameraModel(346, 260, np.array([[320.0, 0, 173], [0, fy, 130], [0, 0, 1]]),
                      np.zeros(5) if dist is None else dist)
    return ev, js, od, cam


def damage(rng, data: bytes) -> tuple[bytes, str]:
    """A damaged copy of ``data`` (truncated, bit flips, or both) and how it was damaged."""
    b = bytearray(data)
    mode = int(rng.integers(0, 3))
    if mode == 0:
        return bytes(b[: int(rng.integers(0, len(b)))]), "truncated"
    if mode == 1:
        for _ in range(int(rng.integers(1, 4))):
            j = int(rng.integers(0, len(b)))
            b[j] ^= 1 << int(rng.integers(0, 8))
        return bytes(b), "bit flips"
    b = b[: int(rng.integers(len(b) // 2, len(b)))]
    b[int(rng.integers(0, len(b)))] ^= 0xFF
    return bytes(b), "truncated and flipped"


def damaged_copies(tmp_path, data: bytes, seed: int, n: int, suffix: str):
    """(path, how) of ``n`` randomly damaged copies of ``data``, reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        bad, how = damage(rng, data)
        p = tmp_path / f"bad{i}{suffix}"
        p.write_bytes(bad)
        yield p, how


def copy_mcap(src, dst, copies=lambda topic: 1, also: dict[str, str] | None = None) -> None:
    """Write the MCAP ``src`` again as ``dst`` with each message of a topic written ``copies(topic)`` times (0 leaves
    the topic's messages out; its channel stays registered only if some message is kept). ``also`` maps a topic to a
    second topic its messages are written to as well (e.g. a second camera's camera info)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f_in, open(dst, "wb") as f_out:
        reader = make_reader(f_in)
        summary = reader.get_summary()
        w = Writer(f_out)
        w.start()
        schemas = {sid: w.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        chans = {cid: w.register_channel(c.topic, c.message_encoding, schemas[c.schema_id], c.metadata)
                 for cid, c in summary.channels.items() if copies(c.topic) > 0}
        extra = {c.topic: w.register_channel(also[c.topic], c.message_encoding, schemas[c.schema_id], c.metadata)
                 for c in summary.channels.values() if c.topic in (also or {})}
        for _s, channel, msg in reader.iter_messages():
            for _ in range(copies(channel.topic) if channel.id in chans else 0):
                w.add_message(chans[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
            if channel.topic in extra:
                w.add_message(extra[channel.topic], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        w.finish()
