"""MCAP container access with the ``mcap`` library, tolerant of truncated and corrupt files.

Messages are read in one forward pass (chunk by chunk, so memory is bounded by the chunk size). A corrupt
chunk (bad CRC, bad compression) is skipped with a warning; a corrupt record header or a truncation ends
the pass with a warning, keeping everything read before it. The summary (when the file has an intact one)
gives the topic list and message counts cheaply and lets the reader say how many messages were lost.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from ..errors import RecordingError
from .base import RawMessage, ReadLog, TopicInfo
from .messages import FileTypes, normalize_type

log = logging.getLogger(__name__)

# A chunk claiming more than this when decompressed is treated as corrupt rather than allocated.
_MAX_CHUNK_BYTES = 1 << 31


class McapSource:
    """One MCAP file. ``topics()`` uses the summary if readable, else a scan; ``iter_raw`` streams."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.log = ReadLog()
        self.size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            if f.read(8) != b"\x89MCAP0\r\n":
                raise RecordingError(f"{self.path} is not an MCAP file (bad magic); is it a ROS 1 .bag or .db3?")
        self._topics: dict[str, TopicInfo] | None = None
        self._summary_ok = False
        # Channels by id from the summary: lets messages be read even when the chunk declaring them is lost.
        self._summary_channels: dict[int, tuple[str, str, str]] = {}
        self._chunk_spans: dict[int, list[int]] = {}
        self._read_summary()

    def approx_span(self, topic: str) -> tuple[int, int] | None:
        """(first, last) log time (ns) of the chunks that hold ``topic``'s messages, from the summary's chunk index:
        what a progress bar needs, not the messages' exact times; None without an index."""
        ends = [self._chunk_spans[c] for c, (t, _, _) in self._summary_channels.items()
                if t == topic and c in self._chunk_spans]
        if not ends:
            return None
        return min(a for a, _ in ends), max(b for _, b in ends)

    def _read_summary(self) -> None:
        from mcap.reader import SeekingReader

        try:
            with open(self.path, "rb") as f:
                summary = SeekingReader(f, record_size_limit=self.size).get_summary()
        except Exception as exc:  # noqa: BLE001 - any parse failure of the footer means "no usable summary"
            log.info("%s: no readable summary (%s); scanning the file instead", self.path, exc)
            return
        if summary is None or not summary.channels:
            return
        # Each channel's time span from the chunk index (a chunk's range: for progress bars, not exact times).
        spans: dict[int, list[int]] = {}
        for ci in summary.chunk_indexes or []:
            for cid in ci.message_index_offsets or {}:
                a = spans.setdefault(cid, [ci.message_start_time, ci.message_end_time])
                a[0], a[1] = min(a[0], ci.message_start_time), max(a[1], ci.message_end_time)
        self._chunk_spans = spans
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        topics: dict[str, TopicInfo] = {}
        for cid, ch in summary.channels.items():
            sc = summary.schemas.get(ch.schema_id)
            name = normalize_type(sc.name) if sc else ""
            info = TopicInfo(
                ch.topic,
                name,
                counts.get(cid) if counts else None,
                sc.encoding if sc else "",
                sc.data.decode("utf-8", errors="replace") if sc else "",
                "cdr" if ch.message_encoding == "cdr" else ch.message_encoding,
            )
            self._summary_channels[cid] = (ch.topic, name, info.serialization)
            if ch.topic in topics:  # the same topic on several channels: add up
                old = topics[ch.topic]
                if old.messages is not None and info.messages is not None:
                    old.messages += info.messages
                continue
            topics[ch.topic] = info
        self._topics = topics
        self._summary_ok = True

    def topics(self) -> dict[str, TopicInfo]:
        if self._topics is None:
            # No index: one pass over the file finds the channels and counts what is readable.
            found: dict[str, TopicInfo] = {}
            counts: Counter[str] = Counter()
            # The scan's own damage reports are dropped: the real read reports the same damage once.
            real_log, self.log = self.log, ReadLog()
            try:
                for m in self._iter(None, found):
                    counts[m.topic] += 1
            finally:
                scan_log, self.log = self.log, real_log
            if not found:  # nothing readable: the scan's report is all there is to say
                for w in scan_log.warnings:
                    self.log.warn(w)
            # Without a summary the total per topic is unknown (None); only what is readable was counted.
            self._readable_counts = dict(counts)
            self._topics = found
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        return self._iter(topics, None)

    def _iter(self, topics: set[str] | None, found: dict[str, TopicInfo] | None) -> Iterator[RawMessage]:
        schemas: dict[int, Schema] = {}
        channels: dict[int, tuple[str, str, str]] = dict(self._summary_channels)
        read: Counter[str] = Counter()
        lost_chunks = 0
        orphans = [0]

        def handle(rec) -> Iterator[RawMessage]:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                sc = schemas.get(rec.schema_id)
                name = normalize_type(sc.name) if sc else ""
                ser = "cdr" if rec.message_encoding == "cdr" else rec.message_encoding
                channels[rec.id] = (rec.topic, name, ser)
                if found is not None and rec.topic not in found:
                    found[rec.topic] = TopicInfo(
                        rec.topic,
                        name,
                        None,
                        sc.encoding if sc else "",
                        sc.data.decode("utf-8", errors="replace") if sc else "",
                        ser,
                    )
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    orphans[0] += 1
                    return
                if topics is None or ch[0] in topics:
                    read[ch[0]] += 1
                    yield RawMessage(ch[0], ch[1], rec.log_time, rec.data, ch[2])

        with open(self.path, "rb") as f:
            records = StreamReader(f, emit_chunks=True, validate_crcs=True, record_size_limit=self.size).records
            while True:
                start = f.tell()
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except Exception as exc:  # noqa: BLE001 - the mcap library raises many types on corrupt bytes
                    before = sum(read.values())
                    salvaged: list = []
                    for r in _salvage_chunk(self.path, start, self.size, salvaged):
                        yield from handle(r)
                    self._stopped(exc, start, read, topics, sum(read.values()) - before, salvaged)
                    break
                if isinstance(rec, Chunk):
                    try:
                        if rec.uncompressed_size > _MAX_CHUNK_BYTES:
                            raise RecordingError(f"chunk claims {rec.uncompressed_size} bytes uncompressed")
                        inner = breakup_chunk(rec, validate_crc=True)
                    except Exception as exc:  # noqa: BLE001
                        lost_chunks += 1
                        self.log.warn(
                            f"{self.path.name}: skipped a corrupt chunk (messages logged "
                            f"{rec.message_start_time} .. {rec.message_end_time} ns are lost): {exc}"
                        )
                        continue
                    for r in inner:
                        yield from handle(r)
                else:
                    yield from handle(rec)
        for t, n in read.items():
            self.log.messages_read[t] = self.log.messages_read.get(t, 0) + n
        if orphans[0]:
            self.log.warn(f"{self.path.name}: {orphans[0]} messages of channels never declared (lost) were skipped")
        if lost_chunks or self.log.stopped_early:
            self._report_lost(read, topics)

    def _stopped(
        self, exc: Exception, pos: int, read: Counter, topics: set[str] | None, salvaged: int, why: list
    ) -> None:
        self.log.stopped_early = True
        extra = f", {salvaged} of them from the damaged chunk's readable start" if salvaged else ""
        self.log.warn(
            f"{self.path.name}: file is truncated or corrupt near byte {pos} of {self.size} "
            f"({type(exc).__name__}: {exc}); kept the {sum(read.values())} messages "
            f"{'' if topics is None else 'of ' + ', '.join(sorted(topics)) + ' '}read before it{extra}"
        )

    def _report_lost(self, read: Counter, topics: set[str] | None) -> None:
        if not self._summary_ok or self._topics is None:
            self.log.warn(f"{self.path.name}: no intact summary, so the number of lost messages is unknown")
            return
        for t, info in self._topics.items():
            if (topics is None or t in topics) and info.messages is not None and read.get(t, 0) < info.messages:
                lost = info.messages - read.get(t, 0)
                self.log.warn(f"{self.path.name}: topic {t}: {lost} of {info.messages} messages lost")

    def deserialize(self, m: RawMessage):
        """A message object (rosbags dataclass) for a non-event message, from its CDR bytes.

        Standard types use rosbags' ROS 2 definitions; others are registered from the file's own
        ``ros2msg`` schema text.
        """
        if m.serialization == "ros1":
            return self._deserialize_ros1(m)
        if getattr(self, "_types", None) is None:
            self._types = FileTypes(self.path.name)
        info = self.topics().get(m.topic)
        schema = None if info is None else (info.schema_encoding, info.schema_text)
        enc = info.schema_encoding if info else "missing"
        return self._types.deserialize(m, schema, f"with a {enc} schema that plsgraph cannot parse")

    def _deserialize_ros1(self, m: RawMessage):
        # MCAP with the ros1 profile: the schema is the bag-style concatenated ROS 1 definition.
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        if getattr(self, "_ts1", None) is None:
            self._ts1 = get_typestore(Stores.EMPTY)
        if m.msgtype not in self._ts1.types:
            info = self.topics().get(m.topic)
            if info is None or not info.schema_text:
                raise RecordingError(f"{self.path.name}: topic {m.topic} has no ROS 1 message definition")
            self._ts1.register(get_types_from_msg(info.schema_text, m.msgtype))
        return self._ts1.deserialize_ros1(bytes(m.data), m.msgtype)


