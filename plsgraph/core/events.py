"""Event streams as four numpy arrays (struct of arrays), sorted by time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class EventStream:
    """Events of one sensor: ``t`` int64 ns, ``x``/``y`` uint16 pixels, ``p`` int8 polarity (+1 ON, -1 OFF).

    Construction validates (sorted time, coordinates inside the sensor, equal lengths) unless
    ``validate=False`` is given to :meth:`from_arrays` by code that has already checked.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        n = len(self.t)
        if not (len(self.x) == len(self.y) == len(self.p) == n):
            raise InputError(
                f"events: arrays differ in length (t {n}, x {len(self.x)}, y {len(self.y)}, p {len(self.p)})"
            )
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"events: sensor size must be positive, got {self.width} x {self.height}")

    @classmethod
    def from_arrays(
        cls,
        t: np.ndarray,
        x: np.ndarray,
        y: np.ndarray,
        p: np.ndarray,
        width: int,
        height: int,
        validate: bool = True,
    ) -> EventStream:
        """Build a stream, converting dtypes. Polarity may be bool, {0, 1} or {-1, +1}."""
        t = np.asarray(t)
        if t.dtype.kind == "f":
            if t.size and not np.all(np.isfinite(t)):
                raise InputError("events: timestamps contain NaN or inf")
            t = np.round(t).astype(np.int64)
        t = t.astype(np.int64, copy=False)
        p = np.asarray(p)
        if p.dtype == bool or (p.size and p.min() >= 0):
            p = np.where(p.astype(bool), 1, -1).astype(np.int8)
        else:
            p = np.sign(p).astype(np.int8)
        xs, ys = np.asarray(x), np.asarray(y)
        if validate and xs.size:
            if xs.min() < 0 or ys.min() < 0 or xs.max() >= width or ys.max() >= height:
                bad = int(np.count_nonzero((xs < 0) | (xs >= width) | (ys < 0) | (ys >= height)))
                raise InputError(f"events: {bad} events lie outside the {width} x {height} sensor")
        s = cls(t, xs.astype(np.uint16), ys.astype(np.uint16), p, int(width), int(height))
        if validate:
            s.check_sorted()
        return s

    @classmethod
    def empty(cls, width: int, height: int) -> EventStream:
        z = np.zeros(0)
        return cls(z.astype(np.int64), z.astype(np.uint16), z.astype(np.uint16), z.astype(np.int8), width, height)

    def check_sorted(self) -> None:
        if self.t.size > 1:
            # A comparison of neighbours (one byte per event), not np.diff (eight): the same test, a fraction of the
            # memory traffic on spans of ten million events.
            back = np.count_nonzero(self.t[1:] < self.t[:-1])
            if back:
                raise InputError(
                    f"events: {int(back)} timestamps go backwards; sort the stream "
                    "(EventStream.sorted()) or check the recording for clock resets"
                )

    def sorted(self) -> EventStream:
        """A copy sorted by time (stable, so simultaneous events keep their order)."""
        order = np.argsort(self.t, kind="stable")
        return EventStream(self.t[order], self.x[order], self.y[order], self.p[order], self.width, self.height)

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def t_first(self) -> int:
        return int(self.t[0]) if self.t.size else 0

    @property
    def t_last(self) -> int:
        return int(self.t[-1]) if self.t.size else 0

    @property
    def duration_s(self) -> float:
        return (self.t_last - self.t_first) * 1e-9

    def slice_index(self, i0: int, i1: int) -> EventStream:
        return EventStream(self.t[i0:i1], self.x[i0:i1], self.y[i0:i1], self.p[i0:i1], self.width, self.height)

    def slice_time(self, t0_ns: int, t1_ns: int) -> EventStream:
        """Events with t0 <= t < t1 (views, no copy)."""
        i0, i1 = np.searchsorted(self.t, [t0_ns, t1_ns], side="left")
        return self.slice_index(int(i0), int(i1))

    @staticmethod
    def concatenate(streams: list[EventStream]) -> EventStream:
        """Join streams of the same sensor in time order; they must not overlap in time."""
        if not streams:
            raise InputError("events: nothing to concatenate")
        w, h = streams[0].width, streams[0].height
        if any((s.width, s.height) != (w, h) for s in streams):
            raise InputError("events: cannot concatenate streams from sensors of different size")
        s = EventStream(
            np.concatenate([s.t for s in streams]),
            np.concatenate([s.x for s in streams]),
            np.concatenate([s.y for s in streams]),
            np.concatenate([s.p for s in streams]),
            w,
            h,
        )
        s.check_sorted()
        return s

    @property
    def n_on(self) -> int:
        return int(np.count_nonzero(self.p > 0))

    @property
    def n_off(self) -> int:
        return int(np.count_nonzero(self.p <= 0))
