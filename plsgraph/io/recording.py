"""Containers for the non-event topics of a recording and ``read_recording``, which gathers everything.

Times are the message header stamps (sensor time), int64 ns; a message with a zero stamp falls back to
its log time and the fallback is reported in the warnings.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..core.camera import CameraModel
from ..core.events import EventStream
from ..errors import InputError, RecordingError
from .events_reader import _iter_chunks, _TopicDecoder, join_chunks, pick_topic
from .messages import (
    CAMERA_INFO_TYPE,
    EVENT_ARRAY_TYPES,
    EVENT_TYPES,
    IMU_TYPE,
    JOINT_STATE_TYPE,
    ODOMETRY_TYPE,
    parse_camera_info_cdr,
    parse_imu_cdr,
    parse_joint_state_cdr,
    parse_odometry_cdr,
)
from .source import Source, TopicInfo, open_source

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointStates:
    """``t`` (n,) int64 ns; ``names`` (k,); ``position``/``velocity`` (n, k), NaN where a message lacks a value."""

    t: np.ndarray
    names: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    #: When the messages' header stamps went backwards and, put in their order, the positions move back and forth
    #: more than in the order the messages were recorded: how many times more (the stamps are then likely wrong, not
    #: the order; see :func:`stamp_order_roughness`). None otherwise.
    stamps_rougher: float | None = None

    def __post_init__(self) -> None:
        n, k = len(self.t), len(self.names)
        if self.position.shape != (n, k) or self.velocity.shape != (n, k):
            raise InputError(
                f"joint states: position {self.position.shape} and velocity {self.velocity.shape} must be ({n}, {k})"
            )

    def __len__(self) -> int:
        return int(self.t.size)

    def wheel_columns(self, left: str | None = None, right: str | None = None) -> tuple[list[int], list[int]]:
        """Columns of the left and right wheel joints: by exact name if given, else every joint whose name
        has 'left' (or 'right') and 'wheel' in it (a four-wheel skid-steer base has two per side)."""

        def pick(side: str, name: str | None) -> list[int]:
            if name is not None:
                if name not in self.names:
                    raise InputError(f"joint states: no joint {name!r}; joints are {', '.join(self.names)}")
                return [self.names.index(name)]
            cols = [i for i, j in enumerate(self.names) if side in j.lower() and "wheel" in j.lower()]
            if not cols:
                cols = [i for i, j in enumerate(self.names) if side in j.lower()]
            if not cols:
                raise InputError(
                    f"joint states: cannot tell the {side} wheel among joints {', '.join(self.names)}; "
                    f"pass its name (left=..., right=...)"
                )
            return [i for i in cols if i not in self.stray_columns()]

        return pick("left", left), pick("right", right)

    def stray_columns(self) -> set[int]:
        """Joints with a value in under a tenth of the messages the most frequent joint has one in: a name that
        appears now and then (a damaged message's bit-flipped name, a joint published once) is not a wheel."""
        has = np.isfinite(self.position) | np.isfinite(self.velocity)
        counts = has.sum(axis=0) if has.size else np.zeros(len(self.names), int)
        top = int(counts.max()) if counts.size else 0
        return {i for i, c in enumerate(counts) if top >= 20 and c < 0.1 * top}

    def wheels(self, left: str | None = None, right: str | None = None) -> tuple[np.ndarray, ...]:
        """(left angle, right angle, left rate, right rate) in rad and rad/s, averaged over each side's joints."""
        lc, rc = self.wheel_columns(left, right)
        return (
            self.position[:, lc].mean(axis=1),
            self.position[:, rc].mean(axis=1),
            self.velocity[:, lc].mean(axis=1),
            self.velocity[:, rc].mean(axis=1),
        )


@dataclass(frozen=True)
class OdometryMsgs:
    """nav_msgs/Odometry as arrays: pose of ``child_frame_id`` in ``frame_id``; twist in the child frame."""

    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray  # x, y, z, w
    linear: np.ndarray
    angular: np.ndarray
    frame_id: str = "odom"
    child_frame_id: str = "base_link"
    stamps_rougher: float | None = None  # as JointStates.stamps_rougher, of the positions

    def __post_init__(self) -> None:
        n = len(self.t)
        for name, a, k in (
            ("position", self.position, 3),
            ("orientation", self.orientation, 4),
            ("linear", self.linear, 3),
            ("angular", self.angular, 3),
        ):
            if np.shape(a) != (n, k):
                raise InputError(f"odometry: {name} must be ({n}, {k}), got {np.shape(a)}")

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class ImuMsgs:
    """sensor_msgs/Imu as arrays: angular velocity (rad/s) and linear acceleration (m/s^2) in ``frame_id``."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    frame_id: str = "imu_link"

    def __post_init__(self) -> None:
        n = len(self.t)
        if np.shape(self.gyro) != (n, 3) or np.shape(self.accel) != (n, 3):
            raise InputError(f"imu: gyro {np.shape(self.gyro)} and accel {np.shape(self.accel)} must be ({n}, 3)")

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class Recording:
    """Everything plsgraph reads from one recording, with what went wrong while reading it."""

    path: Path
    topics: dict[str, TopicInfo]
    events: EventStream | None = None
    event_topic: str | None = None
    event_encoding: str | None = None
    joints: JointStates | None = None
    odometry: OdometryMsgs | None = None
    imu: ImuMsgs | None = None
    camera: CameraModel | None = None
    used_topics: dict[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    lost: dict[str, int | None] = field(default_factory=dict)


_ROLES = {
    "events": (EVENT_TYPES, "event"),
    "joints": ((JOINT_STATE_TYPE,), "joint state"),
    "odometry": ((ODOMETRY_TYPE,), "odometry"),
    "imu": ((IMU_TYPE,), "IMU"),
    "camera_info": ((CAMERA_INFO_TYPE,), "camera info"),
}


def _namespace(topic: str) -> str:
    return topic.rstrip("/").rsplit("/", 1)[0]


def _busiest_events(all_topics: dict) -> str | None:
    """The event topic with the most messages (the one the pipeline streams when none is named), if any."""
    cands = [(-(i.messages or 0), t) for t, i in all_topics.items() if i.msgtype in EVENT_TYPES]
    return min(cands)[1] if cands else None


def _camera_info_of(src, events_topic: str) -> str:
    """The camera info topic of the events' camera: the one in the events topic's namespace when there is one (a robot
    with two event cameras), else the only or the busiest one, with a warning when it is another camera's namespace."""
    topics = src.topics()
    cands = sorted(t for t, i in topics.items() if i.msgtype == CAMERA_INFO_TYPE)
    ns = _namespace(events_topic)
    same = [t for t in cands if ns and _namespace(t) == ns]
    if len(same) == 1:
        return same[0]
    picked = pick_topic(src, (CAMERA_INFO_TYPE,), None, "camera info")
    if ns and _namespace(picked) and _namespace(picked) != ns:
        src.log.warn(f"{src.path.name}: the camera info {picked} is not in the namespace of the events topic "
                     f"{events_topic}: check that it is this camera's, or give its intrinsics with --camera-info")
    return picked


_TYPE = {"joints": JOINT_STATE_TYPE, "odometry": ODOMETRY_TYPE, "imu": IMU_TYPE, "camera_info": CAMERA_INFO_TYPE}


def _stamp(obj, log_time: int) -> int:
    st = obj.header.stamp
    t = int(st.sec) * 1_000_000_000 + int(st.nanosec)
    return t if t > 0 else -int(log_time) - 1  # negative marks "fell back to the log time"


def _xyz(v) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


#: Header stamps are taken for wrong (not the recorded order) when, put in their order, the values move back and forth
#: this many times more (summed absolute second differences) than in the order the messages were recorded ...
STAMPS_ROUGHER = 2.0
#: ... and at least this share of the messages steps back: a few stamps of a fast driver that jitter past their
#: neighbour (3 of 10,000 at 1 kHz) are jitter, not wrong stamps, though they roughen smooth data many times.
STAMPS_BACK_SHARE = 0.05


def stamp_order_roughness(values: np.ndarray, order: np.ndarray) -> float | None:
    """How many times rougher the columns of ``values`` (n, k; rows in recorded order, NaN allowed) are in the order
    ``order`` (the stamps') than as recorded: the summed absolute second differences of each column's finite values.
    Messages that arrived out of order with right stamps are smoother in stamp order (ratio below 1); stamps that are
    wrong (swapped, scrambled) make the values jump back and forth in their order. None when the recorded order has
    no roughness to compare with (a still robot)."""
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    rough = [0.0, 0.0]
    for j, rows in enumerate((v, v[order])):
        for c in range(rows.shape[1]):
            x = rows[:, c][np.isfinite(rows[:, c])]
            if x.size > 2:
                rough[j] += float(np.abs(np.diff(x, 2)).sum())
    return rough[1] / rough[0] if rough[0] > 0 else None


class _Collector:
    """Accumulates one non-event topic's messages as rows, then builds the array container."""

    def __init__(self, role: str, topic: str) -> None:
        self.role, self.topic = role, topic
        self.t: list[int] = []
        self.rows: list = []
        self.names: list[str] = []
        self.frames: set[tuple[str, str]] = set()
        self.bad = 0

    def add(self, obj, log_time: int) -> None:
        self.t.append(_stamp(obj, log_time))
        if self.role == "joints":
            self.rows.append((list(obj.name), np.asarray(obj.position, float), np.asarray(obj.velocity, float)))
        elif self.role == "odometry":
            p, q = obj.pose.pose.position, obj.pose.pose.orientation
            tw = obj.twist.twist
            self.rows.append((*_xyz(p), q.x, q.y, q.z, q.w, *_xyz(tw.linear), *_xyz(tw.angular)))
            self.frames.add((obj.header.frame_id, obj.child_frame_id))
        elif self.role == "imu":
            self.rows.append((*_xyz(obj.angular_velocity), *_xyz(obj.linear_acceleration)))
            self.frames.add((obj.header.frame_id, ""))
        else:
            self.rows.append(obj)

    def add_cdr(self, data, log_time: int) -> None:
        """Same as :meth:`add` from ROS 2 CDR bytes, without building a message object."""
        if self.role == "joints":
            stamp, names, pos, vel = parse_joint_state_cdr(data, log_time)
            self.rows.append((names, pos, vel))
        elif self.role == "odometry":
            stamp, frame, child, row = parse_odometry_cdr(data, log_time)
            self.rows.append(row)
            self.frames.add((frame, child))
        elif self.role == "camera_info":
            stamp, fields = parse_camera_info_cdr(data, log_time)
            self.rows.append(fields)
        else:
            stamp, frame, row = parse_imu_cdr(data, log_time)
            self.rows.append(row)
            self.frames.add((frame, ""))
        self.t.append(stamp)

    def times(self, warn) -> np.ndarray:
        t = np.asarray(self.t, np.int64)
        fell_back = t < 0
        if np.any(fell_back):
            warn(f"{self.topic}: {int(fell_back.sum())} messages have a zero header stamp; used their log time")
            t = np.where(fell_back, -t - 1, t)
        return t

    def build(self, warn):
        if not self.rows:
            return None
        t = self.times(warn)
        order = np.argsort(t, kind="stable")
        back = int(np.sum(np.diff(t) < 0))
        if back:
            warn(f"{self.topic}: header stamps go backwards {back} times; sorted by stamp")
        if self.role == "joints":
            js = self._joints(t, order, warn)
            if back >= STAMPS_BACK_SHARE * t.size:
                ratio = stamp_order_roughness(js.position[np.argsort(order)], order)  # rows back in recorded order
                if ratio is not None and ratio > STAMPS_ROUGHER:
                    js = replace(js, stamps_rougher=ratio)
            return js
        if self.role in ("odometry", "imu"):
            a = np.asarray(self.rows, float)[order]
            if not np.all(np.isfinite(a)):
                warn(f"{self.topic}: {int(np.sum(~np.isfinite(a).all(axis=1)))} messages contain NaN or inf")
            frames = sorted(self.frames)
            if len(frames) > 1:
                warn(f"{self.topic}: frame ids change during the recording: {frames}")
            fr = frames[0] if frames else ("", "")
            if self.role == "odometry":
                ratio = (stamp_order_roughness(np.asarray(self.rows, float)[:, 0:3], order)
                         if back >= STAMPS_BACK_SHARE * t.size else None)
                return OdometryMsgs(t[order], a[:, 0:3], a[:, 3:7], a[:, 7:10], a[:, 10:13], fr[0], fr[1],
                                    stamps_rougher=ratio if ratio is not None and ratio > STAMPS_ROUGHER else None)
            return ImuMsgs(t[order], a[:, 0:3], a[:, 3:6], fr[0])
        return self._camera(warn)

    def _joints(self, t, order, warn) -> JointStates:
        names: list[str] = []
        for nm, _, _ in self.rows:
            for j in nm:
                if j not in names:
                    names.append(j)
        col = {j: i for i, j in enumerate(names)}
        n, k = len(self.rows), len(names)
        pos = np.full((n, k), np.nan)
        vel = np.full((n, k), np.nan)
        short = 0
        bad: dict[str, int] = {}  # joint -> messages that name it with a NaN or infinite position
        for i, (nm, p, v) in enumerate(self.rows):
            idx = [col[j] for j in nm]
            if p.size == len(nm):
                pos[i, idx] = p
                if not np.all(np.isfinite(p)):
                    for j in np.flatnonzero(~np.isfinite(p)):
                        bad[nm[j]] = bad.get(nm[j], 0) + 1
            elif p.size:
                short += 1
            if v.size == len(nm):
                vel[i, idx] = v
            elif v.size:
                short += 1
        if short:
            warn(f"{self.topic}: {short} messages have position/velocity arrays not matching their joint names")
        # A joint with no finite position at all is one whose driver reports none (ros2_control gives NaN for a joint
        # without a position interface; its velocities are used then): not a damaged value.
        bad = {j: c for j, c in bad.items() if np.any(np.isfinite(pos[:, col[j]]))}
        if bad:
            said = ", ".join(f"{j!r} in {c}" for j, c in sorted(bad.items(), key=lambda kv: -kv[1])[:4])
            warn(f"{self.topic}: joint positions that are NaN or infinite ({said} of {n} messages); a wheel's are "
                 "taken as missing and filled in from the messages around them")
        return JointStates(t[order], tuple(names), pos[order], vel[order])

    def _camera(self, warn) -> CameraModel | None:
        """The intrinsics most of the messages carry (the first such message's), among those that make a camera;
        a warning names what the others carry. None (with a warning) when no message makes one."""
        cams: list[tuple] = []  # (key, camera) of each usable message, in order
        unusable: list[str] = []
        for msg in self.rows:
            K = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), float)
            D = np.asarray(getattr(msg, "d", getattr(msg, "D", [])), float)
            model = msg.distortion_model or "plumb_bob"
            if model not in ("plumb_bob", "rational_polynomial") or D.size > 5 and np.any(D[5:] != 0):
                unusable.append(f"distortion {model!r} with {D.size} coefficients is not plumb_bob")
                continue
            try:
                cam = CameraModel(int(msg.width), int(msg.height), K.reshape(3, 3), D[:5])
            except (InputError, ValueError) as exc:
                unusable.append(str(exc))
                continue
            cams.append(((int(msg.width), int(msg.height), tuple(K.ravel()), tuple(D[:5])), cam))
        if not cams:
            warn(f"{self.topic}: none of its {len(self.rows)} camera info messages is usable ({unusable[0]}); camera "
                 "ignored")
            return None
        counts: dict[tuple, int] = {}
        for key, _ in cams:
            counts[key] = counts.get(key, 0) + 1
        best = max(counts, key=lambda k: counts[k])  # the first of the most frequent (dicts keep insertion order)
        cam = next(c for key, c in cams if key == best)
        others = len(self.rows) - counts[best]
        if others:
            why = f"; {len(unusable)} unusable ({unusable[0]})" if unusable else ""
            warn(f"{self.topic}: the intrinsics differ between messages: {counts[best]} of {len(self.rows)} carry the "
                 f"ones used (fx {best[2][0]:.6g}, fy {best[2][4]:.6g}, cx {best[2][2]:.6g}, cy {best[2][5]:.6g}){why}"
                 + ("; fewer than half agree, so check the camera calibration (or pass --camera-info)"
                    if 2 * counts[best] <= len(self.rows) else ""))
        return cam


