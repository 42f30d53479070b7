"""Recording readers and writers: MCAP, ROS 2 .db3, ROS 1 .bag; event decoding; inspection.

The names below are imported on first use (PEP 562), so that ``plsgraph inspect`` loads the readers it needs and not
the writer, YAML or the camera models.
"""

from __future__ import annotations

import importlib

_WHERE = {
    "iter_event_chunks": "events_reader",
    "read_events": "events_reader",
    "read_events_with_log": "events_reader",
    "format_inspection": "inspect",
    "inspect_recording": "inspect",
    "render_inspection": "inspect",
    "ImuMsgs": "recording",
    "JointStates": "recording",
    "OdometryMsgs": "recording",
    "Recording": "recording",
    "read_recording": "recording",
    "read_truth": "writer",
    "write_recording": "writer",
    "write_truth": "writer",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
