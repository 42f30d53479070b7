"""The progress protocol of long library steps: a factory ``label -> context manager`` whose value is also a
``progress(done, total)`` callable. The library's default reports nothing; the command line passes bars."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

ProgressFactory = Callable[[str], Any]


class _Silent:
    def __call__(self, done: int, total: int) -> None:
        pass

    def __enter__(self) -> _Silent:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def no_progress(label: str) -> _Silent:
    """A progress factory that reports nothing."""
    return _Silent()
