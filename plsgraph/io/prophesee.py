"""Prophesee Metavision ``.raw`` event files (EVT 2.0 and EVT 3.0), decoded with the project's codecs.

A ``.raw`` file is ASCII header lines beginning with ``%`` (``% evt 3.0``, ``% format EVT3;height=720;
width=1280``, ``% geometry 1280x720``, ... ``% end``) followed by the sensor's words exactly as the camera
sent them. It holds one event stream (plus trigger words) on the sensor's clock (µs since the camera
started), no host time and no odometry. The file is read in blocks of a few MB; each block becomes one
:class:`DecodedEvents` "message" of the single topic ``events``.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from .base import DecodedEvents, RawMessage, ReadLog, TopicInfo
from .event_codecs import Evt2Decoder, Evt3Decoder

log = logging.getLogger(__name__)

TOPIC = "events"
_MAX_HEADER = 1 << 16
# Bytes per block handed to the decoder (a multiple of both word sizes).
BLOCK_BYTES = 1 << 22
# Neither format declares the sensor in its words; 11-bit addresses bound it when the header does not.
_FALLBACK_SIZE = 2048
_FORMATS = {"evt2": ("EVT2", 4), "evt3": ("EVT3", 2)}


def parse_raw_header(data: bytes, name: str) -> tuple[dict[str, str], int]:
    """The ``% key value`` lines at the start of a .raw file as a dict, and the offset of the first binary byte."""
    fields: dict[str, str] = {}
    pos = 0
    while pos < len(data) and data[pos : pos + 1] == b"%":
        end = data.find(b"\n", pos)
        if end < 0:
            raise RecordingError(f"{name}: the .raw header is cut off (no end of line after byte {pos})")
        line = data[pos + 1 : end].decode("ascii", "replace").strip()
        pos = end + 1
        if line == "end":
            break
        key, _, value = line.partition(" ")
        if key:
            fields.setdefault(key.lower(), value.strip())
    return fields, pos


def raw_format(fields: dict[str, str], name: str) -> tuple[str, int, int, list[str]]:
    """(encoding 'evt2' / 'evt3', width, height, warnings) from the header fields."""
    warnings: list[str] = []
    fmt = fields.get("format", "")
    parts = [q.strip() for q in fmt.split(";") if q.strip()]
    enc = parts[0].lower() if parts else ""
    if not enc:
        v = fields.get("evt", "").strip()
        enc = {"2.0": "evt2", "3.0": "evt3", "2.1": "evt21"}.get(v, f"evt {v}" if v else "")
    if enc not in _FORMATS:
        what = f"the event format {enc!r}" if enc else "no '% evt' or '% format' line"
        raise RecordingError(
            f"{name}: the .raw header has {what}; plsgraph reads EVT 2.0 and EVT 3.0 .raw files "
            "(convert others with Metavision, e.g. record in EVT 3.0)"
        )
    opts = dict(q.split("=", 1) for q in parts[1:] if "=" in q)
    w = h = 0
    try:
        if "width" in opts and "height" in opts:
            w, h = int(opts["width"]), int(opts["height"])
        elif "geometry" in fields:
            m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", fields["geometry"])
            if m:
                w, h = int(m.group(1)), int(m.group(2))
        elif "width" in fields and "height" in fields:
            w, h = int(fields["width"]), int(fields["height"])
    except ValueError:
        w = h = 0
    if w <= 0 or h <= 0 or w > _FALLBACK_SIZE or h > _FALLBACK_SIZE:
        warnings.append(f"{name}: the .raw header states no usable sensor size; assuming {_FALLBACK_SIZE} x "
                        f"{_FALLBACK_SIZE}")
        w = h = _FALLBACK_SIZE
    return enc, w, h, warnings


class RawEventSource:
    """A Metavision ``.raw`` file as a source with one event topic, ``events``."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.log = ReadLog()
        with open(self.path, "rb") as f:
            head = f.read(_MAX_HEADER)
        if not head.startswith(b"%"):
            raise RecordingError(
                f"{self.path} is not a Metavision .raw file (it does not start with '%' header lines)"
            )
        self.header, self.data_offset = parse_raw_header(head, self.path.name)
        if self.data_offset >= _MAX_HEADER:
            raise RecordingError(f"{self.path}: the .raw header is longer than {_MAX_HEADER} bytes; corrupt file?")
        self.encoding, self.width, self.height, warns = raw_format(self.header, self.path.name)
        for w in warns:
            self.log.warn(w)
        self.msgtype = f"prophesee/raw/{self.encoding}"
        self._word = _FORMATS[self.encoding][1]
        size = self.path.stat().st_size - self.data_offset
        self._topics = {TOPIC: TopicInfo(TOPIC, self.msgtype, None, "", "", "events")}
        if size <= 0:
            self.log.warn(f"{self.path.name}: the .raw file has a header but no event data")

    def topics(self) -> dict[str, TopicInfo]:
        return self._topics

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        if topics is not None and TOPIC not in topics:
            return
        dec = (Evt2Decoder if self.encoding == "evt2" else Evt3Decoder)(self.width, self.height)
        blocks = 0
        with open(self.path, "rb") as f:
            f.seek(self.data_offset)
            while True:
                blob = f.read(BLOCK_BYTES)
                if not blob:
                    break
                t, x, y, p = dec.decode(blob)
                blocks += 1
                if t.size:
                    yield RawMessage(
                        TOPIC,
                        self.msgtype,
                        int(t[0]),
                        DecodedEvents(t, x, y, p, self.width, self.height, self.encoding),
                        "events",
                    )
        self.log.messages_read[TOPIC] = self.log.messages_read.get(TOPIC, 0) + blocks
        self._report(dec)

    def _report(self, dec) -> None:
        s, name = dec.stats, self.path.name
        if s.odd_bytes:
            self.log.warn(f"{name}: ends in {s.odd_bytes} bytes that are not a whole {self._word}-byte word: the file "
                          "is truncated")
        if s.unknown_codes:
            self.log.warn(f"{name}: ignored {s.unknown_codes} words with unknown type codes (corrupt data or "
                          "another event format than the header says)")
        if s.outside_sensor:
            self.log.warn(f"{name}: dropped {s.outside_sensor} events outside the {self.width} x {self.height} "
                          "sensor")
        if s.before_time:
            self.log.warn(f"{name}: dropped {s.before_time} events before the first time word")
        if s.time_backwards:
            self.log.warn(f"{name}: the time went backwards {s.time_backwards} times (corrupt data?)")
        if s.triggers:
            log.info("%s: %d external trigger words (not decoded)", name, s.triggers)


def read_raw_events(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All events of a .raw file as plain arrays (t ns, x, y, p), in file order; for benchmarks and tests."""
    src = RawEventSource(path)
    parts = [m.data for m in src.iter_raw()]
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.uint16), np.zeros(0, np.uint16), np.zeros(0, np.int8)
    return tuple(np.concatenate([getattr(d, k) for d in parts]) for k in "txyp")  # type: ignore[return-value]
