"""Recording readers and writers: MCAP, ROS 2 .db3, ROS 1 .bag; event decoding; inspection."""

from .events_reader import iter_event_chunks, read_events, read_events_with_log

__all__ = ["iter_event_chunks", "read_events", "read_events_with_log"]
