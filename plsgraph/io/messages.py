"""Parsers of the event messages straight from their serialized bytes (CDR for ROS 2, ROS 1 serialization).

Event messages carry millions of events, so they are never turned into per-event Python objects: the
fixed header is read with a bounds-checked cursor and the event payload is viewed as a numpy array.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from ..errors import RecordingError
from .cdr import CdrError, CdrReader

# event_array_msgs/EventArray is the predecessor of EventPacket with the same fields.
EVENT_PACKET_TYPES = ("event_camera_msgs/msg/EventPacket", "event_array_msgs/msg/EventArray")
EVENT_ARRAY_TYPES = ("dvs_msgs/msg/EventArray",)
# Event streams of event-camera files (no ROS messages): their sources hand out decoded blocks.
EVENT_FILE_TYPES = ("aedat4/events", "prophesee/raw/evt2", "prophesee/raw/evt3")
EVENT_TYPES = EVENT_PACKET_TYPES + EVENT_ARRAY_TYPES + EVENT_FILE_TYPES
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
IMU_TYPE = "sensor_msgs/msg/Imu"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


# Message definitions of the two event packages (field lists as their .msg files declare them).
EVENT_MSG_DEFINITIONS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n",
    "dvs_msgs/msg/EventArray": "std_msgs/Header header\nuint32 height\nuint32 width\nEvent[] events\n",
    "event_camera_msgs/msg/EventPacket": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
        "string encoding\nbool is_bigendian\nuint8[] events\n"
    ),
}

_TYPESTORE = []


def typestore():
    """A rosbags typestore with the ROS 2 (Humble) standard types plus the two event packages (cached)."""
    if not _TYPESTORE:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        ts = get_typestore(Stores.ROS2_HUMBLE)
        types = {}
        for name, text in EVENT_MSG_DEFINITIONS.items():
            types.update(get_types_from_msg(text, name))
        types.update(get_types_from_msg(EVENT_MSG_DEFINITIONS[EVENT_PACKET_TYPES[0]], EVENT_PACKET_TYPES[1]))
        ts.register(types)
        _TYPESTORE.append(ts)
    return _TYPESTORE[0]


def normalize_type(name: str) -> str:
    """'dvs_msgs/EventArray' (ROS 1) and 'dvs_msgs/msg/EventArray' (ROS 2) -> the ROS 2 spelling."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name.strip()


@dataclass(frozen=True)
class EventPacketHeader:
    stamp_ns: int
    frame_id: str
    width: int
    height: int
    seq: int
    time_base: int
    encoding: str
    is_bigendian: bool


