"""A small terminal progress bar. Library functions accept ``progress(done, total)`` callables."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

ProgressFn = Callable[[int, int], None]


#: The bar drawn last and not yet ended: a log record ends its line first (:func:`end_bar_line`).
_DRAWN: list = []


class ProgressBar:
    """Draws ``label [#####.....] done/total eta`` on stderr, throttled, only when stderr is a terminal
    (or when ``force`` is set). Call ``close()`` when finished.

    A count that starts again (a solver's next pass counting its iterations from 0) is shown as passes and steps
    with the time so far, without a bar or an estimate, which such a count cannot give."""

    def __init__(self, label: str, stream=None, force: bool = False, min_interval_s: float = 0.1):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = force or getattr(self.stream, "isatty", lambda: False)()
        self.min_interval_s = min_interval_s
        self._t0 = time.monotonic()
        self._last = 0.0
        self._drawn = False
        self._done = -1
        self._passes = 1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        if done < self._done:
            self._passes += 1
        self._done = done
        now = time.monotonic()
        if done < total and now - self._last < self.min_interval_s:
            return
        self._last = now
        elapsed = now - self._t0
        if self._passes > 1:
            self.stream.write(f"\r{self.label:<22} pass {self._passes}, step {done}  {elapsed:5.1f}s\033[K")
        else:
            frac = 0.0 if total <= 0 else min(1.0, done / total)
            width = 30
            bar = "#" * int(frac * width) + "." * (width - int(frac * width))
            eta = f" eta {elapsed / frac - elapsed:5.1f}s" if 0 < frac < 1 else f" {elapsed:5.1f}s"
            self.stream.write(f"\r{self.label:<22} [{bar}] {done}/{total}{eta}\033[K")
        self.stream.flush()
        self._drawn = True
        _DRAWN[:] = [self]

    def end_line(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    def close(self) -> None:
        self.end_line()
        if _DRAWN and _DRAWN[0] is self:
            _DRAWN.clear()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def end_bar_line(record: object = None) -> bool:
    """A logging filter: the progress bar being drawn ends its line before the record is written, so that a warning
    does not land at the end of the bar's line. Always lets the record through."""
    if _DRAWN:
        _DRAWN[0].end_line()
    return True
