"""Streaming event reader: event topics of any supported container, decoded in bulk with numpy."""

from __future__ import annotations

import copy
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.events import EventStream
from ..errors import RecordingError
from .cdr import CdrError
from .event_codecs import DecodeStats, Evt3Decoder, finish_events, make_decoder
from .messages import EVENT_ARRAY_TYPES, EVENT_PACKET_TYPES, EVENT_TYPES, parse_event_array, parse_event_packet
from .source import DecodedEvents, RawMessage, ReadLog, Source, TopicInfo, open_source

log = logging.getLogger(__name__)

# evt3 packets used to map the sensor clock onto the host clock.
_EVT3_CLOCK_PACKETS = 8
# evt3 packets decoded together once the clock is mapped: the decoder's state carries from packet to packet, so a
# group decodes to the same events as its packets one by one, with a tenth of the per-call overhead.
EVT3_GROUP_PACKETS = 32
#: After this many groups had to be decoded again packet by packet (a stream whose time steps back now and then),
#: the topic's packets are decoded one by one: grouping would only cost twice.
MAX_GROUP_FALLBACKS = 3
# 11-bit addresses (libcaer_cmp, evt3) bound the sensor when a message does not state its size.
_FALLBACK_SIZE = 2048


def describe_topics(topics: dict[str, TopicInfo], log: ReadLog | None = None) -> str:
    if not topics:
        why = f" ({log.warnings[0]})" if log is not None and log.warnings else ""
        return f"the file has no readable topics{why}"
    return "the file has: " + ", ".join(f"{t} [{i.msgtype or '?'}]" for t, i in sorted(topics.items()))


def pick_topic(src: Source, wanted_types: tuple[str, ...], topic: str | None, what: str) -> str:
    """The topic to read: ``topic`` if given (checked), else the topic of one of ``wanted_types`` (the busiest
    one, with a warning, if there are several)."""
    topics = src.topics()
    if topic is not None:
        if topic not in topics:
            raise RecordingError(f"{src.path.name}: no topic {topic!r}; {describe_topics(topics)}")
        if topics[topic].msgtype not in wanted_types:
            raise RecordingError(
                f"{src.path.name}: topic {topic} has type {topics[topic].msgtype or 'unknown'}, not an {what} type "
                f"plsgraph reads ({', '.join(wanted_types)}); {describe_topics(topics)}"
                if what[:1].lower() in "aeiou" else
                f"{src.path.name}: topic {topic} has type {topics[topic].msgtype or 'unknown'}, not a {what} type "
                f"plsgraph reads ({', '.join(wanted_types)}); {describe_topics(topics)}"
            )
        return topic
    cands = sorted(t for t, i in topics.items() if i.msgtype in wanted_types)
    if not cands:
        raise RecordingError(
            f"{src.path.name}: no {what} topic ({', '.join(wanted_types)}); {describe_topics(topics, src.log)}"
        )
    if len(cands) > 1:
        # The busiest topic is the usual choice (e.g. a camera plus a downsampled preview); say so.
        cands.sort(key=lambda t: -(topics[t].messages or 0))
        src.log.warn(f"{src.path.name}: several {what} topics ({', '.join(cands)}); using {cands[0]} (pass a topic)")
    return cands[0]


