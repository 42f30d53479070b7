"""What a recording holds: topics, message counts, time spans, and event statistics per event topic."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.progress import ProgressFactory, no_progress
from .events_reader import EVT3_GROUP_PACKETS, _TopicDecoder
from .messages import EVENT_TYPES
from .source import Source, open_source

#: Messages read between two calls of the progress callable.
PROGRESS_EVERY = 64


def inspect_recording(path: str | Path | Source, progress: ProgressFactory = no_progress,
                      count_events: bool = True) -> dict:
    """Summary of a recording in one streaming pass.

    Returns ``{"path", "topics": [{"topic", "type", "messages", "t_first_ns", "t_last_ns"} ...], "warnings"}``;
    event topics also have ``events``, ``events_on``, ``events_off``, ``width``, ``height`` and ``encoding``,
    with times from the decoded events. Other topics' times are the container's log times.
    ``progress`` (a factory, as the calibration's) reports the messages read against those the file's index lists,
    where it lists them for every topic (a file without one, e.g. cut short, reports nothing).
    ``count_events`` False (``plsgraph inspect --quick``) leaves the events undecoded, several times faster: event
    topics then have ``events``, ``events_on`` and ``events_off`` None and their times are the messages' log times.
    """
    src = path if hasattr(path, "iter_raw") else open_source(path)
    with progress("reading recording") as bar:
        return _inspect(src, bar, count_events)


def _inspect(src: Source, bar, count_events: bool = True) -> dict:
    topics = src.topics()
    counts = [info.messages for info in topics.values()]
    total = sum(counts) if counts and all(c is not None for c in counts) else 0
    done = 0
    rows: dict[str, dict] = {}
    decoders: dict[str, _TopicDecoder] = {}
    for name, info in sorted(topics.items()):
        row = {"topic": name, "type": info.msgtype, "messages": 0, "t_first_ns": None, "t_last_ns": None}
        if info.msgtype in EVENT_TYPES and count_events:
            row.update(events=0, events_on=0, events_off=0, width=None, height=None, encoding=None)
            decoders[name] = _TopicDecoder(src.log, f"{src.path.name}:{name}")
        elif info.msgtype in EVENT_TYPES:  # not decoded: the messages' log times, no counts
            row.update(events=None, events_on=None, events_off=None, width=None, height=None, encoding=None)
        rows[name] = row
    def add_events(row: dict, outs: list) -> None:
        for t, _x, _y, p in outs:
            if t.size == 0:
                continue
            on = int(np.count_nonzero(p > 0))
            row["events"] += int(t.size)
            row["events_on"] += on
            row["events_off"] += int(t.size) - on
            _span(row, int(t.min()), int(t.max()))

    groups: dict[str, list] = {name: [] for name in decoders}
    for m in src.iter_raw(None):
        row = rows.get(m.topic)
        if row is None:  # a topic the scan found only now (file without summary)
            row = rows[m.topic] = {"topic": m.topic, "type": m.msgtype, "messages": 0, "t_first_ns": None,
                                   "t_last_ns": None}
        row["messages"] += 1
        done += 1
        if total and not done % PROGRESS_EVERY:
            bar(min(done, total), total)
        dec = decoders.get(m.topic)
        if dec is None:
            _span(row, int(m.log_time_ns), int(m.log_time_ns))
            continue
        group = groups[m.topic]
        group.append(m)
        if len(group) >= EVT3_GROUP_PACKETS or dec.evt3_offset_ns is None:
            add_events(row, dec.decode_many(group))
            group.clear()
    for name, dec in decoders.items():
        add_events(rows[name], dec.decode_many(groups[name]))
        add_events(rows[name], dec.flush())
    if total:
        bar(total, total)
    for name, dec in decoders.items():
        dec.finish()
        rows[name].update(width=dec.width or None, height=dec.height or None, encoding=_encoding(dec, rows[name]))
    return {"path": str(src.path), "topics": list(rows.values()), "warnings": list(src.log.warnings)}


def _span(row: dict, t0: int, t1: int) -> None:
    row["t_first_ns"] = t0 if row["t_first_ns"] is None else min(row["t_first_ns"], t0)
    row["t_last_ns"] = t1 if row["t_last_ns"] is None else max(row["t_last_ns"], t1)


def _encoding(dec: _TopicDecoder, row: dict) -> str | None:
    if row["type"] == "dvs_msgs/msg/EventArray":
        return "dvs"
    return dec.encoding


def _fmt_time(t: int | None) -> str:
    return "-" if t is None else f"{t * 1e-9:.3f}"


def render_inspection(info: dict) -> str:
    """A human-readable table of :func:`inspect_recording`'s result."""
    head = ["topic", "type", "messages", "first [s]", "last [s]", "span [s]", "events", "on/off", "sensor", "encoding"]
    lines = []
    for r in info["topics"]:
        span = (
            "-" if r["t_first_ns"] is None else f"{(r['t_last_ns'] - r['t_first_ns']) * 1e-9:.3f}"
        )
        ev = r.get("events") is not None
        lines.append(
            [
                r["topic"],
                r["type"] or "?",
                str(r["messages"]),
                _fmt_time(r["t_first_ns"]),
                _fmt_time(r["t_last_ns"]),
                span,
                f"{r['events']:,}" if ev else ("not counted" if "events" in r else ""),
                f"{r['events_on']:,}/{r['events_off']:,}" if ev else "",
                f"{r['width']}x{r['height']}" if ev and r["width"] else "",
                r.get("encoding") or "",
            ]
        )
    widths = [max(len(h), *(len(row[i]) for row in lines)) if lines else len(h) for i, h in enumerate(head)]
    fmt = lambda row: "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
    out = [f"recording: {info['path']}", fmt(head), fmt(["-" * w for w in widths])]
    out += [fmt(r) for r in lines]
    if info.get("warnings"):
        out.append("warnings:")
        out += [f"  - {w}" for w in info["warnings"]]
    return "\n".join(out)


# The CLI's name for the table renderer.
format_inspection = render_inspection
