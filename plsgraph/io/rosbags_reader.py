"""ROS 1 ``.bag`` and ROS 2 ``.db3`` (sqlite3 bag directory) access through the ``rosbags`` library."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from ..errors import RecordingError
from .base import RawMessage, ReadLog, TopicInfo
from .messages import normalize_type, typestore

log = logging.getLogger(__name__)


def _bag_path(p: Path) -> Path:
    # rosbags opens a ROS 2 bag by its directory (metadata.yaml); a lone .db3 is opened through its folder.
    if p.suffix == ".db3":
        if (p.parent / "metadata.yaml").exists():
            return p.parent
        raise RecordingError(
            f"{p} is a ROS 2 sqlite file without metadata.yaml beside it; run `ros2 bag reindex {p.parent}` "
            "or pass the bag directory"
        )
    return p


def open_bag(path: Path):
    """A RosbagsSource, or for a ROS 1 bag whose index cannot be read, a sequential scan of its records."""
    try:
        return RosbagsSource(path)
    except RecordingError as exc:
        if Path(path).suffix != ".bag" or not Path(path).is_file():
            raise
        from .ros1_scan import Ros1ScanSource

        src = Ros1ScanSource(path)
        src.log.warn(f"{Path(path).name}: index unreadable ({exc.__cause__ or exc}); reading the bag front to back")
        if not src.topics():
            raise RecordingError(f"{path}: no readable connections or messages in the bag") from exc
        return src


class RosbagsSource:
    """A ROS 1 bag or ROS 2 bag directory. Messages keep their native serialization ('ros1' or 'cdr')."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        self.log = ReadLog()
        self._bag = _bag_path(self.path)
        try:
            # Older ROS 2 bags carry no type definitions; the default store covers the types plsgraph reads.
            self._reader = AnyReader([self._bag], default_typestore=typestore())
            self._reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises its own error types plus OS/struct errors
            hint = ("if it is a ROS 1 bag that was cut short, run `rosbag reindex` on a copy first"
                    if self.path.is_file() and self.path.suffix != ".db3" else
                    f"if its metadata.yaml is missing or damaged, run `ros2 bag reindex {self.path}` on a copy first")
            raise RecordingError(
                f"{self.path} cannot be opened as a ROS bag ({type(exc).__name__}: {exc}); {hint}"
            ) from exc
        self.serialization = "cdr" if self._reader.is2 else "ros1"
        self._topics: dict[str, TopicInfo] = {}
        for c in self._reader.connections:
            name = normalize_type(c.msgtype)
            if c.topic in self._topics:
                self._topics[c.topic].messages = (self._topics[c.topic].messages or 0) + c.msgcount
                continue
            self._topics[c.topic] = TopicInfo(c.topic, name, c.msgcount, "ros1msg" if not self._reader.is2 else "", "",
                                              self.serialization)

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        read: Counter[str] = Counter()
        given: Counter[tuple[str, int]] = Counter()  # (topic, time) of the messages handed out
        it = self._reader.messages(connections=conns)
        while True:
            try:
                c, t, raw = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - corrupt chunk or sqlite page
                if not self._reader.is2 and self.path.is_file():
                    # A ROS 1 bag: read it front to back past the damage (chunk by chunk, the index's chunk
                    # positions to go on after a damaged record), handing out what was not handed out yet.
                    yield from self._past_damage(exc, topics, given, read)
                    break
                self.log.stopped_early = True
                self.log.warn(f"{self.path.name}: reading stopped at a corrupt part ({type(exc).__name__}: {exc})")
                break
            read[c.topic] += 1
            given[(c.topic, int(t))] += 1
            yield RawMessage(c.topic, normalize_type(c.msgtype), int(t), raw, self.serialization)
        for tp, n in read.items():
            self.log.messages_read[tp] = self.log.messages_read.get(tp, 0) + n
        for tp in {c.topic for c in conns}:
            want = self._topics[tp].messages
            if self.log.stopped_early and want is not None and read[tp] < want:
                self.log.warn(f"{self.path.name}: topic {tp}: {want - read[tp]} of {want} messages lost")

    def _past_damage(self, exc: Exception, topics: set[str] | None, given: Counter, read: Counter
                     ) -> Iterator[RawMessage]:
        from .base import ReadLog
        from .ros1_scan import Ros1ScanSource

        self.log.warn(f"{self.path.name}: a corrupt part ({type(exc).__name__}: {exc}); read the bag front to back "
                      "from there on")
        scan = Ros1ScanSource(self.path, ReadLog())
        for m in scan.iter_raw(topics):
            key = (m.topic, m.log_time_ns)
            if given[key]:
                given[key] -= 1
                continue
            read[m.topic] += 1
            yield RawMessage(m.topic, m.msgtype, m.log_time_ns, m.data, self.serialization)
        for w in scan.log.warnings:
            self.log.warn(w)
        self.log.stopped_early = True  # the per-topic counts below say what was lost

    def deserialize(self, m: RawMessage):
        """A message object (rosbags dataclass) using the bag's own type definitions."""
        return self._reader.deserialize(bytes(m.data), self._conn_type(m))

    def _conn_type(self, m: RawMessage) -> str:
        for c in self._reader.connections:
            if c.topic == m.topic:
                return c.msgtype
        return m.msgtype

    def close(self) -> None:
        self._reader.close()
