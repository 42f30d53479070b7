"""What every container reader hands out: topics, raw (still serialized) messages, decoded event blocks, and
the log of what went wrong while reading. Readers import this module; :mod:`plsgraph.io.source` picks the reader."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class DecodedEvents:
    """A block of events that an event-file container (AEDAT4, Metavision .raw) has already decoded.

    ``t`` int64 ns on the file's clock, ``x``/``y`` pixels, ``p`` polarity (+1 / -1 or bool), ``width`` x
    ``height`` the sensor as the file declares it, ``encoding`` the file's event format.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    width: int
    height: int
    encoding: str


@dataclass(frozen=True)
class RawMessage:
    """One message as stored: ``serialization`` is 'cdr' (ROS 2) or 'ros1'; event files (``serialization``
    'events') hand out :class:`DecodedEvents` as ``data``."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes | memoryview | DecodedEvents
    serialization: str


@dataclass
class TopicInfo:
    """A topic as the container declares it. ``messages`` is None when the file has no readable index."""

    topic: str
    msgtype: str
    messages: int | None = None
    schema_encoding: str = ""
    schema_text: str = ""
    serialization: str = "cdr"
    t_first_ns: int | None = None
    t_last_ns: int | None = None


@dataclass
class ReadLog:
    """What went wrong while reading: human-readable warnings and messages known (or suspected) lost."""

    warnings: list[str] = field(default_factory=list)
    messages_read: dict[str, int] = field(default_factory=dict)
    stopped_early: bool = False

    def warn(self, msg: str) -> None:
        if msg in self.warnings:  # a second pass over the same damage says nothing new
            return
        logging.getLogger("plsgraph.io").warning(msg)
        self.warnings.append(msg)


class Source(Protocol):
    path: Path
    log: ReadLog

    def topics(self) -> dict[str, TopicInfo]: ...

    def iter_raw(self, topics: set[str] | None = None) -> Iterator[RawMessage]: ...
