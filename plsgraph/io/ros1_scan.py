"""Sequential reader of ROS 1 bags (format 2.0) that needs no index: the fallback for cut-short bags.

A bag written until the robot lost power has its records but no index (the index sits at the end). This
reader walks the records from the start (bag header, chunks with connections and messages), keeps every
message it can read, and stops with a warning at the first record that is cut off or malformed. Every
length field is checked against the bytes that are left before it is used.
"""

from __future__ import annotations

import bz2
import logging
import mmap
import struct
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from ..errors import RecordingError
from .base import RawMessage, ReadLog, TopicInfo
from .messages import normalize_type

log = logging.getLogger(__name__)

MAGIC = b"#ROSBAG V2.0\n"
_OP_MSG, _OP_BAG_HEADER, _OP_INDEX, _OP_CHUNK, _OP_CHUNK_INFO, _OP_CONN = 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
# Chunks above this uncompressed size are taken as corrupt instead of being allocated.
_MAX_CHUNK = 1 << 30


class _Corrupt(Exception):
    pass


def _fields(buf: bytes) -> dict[bytes, bytes]:
    out: dict[bytes, bytes] = {}
    pos = 0
    while pos < len(buf):
        if pos + 4 > len(buf):
            raise _Corrupt("record header field length cut off")
        (n,) = struct.unpack_from("<I", buf, pos)
        pos += 4
        if n > len(buf) - pos:
            raise _Corrupt(f"record header field of {n} bytes overruns its header")
        name, sep, value = buf[pos : pos + n].partition(b"=")
        if not sep:
            raise _Corrupt("record header field without '='")
        out[name] = value
        pos += n
    return out


def _records(buf: memoryview | bytes, pos: int, end: int) -> Iterator[tuple[int, dict[bytes, bytes], memoryview, int]]:
    """(op, header fields, data, offset) of consecutive records in ``buf[pos:end]``; raises _Corrupt (its ``pos``:
    where the record that could not be read starts)."""
    mv = memoryview(buf)
    while pos < end:
        try:
            if end - pos < 4:
                raise _Corrupt("record cut off in its header length")
            (hl,) = struct.unpack_from("<I", mv, pos)
            if hl > end - pos - 4:
                raise _Corrupt(f"record header of {hl} bytes runs past the end")
            hdr = _fields(bytes(mv[pos + 4 : pos + 4 + hl]))
            p = pos + 4 + hl
            if end - p < 4:
                raise _Corrupt("record cut off in its data length")
            (dl,) = struct.unpack_from("<I", mv, p)
            if dl > end - p - 4:
                cut = _Corrupt(f"record data of {dl} bytes runs past the end")
                cut.cut_record = (hdr, mv[p + 4 : end])  # the data the record has before the end
                raise cut
        except _Corrupt as exc:
            exc.pos = pos
            raise
        op = hdr.get(b"op", b"\xff")[:1]
        yield op[0] if op else 0xFF, hdr, mv[p + 4 : p + 4 + dl], pos
        pos = p + 4 + dl


def _index(buf: memoryview | bytes) -> tuple[list[int], list[tuple[dict[bytes, bytes], memoryview]]]:
    """The chunk positions (sorted) and the connection records of the bag's index, as far as they can be read (a
    bag cut short has none): where to go on after a damaged record, and the connections of chunks skipped."""
    positions: list[int] = []
    conns: list[tuple[dict[bytes, bytes], memoryview]] = []
    try:
        op, hdr, _, _ = next(_records(buf, len(MAGIC), len(buf)))
        if op != _OP_BAG_HEADER or len(hdr.get(b"index_pos", b"")) != 8:
            return positions, conns
        (index_pos,) = struct.unpack("<Q", hdr[b"index_pos"])
        if not len(MAGIC) < index_pos < len(buf):
            return positions, conns
        for op, hdr, body, _ in _records(buf, index_pos, len(buf)):
            if op == _OP_CONN:
                conns.append((hdr, body))
            elif op == _OP_CHUNK_INFO and len(hdr.get(b"chunk_pos", b"")) == 8:
                positions.append(struct.unpack("<Q", hdr[b"chunk_pos"])[0])
    except (_Corrupt, StopIteration):
        pass
    return sorted(p for p in positions if len(MAGIC) < p < len(buf)), conns


