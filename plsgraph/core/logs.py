"""Logging helpers shared by the command line and the batch workers."""

from __future__ import annotations

import contextvars
import logging
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field


@dataclass
class _Said:
    """What one command or one recording has said so far, and whose it is."""

    label: str | None = None
    seen: set[str] = field(default_factory=set)


# Per thread (and per asyncio task): recordings calibrated in threads of one process (a Dask worker, a thread pool)
# each have their own, so one recording's warnings are neither dropped for another's nor labelled with its name.
_SAID: contextvars.ContextVar[_Said | None] = contextvars.ContextVar("plsgraph_warnings_said", default=None)
_INSTALL = threading.Lock()


class OncePerMessage(logging.Filter):
    """Each warning once within a :func:`warnings_once` block (several passes over one damaged file repeat theirs,
    with other counts in them), prefixed with the block's label; outside every block it lets everything through.

    One filter serves every block of the process: what was said is looked up in the emitting thread's context."""

    def filter(self, record: logging.LogRecord) -> bool:
        said = _SAID.get()
        if said is None or record.levelno < logging.WARNING:
            return True
        decided = getattr(record, "_said_once", None)
        if decided is None:  # one record, several handlers: each gets the first answer
            text = record.getMessage()
            key = re.sub(r"\d+", "#", text)
            decided = key not in said.seen
            said.seen.add(key)
            if decided and said.label and not text.startswith(f"{said.label}:"):  # whose, among recordings run together
                record.msg, record.args = f"{said.label}: {text}", ()
            record._said_once = decided
        return decided


_FILTER = OncePerMessage()


@contextmanager
def warnings_once(label: str | None = None) -> Iterator[None]:
    """Within the block, each warning reaches the root logger's handlers once (prefixed ``label: `` if given).

    A process without handlers (a batch worker) gets one that prints ``LEVEL message`` on stderr, as the command
    does. The filter stays on the handlers but does nothing outside a block, so a long-lived worker says the next
    recording's warnings, and blocks in other threads keep their own account."""
    root = logging.getLogger()
    with _INSTALL:
        if not root.handlers:
            handler = logging.StreamHandler()
            handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
            handler.setLevel(logging.WARNING)
            root.addHandler(handler)
        for h in root.handlers:
            if _FILTER not in h.filters:
                h.addFilter(_FILTER)
    token = _SAID.set(_Said(label))
    try:
        yield
    finally:
        _SAID.reset(token)
