"""Write simulated recordings as ROS 2 MCAP files (profile ``ros2``, ``ros2msg`` schemas, CDR messages).

The files open in Foxglove and with ``ros2 bag`` (rosbag2_storage_mcap): every schema carries the full
concatenated message definition, the way ros2 bag writes it. Ground truth goes to a sidecar
``<name>.truth.yaml`` beside the recording.
"""

from __future__ import annotations

import heapq
import logging
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import yaml

from ..core.camera import CameraModel
from ..core.events import EventStream
from ..errors import InputError
from .cdr import CdrWriter
from .event_codecs import encode_evt3, encode_libcaer, encode_libcaer_cmp, encode_mono
from .messages import typestore
from .recording import JointStates, OdometryMsgs

log = logging.getLogger(__name__)

EVENT_FORMATS = ("dvs", "libcaer_cmp", "evt3", "libcaer", "mono")

DEFAULT_TOPICS = {
    "dvs": "/dvs/events",
    "packet": "/event_camera/events",
    "joints": "/joint_states",
    "odometry": "/odom",
    "camera_info": "/event_camera/camera_info",
}


def message_definition(msgtype: str) -> str:
    """Full concatenated ROS 2 message definition text of a type (main type, then 'MSG:' dependencies)."""
    return typestore().generate_msgdef(msgtype, ros_version=2)[0]


def truth_path(path: str | Path) -> Path:
    p = Path(path)
    return p.with_name(p.stem + ".truth.yaml")