def _u32(hdr: dict[bytes, bytes], key: bytes) -> int:
    v = hdr.get(key)
    if v is None or len(v) < 4:
        raise _Corrupt(f"record lacks its {key.decode()} field")
    return struct.unpack_from("<I", v)[0]


def _decompress(hdr: dict[bytes, bytes], data: memoryview) -> bytes:
    comp = hdr.get(b"compression", b"none")
    size = _u32(hdr, b"size")
    if size > _MAX_CHUNK:
        raise _Corrupt(f"chunk claims {size} bytes uncompressed")
    if comp == b"none":
        out = bytes(data)
    elif comp == b"bz2":
        out = bz2.decompress(data)
    elif comp == b"lz4":
        import lz4.frame

        out = lz4.frame.decompress(bytes(data))
    else:
        raise _Corrupt(f"unknown chunk compression {comp!r}")
    if len(out) != size:
        raise _Corrupt(f"chunk decompressed to {len(out)} bytes, header says {size}")
    return out


def _decompress_cut(hdr: dict[bytes, bytes], data: memoryview) -> bytes:
    """As much of a chunk whose data is cut off at the end of the file as its bytes give: all of them when
    uncompressed, the complete blocks of a bz2 or lz4 stream. Empty when nothing can be recovered."""
    comp = hdr.get(b"compression", b"none")
    try:
        if comp == b"none":
            return bytes(data)
        if comp == b"bz2":
            return bz2.BZ2Decompressor().decompress(bytes(data))
        if comp == b"lz4":
            import lz4.frame

            return lz4.frame.LZ4FrameDecompressor().decompress(bytes(data))
    except Exception:  # noqa: BLE001 - bz2/lz4 raise assorted types on bad data: nothing recovered
        return b""
    return b""


