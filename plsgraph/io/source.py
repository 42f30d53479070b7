"""Common view of a recording container: topics and a stream of raw (still serialized) messages."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import RecordingError


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


def open_source(path: str | Path) -> Source:
    """Open an MCAP file, a ROS 1 ``.bag``, a ROS 2 ``.db3`` or a ROS 2 bag directory, an AEDAT4 file
    (``.aedat4``) or a Prophesee Metavision ``.raw`` file (EVT 2.0 / 3.0).

    A ``.db3`` without ``metadata.yaml`` beside it (or a bag folder without one) is read from its sqlite
    tables directly.
    """
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"recording {p} does not exist")
    if p.is_dir() or p.suffix in (".bag", ".db3"):
        from .db3_reader import Db3Source, bare_db3_files

        bare = bare_db3_files(p)
        if bare is not None:
            return Db3Source(bare, name=p)
        from .rosbags_reader import open_bag

        return open_bag(p)
    head = _head(p)
    if p.suffix == ".mcap" or head.startswith(b"\x89MCAP0\r\n"):
        from .mcap_reader import McapSource

        return McapSource(p)
    if p.suffix in (".aedat4", ".aedat") or head.startswith(b"#!AER-DAT"):
        from .aedat4 import Aedat4Source

        return Aedat4Source(p)
    if p.suffix == ".raw" or head.startswith(b"% "):
        from .prophesee import RawEventSource

        return RawEventSource(p)
    if p.suffix in (".hdf5", ".h5"):
        raise RecordingError(
            f"{p}: Metavision HDF5 event files are not supported (their ECF compression plugin has no maintained "
            "Python package); record RAW (.raw, Metavision's default) "
            "or write the events to a ROS bag or AEDAT4 instead"
        )
    raise RecordingError(
        f"cannot tell the container type of {p}: expected a .mcap file, a ROS 1 .bag, a ROS 2 .db3 "
        "or a ROS 2 bag directory, an AEDAT4 file (.aedat4) or a Prophesee .raw file"
    )


def _head(p: Path) -> bytes:
    with open(p, "rb") as f:
        return f.read(16)
