"""ROS 2 sqlite bags (``.db3``) read straight from their tables, without ``metadata.yaml``.

A rosbag2 sqlite file is self-describing: table ``topics`` holds every topic's name, type and
serialization format, table ``messages`` (topic_id, timestamp, data) the serialized messages; bags from
ROS 2 Iron on also keep the message definitions (table ``message_definitions``). ``metadata.yaml`` only
adds the file list, counts and compression settings, so a bag copied without it (or a folder of split
``.db3`` files whose metadata was lost) is still fully readable here. Messages are handed on as CDR bytes
and parsed by the project's CDR readers like any other container's.
"""

from __future__ import annotations

import logging
import sqlite3
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from ..errors import RecordingError
from .base import RawMessage, ReadLog, TopicInfo
from .messages import FileTypes, normalize_type

log = logging.getLogger(__name__)

_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def _connect(path: Path) -> sqlite3.Connection:
    # Read-only and immutable: no journal or lock file is created beside the user's recording.
    return sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True)


class Db3Source:
    """One or more ``.db3`` files of one ROS 2 bag (split files are read in name order)."""

    def __init__(self, paths: Path | list[Path], name: Path | None = None) -> None:
        files = [paths] if isinstance(paths, Path) else sorted(paths, key=_split_index)
        self.path = Path(name or files[0])
        self.files = files
        self.log = ReadLog()
        self._topics: dict[str, TopicInfo] = {}
        self._defs: dict[str, tuple[str, str]] = {}  # type -> (encoding, definition text)
        self._types = FileTypes(self.path.name, event_packages=True)
        for f in files:
            self._read_tables(f)
        if not self._topics:
            raise RecordingError(f"{self.path}: the ROS 2 sqlite bag declares no topics")

    def _read_tables(self, f: Path) -> None:
        try:
            con = _connect(f)
            try:
                cols = {r[1] for r in con.execute("PRAGMA table_info(topics)")}
                if not {"id", "name", "type"} <= cols:
                    raise RecordingError(
                        f"{f} is an sqlite file but not a ROS 2 bag (no table 'topics' with id, name, type)"
                    )
                ser = "serialization_format" if "serialization_format" in cols else "'cdr'"
                rows = con.execute(f"SELECT id, name, type, {ser} FROM topics").fetchall()
                counts = dict(
                    con.execute("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id").fetchall()
                )
                span = {
                    r[0]: (r[1], r[2])
                    for r in con.execute(
                        "SELECT topic_id, MIN(timestamp), MAX(timestamp) FROM messages GROUP BY topic_id"
                    )
                }
                tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
                if "message_definitions" in tables:
                    for typ, enc, text in con.execute(
                        "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
                    ):
                        if text:
                            self._defs[normalize_type(typ)] = (enc, text)
            finally:
                con.close()
        except sqlite3.Error as exc:
            raise RecordingError(
                f"{f} cannot be read as a ROS 2 sqlite bag ({type(exc).__name__}: {exc}); the file is corrupt, "
                "truncated or not a bag"
            ) from exc
        for tid, name, typ, fmt in rows:
            n = int(counts.get(tid, 0))
            t0, t1 = span.get(tid, (None, None))
            info = self._topics.get(name)
            if info is None:
                self._topics[name] = TopicInfo(name, normalize_type(typ), n, "", "", str(fmt or "cdr"), t0, t1)
            else:  # the same topic in another split file
                info.messages = (info.messages or 0) + n
                if t0 is not None:
                    info.t_first_ns = t0 if info.t_first_ns is None else min(info.t_first_ns, t0)
                    info.t_last_ns = t1 if info.t_last_ns is None else max(info.t_last_ns, t1)

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        read: Counter[str] = Counter()
        try:
            for f in self.files:
                yield from self._iter_file(f, topics, read)
        finally:
            for tp, n in read.items():
                self.log.messages_read[tp] = self.log.messages_read.get(tp, 0) + n
        if not self.log.stopped_early:
            return
        for tp, info in self._topics.items():
            want = info.messages or 0
            if (topics is None or tp in topics) and read[tp] < want:
                self.log.warn(f"{self.path.name}: topic {tp}: {want - read[tp]} of {want} messages lost")

    def _iter_file(self, f: Path, topics: set[str] | None, read: Counter) -> Iterator[RawMessage]:
        try:
            con = _connect(f)
        except sqlite3.Error as exc:
            self.log.stopped_early = True
            self.log.warn(f"{f.name}: cannot be opened ({exc})")
            return
        try:
            ids = {r[0]: (r[1], normalize_type(r[2])) for r in con.execute("SELECT id, name, type FROM topics")}
            want = [i for i, (name, _) in ids.items() if topics is None or name in topics]
            if not want:
                return
            q = (
                "SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN "
                f"({','.join('?' * len(want))}) ORDER BY timestamp, id"
            )
            cur = con.execute(q, want)
            while True:
                try:
                    rows = cur.fetchmany(256)
                except sqlite3.Error as exc:
                    self.log.stopped_early = True
                    self.log.warn(f"{f.name}: reading stopped at a corrupt part ({type(exc).__name__}: {exc})")
                    return
                if not rows:
                    return
                for tid, t, data in rows:
                    name, typ = ids[tid]
                    if data is None:
                        continue
                    if bytes(data[:4]) == _ZSTD_MAGIC:  # per-message zstd compression (metadata.yaml lost)
                        data = self._unzstd(name, data)
                        if data is None:
                            continue
                    read[name] += 1
                    yield RawMessage(name, typ, int(t), data, self._topics[name].serialization)
        except sqlite3.Error as exc:
            self.log.stopped_early = True
            self.log.warn(f"{f.name}: reading stopped at a corrupt part ({type(exc).__name__}: {exc})")
        finally:
            con.close()

    def _unzstd(self, topic: str, data: bytes) -> bytes | None:
        import zstandard

        try:
            return zstandard.ZstdDecompressor().decompress(data, max_output_size=1 << 30)
        except zstandard.ZstdError as exc:
            self.log.warn(f"{self.path.name}: topic {topic}: skipped a message whose zstd data is corrupt ({exc})")
            return None

    def deserialize(self, m: RawMessage):
        """A message object (rosbags dataclass) from CDR bytes: ROS 2 Humble types plus the bag's own definitions."""
        return self._types.deserialize(m, self._defs.get(m.msgtype),
                                       "which is not a standard ROS 2 type and has no ros2msg definition in the bag")

    def close(self) -> None:
        pass


def _split_index(p: Path) -> tuple[int, str]:
    # rosbag2 names split files <bag>_0.db3, <bag>_1.db3, ...: order by that number, not as text.
    stem = p.stem
    tail = stem.rsplit("_", 1)[-1]
    return (int(tail) if tail.isdigit() else -1, p.name)


def bare_db3_files(p: Path) -> list[Path] | None:
    """The ``.db3`` files to read directly: ``p`` itself (a ``.db3`` without ``metadata.yaml`` beside it) or
    those in directory ``p`` (a bag folder that lost its ``metadata.yaml``); None when rosbags should open it."""
    if p.is_dir():
        if (p / "metadata.yaml").exists():
            return None
        files = sorted(p.glob("*.db3"))
        return files or None
    if p.suffix == ".db3" and not (p.parent / "metadata.yaml").exists():
        return [p]
    return None