class Ros1ScanSource:
    """A ROS 1 bag read front to back without its index. Message counts are what could be read."""

    def __init__(self, path: str | Path, log_: ReadLog | None = None) -> None:
        self.path = Path(path)
        self.log = log_ or ReadLog()
        with open(self.path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise RecordingError(f"{self.path} is not a ROS 1 bag (format 2.0): bad magic")
        self._conns: dict[int, tuple[str, str, str]] = {}  # id -> topic, type, definition
        self._topics: dict[str, TopicInfo] | None = None
        self._ts = None

    def topics(self) -> dict[str, TopicInfo]:
        if self._topics is None:
            for _ in self._iter(None, quiet=True):
                pass
            self._topics = {
                # The total per topic is unknown without the index: None, like an MCAP without summary.
                topic: TopicInfo(topic, normalize_type(typ), None, "ros1msg", msgdef, "ros1")
                for topic, typ, msgdef in self._conns.values()
            }
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        return self._iter(topics, quiet=False)

    def _iter(self, topics: set[str] | None, quiet: bool) -> Iterator[RawMessage]:
        # A read-only map keeps memory bounded by one chunk at a time, whatever the bag's size.
        with open(self.path, "rb") as f:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        read: Counter[str] = Counter()
        problem = None
        index = None
        pos = len(MAGIC)
        while True:
            try:
                yield from self._walk(data, pos, topics, quiet, read)
                break
            except _Corrupt as exc:
                if index is None:
                    index = _index(data)
                    for hdr, body in index[1]:  # the connections of any chunk skipped below
                        self._connection(hdr, body)
                nxt = next((p for p in index[0] if p > getattr(exc, "pos", len(data))), None)
                if nxt is None:
                    problem = exc
                    cut = getattr(exc, "cut_record", None)
                    if cut is not None and cut[0].get(b"op", b"")[:1] == bytes([_OP_CHUNK]):
                        # The file ends inside a chunk (a recorder stopped while writing it): its messages up to
                        # the cut are read, not the whole chunk lost.
                        yield from self._cut_chunk(cut[0], cut[1], topics, read)
                    break
                if not quiet:
                    self.log.warn(f"{self.path.name}: damaged record at byte {getattr(exc, 'pos', '?')} ({exc}); "
                                  f"went on at the next chunk, byte {nxt} (from the bag's index); what lay between "
                                  "is lost")
                pos = nxt
        if not quiet:
            for t, n in read.items():
                self.log.messages_read[t] = self.log.messages_read.get(t, 0) + n
            if problem is not None:
                self.log.stopped_early = True
                # Per topic: a calibration reads the bag twice (the events apart), and each pass says what it kept.
                kept = ", ".join(f"{t} {n}" for t, n in sorted(read.items())) or "none of the topics read"
                self.log.warn(
                    f"{self.path.name}: bag is cut short or corrupt ({problem}); kept the messages before it ({kept}; "
                    "how many were lost is unknown: the index is gone)"
                )

    def _walk(self, data, pos: int, topics: set[str] | None, quiet: bool, read: Counter) -> Iterator[RawMessage]:
        """The messages of the records from ``pos`` on; raises _Corrupt at the first record that cannot be read."""
        for op, hdr, body, off in _records(data, pos, len(data)):
            if op in (_OP_CONN, _OP_MSG):
                m = self._record(op, hdr, body, topics)
                if m is not None:
                    read[m.topic] += 1
                    yield m
            elif op == _OP_CHUNK:
                try:
                    inner = _decompress(hdr, body)
                except Exception as exc:  # noqa: BLE001 - bz2/lz4 raise assorted types on bad data
                    if not quiet:
                        self.log.warn(f"{self.path.name}: skipped a corrupt chunk at byte {off} ({exc})")
                    continue
                try:
                    yield from self._chunk_messages(inner, topics, read)
                except _Corrupt as exc:
                    if not quiet:
                        self.log.warn(f"{self.path.name}: chunk at byte {off} is damaged ({exc}); rest of it lost")

    def _chunk_messages(self, inner: bytes, topics: set[str] | None, read: Counter) -> Iterator[RawMessage]:
        """The messages of a chunk's decompressed records (counted in ``read``); raises _Corrupt where one cannot be
        read."""
        for op2, hdr2, body2, _ in _records(inner, 0, len(inner)):
            m = self._record(op2, hdr2, body2, topics)
            if m is not None:
                read[m.topic] += 1
                yield m

    def _cut_chunk(self, hdr: dict[bytes, bytes], body: memoryview, topics: set[str] | None, read: Counter
                   ) -> Iterator[RawMessage]:
        """The messages of a chunk the file ends inside, up to its first record cut off."""
        try:
            yield from self._chunk_messages(_decompress_cut(hdr, body), topics, read)
        except _Corrupt:
            pass  # the cut: what follows is lost, as the warning says

    def _record(self, op: int, hdr: dict[bytes, bytes], body: memoryview, topics: set[str] | None
                ) -> RawMessage | None:
        """A connection record is taken in; a message record gives its message (None if not wanted)."""
        if op == _OP_CONN:
            self._connection(hdr, body)
        elif op == _OP_MSG:
            return self._message(hdr, body, topics)
        return None

    def _connection(self, hdr: dict[bytes, bytes], body: memoryview) -> None:
        cid = _u32(hdr, b"conn")
        info = _fields(bytes(body))
        topic = (hdr.get(b"topic") or info.get(b"topic") or b"").decode("utf-8", "replace")
        typ = info.get(b"type", b"").decode("utf-8", "replace")
        self._conns.setdefault(cid, (topic, typ, info.get(b"message_definition", b"").decode("utf-8", "replace")))

    def _message(self, hdr: dict[bytes, bytes], body: memoryview, topics: set[str] | None) -> RawMessage | None:
        cid = _u32(hdr, b"conn")
        t = hdr.get(b"time", b"")
        if len(t) < 8 or cid not in self._conns:
            return None
        topic, typ, _ = self._conns[cid]
        if topics is not None and topic not in topics:
            return None
        sec, nsec = struct.unpack_from("<II", t)
        return RawMessage(topic, normalize_type(typ), sec * 1_000_000_000 + nsec, bytes(body), "ros1")

    def deserialize(self, m: RawMessage):
        """A message object from the bag's own (ROS 1) definition of its type."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        if self._ts is None:
            self._ts = get_typestore(Stores.EMPTY)
        if m.msgtype not in self._ts.types:
            info = self.topics()[m.topic]
            self._ts.register(get_types_from_msg(info.schema_text, m.msgtype))
        return self._ts.deserialize_ros1(bytes(m.data), m.msgtype)
