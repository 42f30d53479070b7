"""A small terminal progress bar. Library functions accept ``progress(done, total)`` callables."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

ProgressFn = Callable[[int, int], None]


class ProgressBar:
    """Draws ``label [#####.....] done/total eta`` on stderr, throttled, only when stderr is a terminal
    (or when ``force`` is set). Call ``close()`` when finished."""

    def __init__(self, label: str, stream=None, force: bool = False, min_interval_s: float = 0.1):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = force or getattr(self.stream, "isatty", lambda: False)()
        self.min_interval_s = min_interval_s
        self._t0 = time.monotonic()
        self._last = 0.0
        self._drawn = False

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if done < total and now - self._last < self.min_interval_s:
            return
        self._last = now
        frac = 0.0 if total <= 0 else min(1.0, done / total)
        width = 30
        bar = "#" * int(frac * width) + "." * (width - int(frac * width))
        elapsed = now - self._t0
        eta = f" eta {elapsed / frac - elapsed:5.1f}s" if 0 < frac < 1 else f" {elapsed:5.1f}s"
        self.stream.write(f"\r{self.label:<22} [{bar}] {done}/{total}{eta}")
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
