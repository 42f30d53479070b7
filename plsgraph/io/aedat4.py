"""iniVation AEDAT4 files (DV software, DAVIS / DVXplorer cameras), read through the ``aedat`` package.

AEDAT4 is ``#!AER-DAT4.0\\r\\n``, a flatbuffer IOHeader (compression, stream descriptions as XML), then
packets (stream id, size, LZ4/ZSTD-compressed flatbuffer) and a file data table. The ``aedat`` package
(Rust, ~1 MB installed) decodes it to numpy; it is an optional dependency (``pip install 'plsgraph[dv]'``).
Event times are µs on the host clock (Unix epoch), turned into int64 ns. Every stream becomes a topic
named by its type (``events``, ``frame``, ``imus``, ``triggers``; ``events_2`` etc. when a type repeats);
only event streams are decoded, the others are counted. AEDAT4 holds no odometry.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from .base import DecodedEvents, RawMessage, ReadLog, TopicInfo

log = logging.getLogger(__name__)

MAGIC = b"#!AER-DAT4.0\r\n"
INSTALL_HINT = "pip install 'plsgraph[dv]'  (or: pip install aedat)"
# aedat's packet keys per stream type: the array (or dict) that holds each packet's time stamps.
_PAYLOAD = {"events": "events", "frame": "frame", "imus": "imus", "triggers": "triggers"}


def _aedat():
    try:
        import aedat
    except ImportError as exc:
        raise RecordingError(
            f"reading AEDAT4 files needs the optional package 'aedat', which is not installed; run: {INSTALL_HINT}"
        ) from exc
    return aedat


class Aedat4Source:
    """One AEDAT4 file as a source; event streams are decoded as they are read."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.log = ReadLog()
        with open(self.path, "rb") as f:
            magic = f.read(len(MAGIC))
        if magic != MAGIC:
            what = "an AEDAT 2/3 file" if magic.startswith(b"#!AER-DAT") else "not an AEDAT4 file"
            raise RecordingError(f"{self.path} is {what} (expected the header {MAGIC!r}); plsgraph reads AEDAT4")
        aedat = _aedat()
        try:
            streams = aedat.Decoder(str(self.path)).id_to_stream()
        except Exception as exc:  # noqa: BLE001 - aedat raises RuntimeError / OSError on a bad header
            raise RecordingError(
                f"{self.path}: the AEDAT4 header cannot be read ({type(exc).__name__}: {exc}); the file is "
                "truncated or corrupt"
            ) from exc
        self._streams: dict[int, tuple[str, str, int, int]] = {}  # id -> (topic, type, width, height)
        seen: Counter[str] = Counter()
        for sid in sorted(streams):
            d = streams[sid]
            typ = str(d.get("type", "unknown"))
            seen[typ] += 1
            topic = typ if seen[typ] == 1 else f"{typ}_{seen[typ]}"
            self._streams[sid] = (topic, typ, int(d.get("width", 0) or 0), int(d.get("height", 0) or 0))
        self._topics = {
            topic: TopicInfo(topic, f"aedat4/{typ}", None, "", "", "events" if typ == "events" else "aedat4")
            for topic, typ, _, _ in self._streams.values()
        }
        if not any(typ == "events" for _, typ, _, _ in self._streams.values()):
            self.log.warn(f"{self.path.name}: the AEDAT4 file declares no event stream")

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        aedat = _aedat()
        read: Counter[str] = Counter()
        it = iter(aedat.Decoder(str(self.path)))
        packets = 0
        while True:
            try:
                pk = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - truncated or corrupt packet (aedat: RuntimeError)
                self.log.stopped_early = True
                self.log.warn(
                    f"{self.path.name}: truncated or corrupt after packet {packets} ({type(exc).__name__}: {exc}); "
                    "kept everything before it"
                )
                break
            packets += 1
            sid = pk.get("stream_id")
            if sid not in self._streams:
                self.log.warn(f"{self.path.name}: packet {packets} names an undeclared stream {sid}; skipped")
                continue
            topic, typ, w, h = self._streams[sid]
            if topics is not None and topic not in topics:
                continue
            msg = self._message(pk, topic, typ, w, h)
            if msg is not None:
                read[topic] += 1
                yield msg
        for tp, n in read.items():
            self.log.messages_read[tp] = self.log.messages_read.get(tp, 0) + n

    def _message(self, pk: dict, topic: str, typ: str, w: int, h: int) -> RawMessage | None:
        payload = pk.get(_PAYLOAD.get(typ, typ))
        if typ == "events":
            if payload is None or payload.size == 0:
                return None
            t = payload["t"].astype(np.int64) * 1000
            ev = DecodedEvents(t, payload["x"], payload["y"], payload["on"], w, h, "aedat4")
            return RawMessage(topic, "aedat4/events", int(t[0]), ev, "events")
        # Other streams are only counted (and timed, for inspection).
        t_us = 0
        if isinstance(payload, dict):
            t_us = int(payload.get("t", 0))
        elif isinstance(payload, np.ndarray) and payload.size and payload.dtype.names and "t" in payload.dtype.names:
            t_us = int(payload["t"][0])
        return RawMessage(topic, f"aedat4/{typ}", t_us * 1000, b"", "aedat4")