def _salvage_chunk(path: Path, start: int, size: int, note: list) -> Iterator:
    """Records from the readable start of a chunk cut off at the end of the file (a recording that was
    interrupted): decompress what is there (uncompressed, zstd or lz4 streams give their prefix) and parse
    whole records until the first incomplete one."""
    import io
    import struct

    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode

    with open(path, "rb") as f:
        f.seek(start)
        head = f.read(9)
        if len(head) < 9 or head[0] != Opcode.CHUNK:
            return
        body = f.read(min(struct.unpack_from("<Q", head, 1)[0], size))
    try:
        _t0, _t1, usize, _crc, clen = struct.unpack_from("<QQQII", body, 0)
        pos = 32
        if clen > 64 or pos + clen + 8 > len(body):
            return
        comp = body[pos : pos + clen].decode()
        pos += clen + 8  # compression name, then the length of the (cut) records block
        data = body[pos:]
        if comp == "":
            raw = data
        elif comp == "zstd":
            import zstandard

            raw = zstandard.ZstdDecompressor().decompressobj().decompress(data)
        elif comp == "lz4":
            import lz4.frame

            raw = lz4.frame.LZ4FrameDecompressor().decompress(data)
        else:
            return
    except Exception:  # noqa: BLE001 - a damaged header or stream: nothing to salvage
        return
    raw = raw[: min(len(raw), usize)]
    readers = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read}
    p = 0
    while p + 9 <= len(raw):
        op = raw[p]
        n = struct.unpack_from("<Q", raw, p + 1)[0]
        if p + 9 + n > len(raw):
            break
        stream = ReadDataStream(io.BytesIO(raw[p + 9 : p + 9 + n]))
        try:
            if op == Opcode.MESSAGE:
                yield Message.read(stream, n)
            elif op in readers:
                yield readers[op](stream)
        except Exception:  # noqa: BLE001
            break
        note.append(op)
        p += 9 + n
