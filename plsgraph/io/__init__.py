"""Recording readers and writers: MCAP, ROS 2 .db3, ROS 1 .bag; event decoding; inspection."""

from .events_reader import iter_event_chunks, read_events, read_events_with_log
from .inspect import format_inspection, inspect_recording, render_inspection
from .recording import ImuMsgs, JointStates, OdometryMsgs, Recording, read_recording
from .writer import read_truth, write_recording, write_truth

__all__ = [
    "ImuMsgs",
    "format_inspection",
    "JointStates",
    "OdometryMsgs",
    "Recording",
    "inspect_recording",
    "iter_event_chunks",
    "read_events",
    "read_events_with_log",
    "read_recording",
    "read_truth",
    "render_inspection",
    "write_recording",
    "write_truth",
]