@dataclass
class _TopicDecoder:
    """Per-topic decoding state: the codec (stateful across packets) and clock bookkeeping."""

    src_log: ReadLog
    name: str
    decoder: object | None = None
    encoding: str | None = None
    width: int = 0
    height: int = 0
    evt3_offset_ns: int | None = None
    bad_messages: int = 0
    good_messages: int = 0
    backwards: int = 0  # messages that started before the previous one ended (stream not time-ordered)
    group_fallbacks: int = 0  # groups of evt3 packets decoded again one by one (their time stepped back)
    repeats: int = 0  # messages that were byte for byte the message before them (recorded twice): read once
    _last: object = None  # the previous message's bytes
    _pending: list = field(default_factory=list)  # evt3 packets waiting for the clock offset
    stats: DecodeStats = field(default_factory=DecodeStats)

    def decode(self, m: RawMessage) -> list[tuple[np.ndarray, ...]]:
        """Decoded (t, x, y, p) arrays ready to hand out: usually this message's, but evt3 holds back its
        first packets until the sensor clock is mapped (see :meth:`flush`)."""
        try:
            out = self._decode(m)
            self.good_messages += 1
            return out
        except CdrError as exc:
            self._bad(m, exc)
        except RecordingError as exc:
            # Unknown encoding, size change, big-endian flag: fatal on the first message (the file is not
            # what it claims), a damaged message once the topic has proven readable.
            if not self.good_messages:
                raise
            self._bad(m, exc)
        return []

    def decode_many(self, msgs: Iterable[RawMessage]) -> list[tuple[np.ndarray, ...]]:
        """:meth:`decode` of each message in turn, with the same events, stats and warnings; evt3 packets whose
        clock is mapped are decoded a group at a time (their words joined), which is several times faster.
        A group whose events come out of time order is decoded again packet by packet, so that a caller
        checking each message's order sees the messages."""
        out: list[tuple[np.ndarray, ...]] = []
        group: list = []
        for m in msgs:
            if self._repeat(m):
                continue
            blob = self._groupable(m)
            if blob is None:
                if group:
                    out += self._decode_group(group)
                    group = []
                out += self.decode(m)
                continue
            group.append(blob)
        if group:
            out += self._decode_group(group)
        return out

    def _repeat(self, m: RawMessage) -> bool:
        """Whether ``m`` is byte for byte the message before it (a recorder that wrote each message twice, a bag
        merged with itself): its events are in the stream already, and a stateful codec must not read them again."""
        data = m.data
        if isinstance(data, DecodedEvents):
            return False
        same = self._last is not None and len(data) == len(self._last) and data == self._last
        self._last = data
        if same:
            self.repeats += 1
        return same

    def _groupable(self, m: RawMessage):
        """The event words of an evt3 packet that can join a group, else None (decoded on its own)."""
        if (
            self.evt3_offset_ns is None
            or self.group_fallbacks >= MAX_GROUP_FALLBACKS
            or not isinstance(self.decoder, Evt3Decoder)
            or isinstance(m.data, DecodedEvents)
            or m.msgtype not in EVENT_PACKET_TYPES
        ):
            return None
        try:
            hdr, blob = parse_event_packet(m.data, m.serialization)
        except (CdrError, RecordingError):
            return None  # decode() reports it
        sized = hdr.width > 0 and hdr.height > 0  # a header without the size keeps the size taken before
        if hdr.encoding != self.encoding or (sized and (hdr.width, hdr.height) != (self.width, self.height)) \
                or len(blob) % 2:
            return None
        self.good_messages += 1
        return blob

    def _decode_group(self, blobs: list) -> list[tuple[np.ndarray, ...]]:
        if len(blobs) == 1:
            return self._mapped(self.decoder.decode(blobs[0]))
        before = copy.deepcopy(self.decoder)
        t, x, y, p = self.decoder.decode(b"".join(blobs))
        if t.size > 1 and np.any(t[1:] < t[:-1]):
            self.decoder = before  # packet by packet, as decode() would
            self.stats = before.stats
            self.group_fallbacks += 1
            return [q for b in blobs for q in self._mapped(self.decoder.decode(b))]
        return self._mapped((t, x, y, p))

    def _mapped(self, q: tuple[np.ndarray, ...]) -> list[tuple[np.ndarray, ...]]:
        t, x, y, p = q
        return [(t + self.evt3_offset_ns, x, y, p)] if t.size else []

    def flush(self) -> list[tuple[np.ndarray, ...]]:
        """Whatever is still held back at the end of the stream."""
        if not self._pending:
            return []
        return self._release()

    def _release(self) -> list[tuple[np.ndarray, ...]]:
        # Median over the held packets of (header stamp - first event's sensor time): the metavision
        # driver stamps a packet with the host time of its first event; the median ignores a first packet
        # stamped differently (seen in the event_camera_codecs evt3 sample).
        offs = np.array([stamp - int(t[0]) for stamp, (t, _, _, _) in self._pending], dtype=np.int64)
        # Integer lower median: float64 cannot hold epoch nanoseconds exactly.
        self.evt3_offset_ns = int(np.sort(offs)[(offs.size - 1) // 2])
        log.info("%s: evt3 sensor clock mapped to host time with offset %d ns (spread %d ns over %d packets)",
                 self.name, self.evt3_offset_ns, int(offs.max() - offs.min()), offs.size)
        out = [(t + self.evt3_offset_ns, x, y, p) for _, (t, x, y, p) in self._pending]
        self._pending = []
        return out

    def _bad(self, m: RawMessage, exc: Exception) -> None:
        self.bad_messages += 1
        if self.bad_messages <= 3:
            self.src_log.warn(f"{self.name}: skipped an unreadable event message at {m.log_time_ns} ns: {exc}")

    def _decode(self, m: RawMessage) -> list[tuple[np.ndarray, ...]]:
        if isinstance(m.data, DecodedEvents):  # an event file's block, decoded by its source
            d = m.data
            self._size(d.width, d.height)
            self.encoding = d.encoding
            return [finish_events(d.t, d.x, d.y, d.p, self.width, self.height, self.stats)]
        if m.msgtype in EVENT_PACKET_TYPES:
            return self._packet(m)
        _stamp, w, h, t, x, y, p = parse_event_array(m.data, m.serialization)
        self._size(w, h)
        # Same bounds check and dtypes as the packet codecs (a corrupt address must not pass silently).
        return [finish_events(t, x, y, p, self.width, self.height, self.stats)]

    def _size(self, w: int, h: int) -> None:
        if not self.width:
            if w <= 0 or h <= 0:
                self.src_log.warn(
                    f"{self.name}: event messages state no sensor size; assuming {_FALLBACK_SIZE} x {_FALLBACK_SIZE}"
                )
                w = h = _FALLBACK_SIZE
            self.width, self.height = int(w), int(h)
        elif (w, h) != (self.width, self.height) and w > 0:
            raise RecordingError(
                f"{self.name}: sensor size changes from {self.width} x {self.height} to {w} x {h} mid-recording"
            )

    def _packet(self, m: RawMessage):
        hdr, blob = parse_event_packet(m.data, m.serialization)
        self._size(hdr.width, hdr.height)
        if self.decoder is None or hdr.encoding != self.encoding:
            new = make_decoder(hdr.encoding, self.width, self.height)  # raises on an unknown encoding
            if self.decoder is not None:
                self.src_log.warn(f"{self.name}: encoding changes from {self.encoding} to {hdr.encoding}")
            self.decoder = new
            self.stats = self.decoder.stats
            self.encoding = hdr.encoding
        t, x, y, p = self.decoder.decode(blob, hdr.time_base)
        if not isinstance(self.decoder, Evt3Decoder) or t.size == 0:
            return [(t, x, y, p)]
        # evt3 carries the sensor clock only; one constant offset maps it onto the host clock, estimated
        # from the first few packets (held back meanwhile: a bounded number).
        if self.evt3_offset_ns is not None:
            return [(t + self.evt3_offset_ns, x, y, p)]
        self._pending.append((int(hdr.stamp_ns), (t, x, y, p)))
        return self._release() if len(self._pending) >= _EVT3_CLOCK_PACKETS else []

    def finish(self) -> None:
        s = self.stats
        if s.outside_sensor:
            self.src_log.warn(f"{self.name}: dropped {s.outside_sensor} events outside the sensor")
        if s.unknown_codes:
            self.src_log.warn(f"{self.name}: ignored {s.unknown_codes} event words with unknown codes")
        if s.odd_bytes:
            self.src_log.warn(f"{self.name}: {s.odd_bytes} trailing bytes did not form a whole event word")
        if self.bad_messages:
            self.src_log.warn(f"{self.name}: {self.bad_messages} event messages could not be read at all")
        if self.repeats:
            self.src_log.warn(f"{self.name}: {self.repeats} event messages were byte for byte the message before them "
                              "(the recording holds them twice); each was read once")


def _iter_chunks(
    src: Source, topic: str, dec: _TopicDecoder, chunk_events: int, t0: int | None, t1: int | None
) -> Iterator[EventStream]:
    parts: list[tuple[np.ndarray, ...]] = []
    n_parts = 0
    last_t = None
    backwards = 0
    unsorted_msgs = 0
    overlapped = False

    def flush(overlapped: bool) -> EventStream:
        s = EventStream(
            np.concatenate([q[0] for q in parts]),
            np.concatenate([q[1] for q in parts]),
            np.concatenate([q[2] for q in parts]),
            np.concatenate([q[3] for q in parts]),
            dec.width,
            dec.height,
        )
        # Messages that overlapped in time are put in order within the chunk (across chunks the warning
        # below is all that can be done without holding the stream).
        return s.sorted() if overlapped else s

    def decoded():
        group: list[RawMessage] = []
        for m in src.iter_raw({topic}):
            group.append(m)
            if len(group) >= EVT3_GROUP_PACKETS or dec.evt3_offset_ns is None:
                yield from dec.decode_many(group)
                group = []
        yield from dec.decode_many(group)
        yield from dec.flush()

    for t, x, y, p in decoded():
        if t.size == 0:
            continue
        if t.size > 1 and np.any(t[1:] < t[:-1]):
            unsorted_msgs += 1
            o = np.argsort(t, kind="stable")
            t, x, y, p = t[o], x[o], y[o], p[o]
        if last_t is not None and t[0] < last_t:
            backwards += 1
            overlapped = True
        last_t = int(t[-1]) if last_t is None else max(last_t, int(t[-1]))
        if t0 is not None or t1 is not None:
            i0 = 0 if t0 is None else int(np.searchsorted(t, t0, "left"))
            i1 = t.size if t1 is None else int(np.searchsorted(t, t1, "left"))
            if t1 is not None and t[0] >= t1 and not backwards:
                break  # time-ordered stream: nothing later can fall in the window
            t, x, y, p = t[i0:i1], x[i0:i1], y[i0:i1], p[i0:i1]
            if t.size == 0:
                continue
        parts.append((t, x, y, p))
        n_parts += t.size
        if n_parts >= chunk_events:
            yield flush(overlapped)
            parts, n_parts, overlapped = [], 0, False
    if parts:
        yield flush(overlapped)
    if unsorted_msgs:
        src.log.warn(f"{dec.name}: {unsorted_msgs} messages had events out of time order; sorted within each")
    if backwards:
        src.log.warn(f"{dec.name}: {backwards} messages start before the previous one ended (overlapping packets)")
    dec.backwards = backwards
    dec.finish()


def iter_event_chunks(
    path: str | Path | Source,
    topic: str | None = None,
    chunk_events: int = 1_000_000,
    t0: int | None = None,
    t1: int | None = None,
) -> Iterator[EventStream]:
    """Stream the events of one topic as :class:`EventStream` chunks of about ``chunk_events`` events.

    Memory stays bounded by the chunk size (plus one container chunk), whatever the recording's length.
    ``t0``/``t1`` (int ns, host clock) keep only events with t0 <= t < t1. Warnings (corrupt parts,
    dropped events) go to the source's ``log`` and to logging.
    """
    if chunk_events <= 0:
        raise RecordingError(f"chunk_events must be positive, got {chunk_events}")
    src = path if hasattr(path, "iter_raw") else open_source(path)
    name = pick_topic(src, EVENT_TYPES, topic, "event")
    dec = _TopicDecoder(src.log, f"{src.path.name}:{name}")
    yield from _iter_chunks(src, name, dec, int(chunk_events), t0, t1)


@dataclass(frozen=True)
class EventReadResult:
    events: EventStream
    topic: str
    encoding: str
    warnings: tuple[str, ...]


def read_events_with_log(
    path: str | Path | Source,
    topic: str | None = None,
    t0: int | None = None,
    t1: int | None = None,
) -> EventReadResult:
    """Like :func:`read_events`, also returning the topic, encoding and warnings."""
    src = path if hasattr(path, "iter_raw") else open_source(path)
    name = pick_topic(src, EVENT_TYPES, topic, "event")
    dec = _TopicDecoder(src.log, f"{src.path.name}:{name}")
    chunks = list(_iter_chunks(src, name, dec, 4_000_000, t0, t1))
    msgtype = src.topics()[name].msgtype
    enc = "dvs" if msgtype in EVENT_ARRAY_TYPES else (dec.encoding or "unknown")
    if not chunks and not dec.width:
        raise RecordingError(f"{src.path.name}: topic {name} holds no readable events")
    stream = join_chunks(chunks, dec, src.log, name)
    return EventReadResult(stream, name, enc, tuple(src.log.warnings))


def join_chunks(chunks: list[EventStream], dec: _TopicDecoder, rlog: ReadLog, name: str) -> EventStream:
    """One stream from the chunks of ``_iter_chunks``; sorted (with a warning) only if messages overlapped."""
    if not chunks:
        return EventStream.empty(dec.width, dec.height)
    # Each message was sorted on its own; with no message starting before its predecessor ended, the
    # chunks are already in order and a second full check would only cost time.
    if len(chunks) == 1:
        s = chunks[0]
    else:
        s = EventStream(
            np.concatenate([c.t for c in chunks]),
            np.concatenate([c.x for c in chunks]),
            np.concatenate([c.y for c in chunks]),
            np.concatenate([c.p for c in chunks]),
            dec.width,
            dec.height,
        )
    if dec.backwards:
        rlog.warn(f"{name}: events were not in time order across messages; sorted them (check the driver's clock)")
        s = s.sorted()
    return s


def read_events(
    path: str | Path | Source, topic: str | None = None, t0: int | None = None, t1: int | None = None
) -> EventStream:
    """All events of one event topic (auto-detected by type unless ``topic`` is given) as one stream.

    ``t0``/``t1`` (int ns) restrict to t0 <= t < t1. Supports dvs_msgs/EventArray and
    event_camera_msgs/EventPacket (libcaer_cmp, libcaer, evt3, mono) in MCAP, ROS 2 .db3 and ROS 1 .bag.
    Damage is logged as warnings; use :func:`read_events_with_log` to get them.
    """
    return read_events_with_log(path, topic, t0, t1).events
