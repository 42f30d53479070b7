"""Logging helpers shared by the command line and the batch workers."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager


class OncePerMessage(logging.Filter):
    """Each warning once: several passes over one damaged file repeat theirs (with other counts in them)."""

    def __init__(self, label: str | None = None) -> None:
        super().__init__()
        self.seen: set[str] = set()
        self.label = label

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        decided = getattr(record, "_said_once", None)
        if decided is None:  # one record, several handlers (and filters): each gets the first answer
            decided = record._said_once = self._first(record)
        text = record.getMessage()
        if decided and self.label and not text.startswith(f"{self.label}:"):  # whose, among recordings run together
            record.msg, record.args = f"{self.label}: {text}", ()
        return decided

    def _first(self, record: logging.LogRecord) -> bool:
        key = re.sub(r"\d+", "#", record.getMessage())
        if key in self.seen:
            return False
        self.seen.add(key)
        return True


@contextmanager
def warnings_once(label: str | None = None) -> Iterator[None]:
    """Within the block, each warning reaches the root logger's handlers once (prefixed ``label: `` if given).

    A process without handlers (a batch worker) gets one that prints ``LEVEL message`` on stderr, as the command
    does; the filter is taken off again at the end, so a long-lived worker says the next recording's warnings."""
    root = logging.getLogger()
    if not root.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
        handler.setLevel(logging.WARNING)
        root.addHandler(handler)
    once = OncePerMessage(label)
    handlers = list(root.handlers)
    for h in handlers:
        h.addFilter(once)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(once)