def _plain(v):
    """numpy values and containers -> plain Python for YAML."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    return v


def write_truth(path: str | Path, truth: dict) -> Path:
    """Write ground truth beside a recording as ``<name>.truth.yaml`` (numpy arrays become lists)."""
    if not isinstance(truth, dict):
        raise InputError("truth must be a dict")
    out = truth_path(path)
    with open(out, "w") as f:
        yaml.safe_dump(_plain(truth), f, sort_keys=False)
    return out


def read_truth(path: str | Path) -> dict:
    """The ground truth written by :func:`write_truth` for a recording (path of the recording or the sidecar)."""
    p = Path(path)
    tp = p if p.name.endswith(".truth.yaml") else truth_path(p)
    if not tp.exists():
        raise InputError(f"truth file {p} does not exist" if tp == p or not p.exists() else
                         f"no ground truth beside {p} (expected {tp})")
    with open(tp) as f:
        return yaml.safe_load(f) or {}


# ------------------------------------------------------------------------------------------ serializers


def _event_array_bytes(stamp: int, frame: str, ev: EventStream, i0: int, i1: int) -> bytes:
    w = CdrWriter()
    w.header(stamp, frame)
    w.prim("uint32", ev.height)
    w.prim("uint32", ev.width)
    n = i1 - i0
    w.prim("uint32", n)
    if n == 0:
        return w.getvalue()
    t = ev.t[i0:i1]
    sec, nsec = np.divmod(t, 1_000_000_000)
    # Element 0 starts 4-aligned (14 bytes); later ones start 2 mod 4 and pad 2 bytes before ts (16 bytes).
    block = np.zeros(14 + 16 * (n - 1), np.uint8)
    first = block[:14].view(
        np.dtype({"names": ["x", "y", "s", "n", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
                  "offsets": [0, 2, 4, 8, 12], "itemsize": 14})
    )
    rest = block[14:].view(
        np.dtype({"names": ["x", "y", "s", "n", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
                  "offsets": [0, 2, 6, 10, 14], "itemsize": 16})
    )
    for a, sl in ((first, slice(0, 1)), (rest, slice(1, n))):
        a["x"] = ev.x[i0:i1][sl]
        a["y"] = ev.y[i0:i1][sl]
        a["s"] = sec[sl]
        a["n"] = nsec[sl]
        a["p"] = ev.p[i0:i1][sl] > 0
    # The last element's trailing pad byte is not part of the message.
    return w.getvalue() + block[:-1].tobytes()


def _packet_bytes(stamp: int, frame: str, ev: EventStream, seq: int, time_base: int, enc: str, blob: bytes) -> bytes:
    w = CdrWriter()
    w.header(stamp, frame)
    w.prim("uint32", ev.height)
    w.prim("uint32", ev.width)
    w.prim("uint64", seq)
    w.prim("uint64", time_base)
    w.string(enc)
    w.prim("uint8", 0)
    w.raw_bytes(blob)
    return w.getvalue()


def _joint_bytes(t: int, names: tuple[str, ...], pos: np.ndarray, vel: np.ndarray) -> bytes:
    w = CdrWriter()
    w.header(t, "")
    w.string_sequence(list(names))
    w.sequence("float64", pos)
    w.sequence("float64", vel)
    w.sequence("float64", np.zeros(0))
    return w.getvalue()


def _odom_bytes(o: OdometryMsgs, i: int) -> bytes:
    w = CdrWriter()
    w.header(int(o.t[i]), o.frame_id)
    w.string(o.child_frame_id)
    w.fixed("float64", o.position[i])
    w.fixed("float64", o.orientation[i])
    w.fixed("float64", np.zeros(36))
    w.fixed("float64", o.linear[i])
    w.fixed("float64", o.angular[i])
    w.fixed("float64", np.zeros(36))
    return w.getvalue()


def _camera_bytes(t: int, frame: str, cam: CameraModel) -> bytes:
    w = CdrWriter()
    w.header(t, frame)
    w.prim("uint32", cam.height)
    w.prim("uint32", cam.width)
    w.string("plumb_bob")
    w.sequence("float64", cam.dist)
    w.fixed("float64", cam.K.ravel())
    w.fixed("float64", np.eye(3).ravel())
    P = np.zeros((3, 4))
    P[:, :3] = cam.K
    w.fixed("float64", P.ravel())
    for _ in range(2):
        w.prim("uint32", 1)  # binning
    for _ in range(4):
        w.prim("uint32", 0)  # roi
    w.prim("uint8", 0)
    return w.getvalue()


# ---------------------------------------------------------------------------------------------- writer


def _packets(ev: EventStream, packet_ns: int) -> Iterator[tuple[int, int]]:
    """Index ranges of consecutive ``packet_ns`` time windows, skipping empty ones."""
    if len(ev) == 0:
        return
    edges = np.arange(ev.t_first, ev.t_last + packet_ns, packet_ns, dtype=np.int64)
    idx = np.searchsorted(ev.t, edges, side="left")
    idx = np.unique(np.concatenate([idx, [len(ev)]]))
    for a, b in zip(idx[:-1], idx[1:], strict=False):
        if b > a:
            yield int(a), int(b)


def _event_messages(
    ev: EventStream, fmt: str, frame: str, packet_ns: int, evt3_sensor_start_us: int, warnings: list[str]
) -> Iterator[tuple[int, bytes]]:
    t_all = ev.t
    if fmt not in ("dvs", "mono") and len(ev) and np.any((t_all - t_all[0]) % 1000):
        # Packet encodings store µs; say so rather than silently moving events.
        warnings.append(f"{fmt}: event times are not whole microseconds after the first event; rounded to µs")
        t_all = t_all[0] + np.round((t_all - t_all[0]) / 1000.0).astype(np.int64) * 1000
    prev_high = None
    for seq, (a, b) in enumerate(_packets(ev, packet_ns)):
        t = t_all[a:b]
        # Drivers stamp libcaer/dvs packets when complete; the metavision driver stamps evt3 packets with
        # the host time of their first event, which is what readers use to map the sensor clock.
        stamp = int(t[0]) if fmt == "evt3" else int(t[-1])
        if fmt == "dvs":
            yield stamp, _event_array_bytes(stamp, frame, ev, a, b)
        elif fmt in ("libcaer_cmp", "libcaer", "mono"):
            tb = int(t[0])
            if fmt == "mono":
                blob = encode_mono(t - tb, ev.x[a:b], ev.y[a:b], ev.p[a:b])
            else:
                enc = encode_libcaer_cmp if fmt == "libcaer_cmp" else encode_libcaer
                blob = enc((t - tb) // 1000, ev.x[a:b], ev.y[a:b], ev.p[a:b])
            yield stamp, _packet_bytes(stamp, frame, ev, seq, tb, fmt, blob)
        else:
            t_us = (t - int(t_all[0])) // 1000 + evt3_sensor_start_us
            blob, prev_high = encode_evt3(t_us, ev.x[a:b], ev.y[a:b], ev.p[a:b], prev_high)
            yield stamp, _packet_bytes(stamp, frame, ev, seq, 0, fmt, blob)


def write_recording(
    path: str | Path,
    events: EventStream | None,
    joints: JointStates | None,
    odometry: OdometryMsgs | None,
    camera: CameraModel | None,
    truth: dict | None = None,
    event_format: str = "dvs",
    overwrite: bool = False,
    *,
    packet_ns: int = 10_000_000,
    camera_frame: str = "camera",
    evt3_sensor_start_us: int = 0,
    topics: dict[str, str] | None = None,
    chunk_bytes: int = 1 << 20,
) -> dict:
    """Write a ROS 2 MCAP recording (and ``<name>.truth.yaml`` if ``truth`` is given).

    ``event_format``: 'dvs' (dvs_msgs/msg/EventArray) or an event_camera_msgs/msg/EventPacket encoding:
    'libcaer_cmp', 'evt3', 'libcaer' (µs time resolution) or 'mono' (ns). Events go out in ``packet_ns``
    windows; camera info once per second. ``chunk_bytes`` is the MCAP chunk size (smaller chunks lose
    less when a file is damaged).
    Refuses to replace an existing file unless ``overwrite``. Returns a summary dict
    (path, truth path, messages per topic, warnings).
    """
    path = Path(path)
    if event_format not in EVENT_FORMATS:
        raise InputError(f"event_format must be one of {EVENT_FORMATS}, got {event_format!r}")
    if path.exists() and not overwrite:
        raise InputError(f"{path} exists; pass overwrite=True to replace it")
    if events is None and joints is None and odometry is None and camera is None:
        raise InputError("write_recording: nothing to write (events, joints, odometry and camera are all None)")
    if packet_ns <= 0:
        raise InputError("packet_ns must be positive")
    names = dict(DEFAULT_TOPICS)
    names.update(topics or {})
    if "camera_info" not in (topics or {}):  # beside the events, as a camera's driver publishes it
        ns = names["dvs" if event_format == "dvs" else "packet"].rstrip("/").rsplit("/", 1)[0]
        if ns:
            names["camera_info"] = f"{ns}/camera_info"
    from mcap.writer import CompressionType, Writer

    warnings: list[str] = []
    streams: list[Iterator[tuple[int, int, bytes]]] = []
    channels: list[tuple[str, str]] = []

    def add(topic: str, msgtype: str, msgs: Iterator[tuple[int, bytes]]) -> None:
        k = len(channels)
        channels.append((topic, msgtype))
        streams.append(((t, k, data) for t, data in msgs))

    if events is not None:
        events.check_sorted()
        if event_format == "dvs":
            add(names["dvs"], "dvs_msgs/msg/EventArray", _event_messages(events, "dvs", camera_frame, packet_ns, 0,
                                                                         warnings))
        else:
            add(names["packet"], "event_camera_msgs/msg/EventPacket",
                _event_messages(events, event_format, camera_frame, packet_ns, evt3_sensor_start_us, warnings))
    if joints is not None:
        add(names["joints"], "sensor_msgs/msg/JointState",
            ((int(joints.t[i]), _joint_bytes(int(joints.t[i]), joints.names, joints.position[i], joints.velocity[i]))
             for i in range(len(joints))))
    if odometry is not None:
        add(names["odometry"], "nav_msgs/msg/Odometry",
            ((int(odometry.t[i]), _odom_bytes(odometry, i)) for i in range(len(odometry))))
    if camera is not None:
        spans = [s.t for s in (events, joints, odometry) if s is not None and len(s.t)]
        t0 = min(int(s[0]) for s in spans) if spans else 0
        t1 = max(int(s[-1]) for s in spans) if spans else 0
        stamps = np.arange(t0, t1 + 1, 1_000_000_000, dtype=np.int64)
        add(names["camera_info"], "sensor_msgs/msg/CameraInfo",
            ((int(t), _camera_bytes(int(t), camera_frame, camera)) for t in stamps))

    tmp = path.with_name(path.name + ".part")
    counts = dict.fromkeys((c[0] for c in channels), 0)
    try:
        with open(tmp, "wb") as f:
            w = Writer(f, chunk_size=int(chunk_bytes), compression=CompressionType.ZSTD)
            w.start(profile="ros2", library="plsgraph")
            ids = []
            schema_ids: dict[str, int] = {}
            for topic, msgtype in channels:
                if msgtype not in schema_ids:
                    schema_ids[msgtype] = w.register_schema(
                        name=msgtype, encoding="ros2msg", data=message_definition(msgtype).encode()
                    )
                ids.append(w.register_channel(topic=topic, message_encoding="cdr", schema_id=schema_ids[msgtype],
                                              metadata={"offered_qos_profiles": ""}))
            seqs = [0] * len(channels)
            for t, k, data in heapq.merge(*streams, key=lambda r: (r[0], r[1])):
                w.add_message(ids[k], log_time=t, data=data, publish_time=t, sequence=seqs[k])
                seqs[k] += 1
                counts[channels[k][0]] += 1
            w.finish()
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    tpath = write_truth(path, truth) if truth is not None else None
    for msg in warnings:
        log.warning("%s: %s", path.name, msg)
    return {"path": str(path), "truth": str(tpath) if tpath else None, "messages": counts, "warnings": warnings}