class _Ros1Reader:
    """Bounds-checked cursor over ROS 1 serialized bytes (little endian, no alignment)."""

    __slots__ = ("buf", "pos")

    def __init__(self, data) -> None:
        self.buf = data
        self.pos = 0

    def _need(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > len(self.buf):
            raise CdrError(
                f"ROS 1 message truncated or corrupt: {what} needs {n} bytes at offset {self.pos}, "
                f"only {max(len(self.buf) - self.pos, 0)} left"
            )

    def unpack(self, fmt: str, what: str):
        n = struct.calcsize(fmt)
        self._need(n, what)
        v = struct.unpack_from("<" + fmt, self.buf, self.pos)
        self.pos += n
        return v

    def string(self) -> str:
        (n,) = self.unpack("I", "string length")
        self._need(n, f"string of {n}")
        s = bytes(self.buf[self.pos : self.pos + n]).decode("utf-8", errors="replace")
        self.pos += n
        return s

    def header(self) -> tuple[int, str]:
        _seq, sec, nsec = self.unpack("III", "header")
        return sec * 1_000_000_000 + nsec, self.string()


_LE_TIME_LEN = struct.Struct("<iII")
_LE_2U32 = struct.Struct("<II")
_LE_2U64 = struct.Struct("<QQ")
_LE_U32 = struct.Struct("<I")


def _event_packet_le_cdr(data) -> tuple[EventPacketHeader, memoryview] | None:
    """:func:`parse_event_packet` of a little-endian CDR message in a few ``unpack_from`` calls, or None when the
    message is anything else or does not fit its own lengths (then the bounds-checked reader says what is wrong).
    The same fields as the general reader: alignment counted after the 4-byte encapsulation header."""
    buf = data if isinstance(data, bytes) else memoryview(data).cast("B")
    n = len(buf)
    if n < 16 or buf[0] != 0 or buf[1] != 1:
        return None
    sec, nsec, flen = _LE_TIME_LEN.unpack_from(buf, 4)
    pos = 16 + flen
    if pos > n:
        return None
    frame = bytes(buf[16:pos]).rstrip(b"\x00").decode("utf-8", errors="replace")
    pos += -pos % 4  # (pos - 4) % 4 == pos % 4
    if pos + 8 > n:
        return None
    height, width = _LE_2U32.unpack_from(buf, pos)
    pos += 8
    pos += -(pos - 4) % 8
    if pos + 20 > n:
        return None
    seq, time_base = _LE_2U64.unpack_from(buf, pos)
    (elen,) = _LE_U32.unpack_from(buf, pos + 16)
    pos += 20
    if pos + elen + 1 > n:
        return None
    enc = bytes(buf[pos : pos + elen]).rstrip(b"\x00").decode("utf-8", errors="replace")
    pos += elen
    big = bool(buf[pos])
    pos += 1
    pos += -pos % 4
    if pos + 4 > n:
        return None
    (blen,) = _LE_U32.unpack_from(buf, pos)
    pos += 4
    if pos + blen > n:
        return None
    if big:
        return None
    blob = memoryview(buf)[pos : pos + blen]
    return EventPacketHeader(sec * 1_000_000_000 + nsec, frame, width, height, seq, time_base, enc, False), blob


def parse_event_packet(data, serialization: str = "cdr") -> tuple[EventPacketHeader, memoryview]:
    """Header fields and a zero-copy view of the ``events`` blob of an EventPacket."""
    if serialization == "cdr":
        fast = _event_packet_le_cdr(data)
        if fast is not None:
            return fast
        r = CdrReader(data)
        stamp, frame = r.header()
        height = r.uint32()
        width = r.uint32()
        seq = r.uint64()
        time_base = r.uint64()
        enc = r.string()
        big = bool(r.prim("uint8"))
        blob = r.bytes_view()
    else:
        r1 = _Ros1Reader(memoryview(data).cast("B"))
        stamp, frame = r1.header()
        height, width, seq, time_base = r1.unpack("IIQQ", "geometry and time base")
        enc = r1.string()
        (big,) = r1.unpack("B", "is_bigendian")
        (n,) = r1.unpack("I", "events length")
        r1._need(n, f"events blob of {n}")
        blob = r1.buf[r1.pos : r1.pos + n]
    if big:
        raise RecordingError(
            "event packet declares big-endian event data, which no known driver writes; the file is corrupt "
            "or from an unsupported source"
        )
    return EventPacketHeader(stamp, frame, int(width), int(height), int(seq), int(time_base), enc, big), blob


# dvs_msgs/Event in ROS 2 CDR: uint16 x, uint16 y, Time ts (int32 sec, uint32 nanosec), bool polarity. The
# first element starts 4-aligned (after the sequence length) and takes 14 bytes; every later element starts
# 2 mod 4 and needs 2 bytes of padding before ts, so it takes 16 bytes.
def _event_dtype(endian: str, x: int, y: int, sec: int, nsec: int, pol: int, size: int) -> np.dtype:
    return np.dtype(
        {
            "names": ["x", "y", "sec", "nsec", "p"],
            "formats": [endian + "u2", endian + "u2", endian + "i4", endian + "u4", "u1"],
            "offsets": [x, y, sec, nsec, pol],
            "itemsize": size,
        }
    )


def parse_event_array(data, serialization: str = "cdr"):
    """(stamp_ns, width, height, t_ns, x, y, p) of a dvs_msgs/EventArray, decoded without a per-event loop."""
    if serialization == "cdr":
        r = CdrReader(data)
        stamp, _frame = r.header()
        height = r.uint32()
        width = r.uint32()
        n = r.uint32()
        e = "<" if r.little_endian else ">"
        buf = r.buf
        p0 = r.pos
        need = 0 if n == 0 else 13 + 16 * (n - 1) + 2
        if n and p0 + 13 + 16 * (n - 1) > len(buf):
            raise CdrError(f"EventArray claims {n} events but the message holds fewer")
        if n == 0:
            empty = np.zeros(0, np.int64)
            return stamp, width, height, empty, empty, empty, empty
        # One padded copy of the payload lets every element use the same 16-byte structured view.
        payload = bytes(buf[p0 : p0 + need]) + b"\x00" * 3
        first = np.frombuffer(payload, _event_dtype(e, 0, 2, 4, 8, 12, 14), count=1)
        rest = np.frombuffer(payload, _event_dtype(e, 0, 2, 6, 10, 14, 16), count=n - 1, offset=14)
        x = np.concatenate([first["x"], rest["x"]]).astype(np.int64)
        y = np.concatenate([first["y"], rest["y"]]).astype(np.int64)
        sec = np.concatenate([first["sec"], rest["sec"]]).astype(np.int64)
        nsec = np.concatenate([first["nsec"], rest["nsec"]]).astype(np.int64)
        p = np.concatenate([first["p"], rest["p"]]).astype(np.int64)
    else:
        r1 = _Ros1Reader(memoryview(data).cast("B"))
        stamp, _frame = r1.header()
        height, width, n = r1.unpack("III", "geometry and event count")
        r1._need(13 * n, f"{n} events")
        a = np.frombuffer(r1.buf, _event_dtype("<", 0, 2, 4, 8, 12, 13), count=n, offset=r1.pos)
        x, y = a["x"].astype(np.int64), a["y"].astype(np.int64)
        sec, nsec, p = a["sec"].astype(np.int64), a["nsec"].astype(np.int64), a["p"].astype(np.int64)
    t = sec * 1_000_000_000 + nsec
    return stamp, int(width), int(height), t, x, y, p


# ---------------------------------------------------------------- fast ROS 2 CDR parsers of the robot topics
# rosbags builds a Python object tree per message, which dominates reading long odometry logs; these read
# the few fields plsgraph uses straight from the CDR bytes (checked against rosbags in the tests).


def _stamp_or_log(stamp: int, log_time: int) -> int:
    return stamp if stamp > 0 else -int(log_time) - 1  # negative marks "fell back to the log time"


def parse_joint_state_cdr(data, log_time: int):
    """(stamp, names, position, velocity) of a sensor_msgs/JointState."""
    r = CdrReader(data)
    stamp, _frame = r.header()
    names = r.string_sequence()
    pos = r.sequence("float64")
    vel = r.sequence("float64")
    return _stamp_or_log(stamp, log_time), names, pos, vel


def parse_odometry_cdr(data, log_time: int):
    """(stamp, frame_id, child_frame_id, 13 floats: position, quaternion xyzw, linear, angular twist)."""
    r = CdrReader(data)
    stamp, frame = r.header()
    child = r.string()
    a = r.fixed("float64", 7 + 36 + 6 + 36)  # pose, pose covariance, twist, twist covariance
    row = np.concatenate([a[0:7], a[43:49]])
    return _stamp_or_log(stamp, log_time), frame, child, row


def parse_imu_cdr(data, log_time: int):
    """(stamp, frame_id, 6 floats: angular velocity, linear acceleration) of a sensor_msgs/Imu."""
    r = CdrReader(data)
    stamp, frame = r.header()
    a = r.fixed("float64", 4 + 9 + 3 + 9 + 3 + 9)
    return _stamp_or_log(stamp, log_time), frame, np.concatenate([a[13:16], a[25:28]])


def _strict_string(r: CdrReader, what: str) -> str:
    """A CDR string that must end in its NUL and be UTF-8, as a message deserializer demands: a damaged camera info is
    refused (and the next one used), not read with a garbled distortion model."""
    n = r.uint32()
    r._need(n, f"string of {n}")
    raw = bytes(r.buf[r.pos : r.pos + n])
    r.pos += n
    if not raw or raw[-1] != 0:
        raise CdrError(f"CDR string {what} lacks its terminating NUL")
    try:
        return raw[:-1].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CdrError(f"CDR string {what} is not UTF-8 ({exc.reason})") from exc


@dataclass(frozen=True)
class CameraInfoFields:
    """The fields of a sensor_msgs/CameraInfo the calibration uses (names as in the message)."""

    width: int
    height: int
    distortion_model: str
    d: np.ndarray
    k: np.ndarray


def parse_camera_info_cdr(data, log_time: int):
    """(stamp, :class:`CameraInfoFields`) of a sensor_msgs/CameraInfo; the whole message is read (r, p, binning and
    the region of interest too), so that a truncated one is refused like any other."""
    r = CdrReader(data)
    stamp = r.time()
    _strict_string(r, "frame_id")
    height = r.uint32()
    width = r.uint32()
    model = _strict_string(r, "distortion_model")
    d = r.sequence("float64")
    k = r.fixed("float64", 9)
    r.fixed("float64", 9 + 12)  # r, p
    r.fixed("uint32", 2 + 4)  # binning x / y, roi x / y offset, height, width
    r.prim("bool")  # roi.do_rectify
    return _stamp_or_log(stamp, log_time), CameraInfoFields(int(width), int(height), model, d, k)


def split_msgdef(name: str, text: str) -> list[tuple[str, str]]:
    """Split a concatenated ROS 2 message definition (main type, then '====' / 'MSG: dep' blocks)."""
    out: list[tuple[str, str]] = []
    current, lines = name, []
    for line in text.splitlines():
        if line.startswith("=" * 10):
            out.append((current, "\n".join(lines)))
            current, lines = "", []
        elif line.startswith("MSG: ") and not lines and not current:
            current = normalize_type(line[5:].strip())
        else:
            lines.append(line)
    out.append((current, "\n".join(lines)))
    return [(n, t) for n, t in out if n]


class FileTypes:
    """A ROS 2 type store private to one recording: rosbags' standard (Humble) types, optionally the event packages,
    and the types the file defines itself (``ros2msg`` text), which must not leak into other files."""

    def __init__(self, file_name: str, event_packages: bool = False):
        self.file_name = file_name
        self.event_packages = event_packages
        self._ts = None

    @property
    def store(self):
        if self._ts is None:
            from rosbags.typesys import Stores, get_typestore

            self._ts = get_typestore(Stores.ROS2_HUMBLE)
            if self.event_packages:
                self._ts.register({k: v for k, v in typestore().fielddefs.items() if k not in self._ts.fielddefs})
        return self._ts

    def deserialize(self, m, schema: tuple[str, str] | None, unknown: str):
        """The message object of a CDR ``RawMessage``; a type the store lacks is registered from ``schema``
        (encoding, text), else refused with ``unknown`` (why the file cannot say what the type is)."""
        if m.serialization != "cdr":
            raise RecordingError(f"{self.file_name}: topic {m.topic} uses message encoding {m.serialization!r}")
        ts = self.store
        if m.msgtype not in ts.types:
            from rosbags.typesys import get_types_from_msg

            enc, text = schema or ("", "")
            if enc != "ros2msg" or not text:
                raise RecordingError(f"{self.file_name}: topic {m.topic} has type {m.msgtype}, {unknown}")
            types = {}
            for name, part in split_msgdef(m.msgtype, text):
                types.update(get_types_from_msg(part, name))
            ts.register(types)
        return ts.deserialize_cdr(bytes(m.data), m.msgtype)