def read_recording(
    path: str | Path | Source,
    topics: dict[str, str] | None = None,
    with_events: bool = True,
    events_topic: str | None = None,
) -> Recording:
    """Read the events, wheel joints, odometry, IMU and camera info of a recording in one pass.

    The camera info taken is the events camera's: in the namespace of the events topic (the one read, else
    ``events_topic``, else the busiest event topic) when several are recorded.

    ``topics`` overrides auto-detection per role: keys ``events``, ``joints``, ``odometry``, ``imu``,
    ``camera_info``. A role given explicitly must exist (else RecordingError listing the file's topics); a
    role left to auto-detection is simply None when the file has no topic of that type.
    """
    src = path if hasattr(path, "iter_raw") else open_source(path)
    topics = dict(topics or {})
    unknown = set(topics) - set(_ROLES)
    if unknown:
        raise InputError(f"read_recording: unknown topic roles {sorted(unknown)}; use {sorted(_ROLES)}")
    all_topics = src.topics()
    used: dict[str, str] = {}
    for role, (types, what) in _ROLES.items():
        if role == "events" and not with_events:
            continue
        if role in topics:
            used[role] = pick_topic(src, types, topics[role], what)
        elif role == "camera_info" and any(i.msgtype in types for i in all_topics.values()) and (
                used.get("events") or events_topic or _busiest_events(all_topics)):
            used[role] = _camera_info_of(src, used.get("events") or events_topic or _busiest_events(all_topics))
        elif any(i.msgtype in types for i in all_topics.values()):
            used[role] = pick_topic(src, types, None, what)
    if not used:
        from .events_reader import describe_topics

        events = _ROLES["events"][0]
        if not with_events and any(i.msgtype in events for i in all_topics.values()):
            # The events were not asked for here: what is missing is the robot's side (and the intrinsics).
            raise RecordingError(
                f"{src.path.name} has events but no odometry (sensor_msgs/JointState or nav_msgs/Odometry) and no "
                f"camera info; a calibration needs the odometry too (in this file, or another one given with "
                f"--odometry) and the intrinsics (--camera-info); {describe_topics(all_topics, src.log)}")
        raise RecordingError(f"{src.path.name}: nothing plsgraph can use; {describe_topics(all_topics, src.log)}")
    by_topic = {t: r for r, t in used.items()}
    collectors = {t: _Collector(r, t) for r, t in used.items() if r != "events"}

    ev_topic = used.get("events")
    dec = _TopicDecoder(src.log, f"{src.path.name}:{ev_topic}") if ev_topic else None
    chunks: list[EventStream] = []

    def other_messages():
        for m in src.iter_raw(set(by_topic)):
            if m.topic == ev_topic:
                yield m
                continue
            c = collectors[m.topic]
            try:
                if m.serialization == "cdr" and c.role in _TYPE and m.msgtype == _TYPE[c.role]:
                    c.add_cdr(m.data, m.log_time_ns)
                else:
                    c.add(src.deserialize(m), m.log_time_ns)
            except Exception as exc:  # noqa: BLE001 - rosbags raises assorted errors on corrupt bytes
                c.bad += 1
                if c.bad <= 3:
                    src.log.warn(f"{m.topic}: skipped an unreadable message at {m.log_time_ns} ns ({exc})")

    # Events are decoded as they stream past; every other message is collected on the way.
    msgs = other_messages()
    if dec is not None:
        chunks = list(_iter_chunks(_Forward(src, msgs), ev_topic, dec, 4_000_000, None, None))
    else:
        for _ in msgs:
            pass

    warn = src.log.warn
    for c in collectors.values():
        if c.bad:
            warn(f"{c.topic}: {c.bad} messages could not be deserialized")
    built = {c.role: c.build(warn) for c in collectors.values()}
    events = None
    enc = None
    if ev_topic is not None:
        if chunks or dec.width:
            events = join_chunks(chunks, dec, src.log, ev_topic)
        else:
            warn(f"{ev_topic}: no readable events")
        msgtype = all_topics[ev_topic].msgtype
        enc = "dvs" if msgtype in EVENT_ARRAY_TYPES else dec.encoding
    lost: dict[str, int | None] = {}
    for t in by_topic:
        want = all_topics[t].messages
        got = src.log.messages_read.get(t, 0)
        if want is not None and got < want:
            lost[t] = want - got
        elif src.log.stopped_early and want is None:
            lost[t] = None
    return Recording(
        path=Path(src.path),
        topics=all_topics,
        events=events,
        event_topic=ev_topic,
        event_encoding=enc,
        joints=built.get("joints"),
        odometry=built.get("odometry"),
        imu=built.get("imu"),
        camera=built.get("camera_info"),
        used_topics=used,
        warnings=tuple(src.log.warnings),
        lost=lost,
    )


class _Forward:
    """Presents an already-running message iterator as a source to the event chunker."""

    def __init__(self, src: Source, msgs) -> None:
        self.path, self.log, self._src, self._msgs = src.path, src.log, src, msgs

    def topics(self) -> dict[str, TopicInfo]:
        return self._src.topics()

    def iter_raw(self, topics: set[str] | None = None):
        yield from self._msgs
