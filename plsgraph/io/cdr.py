"""Minimal bounds-checked CDR (ROS 2 serialization) reader and writer.

Only what plsgraph's message parsers need: primitives, strings, and primitive sequences returned as numpy
views. Alignment is relative to the start of the payload after the 4-byte encapsulation header, as in
XCDR1 / ROS 2. Every length read from the bytes is checked against the buffer, so a corrupt message raises
:class:`CdrError` instead of reading garbage or allocating gigabytes.
"""

from __future__ import annotations

import struct

import numpy as np

from ..errors import RecordingError

_PRIMS = {
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "bool": ("?", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}


class CdrError(RecordingError):
    """A CDR payload is shorter than its own length fields claim, or has an unknown encapsulation."""


class CdrReader:
    """Cursor over one CDR-encoded message."""

    __slots__ = ("buf", "pos", "end", "_e")

    def __init__(self, data: bytes | memoryview) -> None:
        buf = memoryview(data).cast("B") if not isinstance(data, bytes) else data
        if len(buf) < 4:
            raise CdrError(f"CDR message of {len(buf)} bytes is shorter than its 4-byte header")
        kind = buf[1]
        # 0x00/0x01: plain CDR big/little endian; 0x02/0x03: PL_CDR (not used by ROS 2 messages).
        if buf[0] != 0 or kind not in (0, 1):
            raise CdrError(f"unsupported CDR encapsulation {bytes(buf[:2]).hex()}; expected plain CDR")
        self._e = "<" if kind == 1 else ">"
        self.buf = buf
        self.pos = 4
        self.end = len(buf)

    @property
    def little_endian(self) -> bool:
        return self._e == "<"

    def align(self, n: int) -> None:
        # Alignment counts from the byte after the encapsulation header.
        r = (self.pos - 4) % n
        if r:
            self.pos += n - r

    def _need(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > self.end:
            raise CdrError(
                f"CDR message truncated or corrupt: {what} needs {n} bytes at offset {self.pos}, "
                f"only {max(self.end - self.pos, 0)} left"
            )

    def prim(self, kind: str):
        code, size = _PRIMS[kind]
        self.align(size)
        self._need(size, kind)
        v = struct.unpack_from(self._e + code, self.buf, self.pos)[0]
        self.pos += size
        return v

    def uint32(self) -> int:
        return self.prim("uint32")

    def uint64(self) -> int:
        return self.prim("uint64")

    def float64(self) -> float:
        return self.prim("float64")

    def fixed(self, kind: str, n: int) -> np.ndarray:
        """``n`` consecutive primitives (fixed-size array) as a numpy array (copy, native byte order)."""
        code, size = _PRIMS[kind]
        if n:  # an empty array adds no alignment padding (as Fast-CDR and rosbags write it)
            self.align(size)
        self._need(n * size, f"{kind}[{n}]")
        dt = np.dtype(self._e + code) if kind != "bool" else np.dtype(bool)
        a = np.frombuffer(self.buf, dtype=dt, count=n, offset=self.pos)
        self.pos += n * size
        return a.astype(dt.newbyteorder("="))

    def sequence(self, kind: str) -> np.ndarray:
        n = self.uint32()
        _, size = _PRIMS[kind]
        # Guard before allocating: a flipped bit in the length must not ask for gigabytes.
        pad = (-(self.pos - 4)) % size if n else 0
        self._need(pad + n * size, f"sequence<{kind}> of {n}")
        return self.fixed(kind, n)

    def bytes_view(self) -> memoryview:
        """A ``sequence<uint8>`` as a zero-copy view into the message."""
        n = self.uint32()
        self._need(n, f"sequence<uint8> of {n}")
        v = memoryview(self.buf)[self.pos : self.pos + n]
        self.pos += n
        return v

    def string(self) -> str:
        n = self.uint32()
        self._need(n, f"string of {n}")
        raw = bytes(self.buf[self.pos : self.pos + n])
        self.pos += n
        # The length counts the terminating NUL; tolerate writers that omit it.
        return raw.rstrip(b"\x00").decode("utf-8", errors="replace")

    def string_sequence(self) -> list[str]:
        n = self.uint32()
        # Each string takes at least 4 bytes (its length), which bounds n before the loop.
        self._need(4 * n, f"sequence<string> of {n}")
        return [self.string() for _ in range(n)]

    def time(self) -> int:
        """builtin_interfaces/Time as int64 nanoseconds."""
        sec = self.prim("int32")
        nsec = self.prim("uint32")
        return sec * 1_000_000_000 + nsec

    def header(self) -> tuple[int, str]:
        """std_msgs/Header: (stamp ns, frame_id)."""
        t = self.time()
        return t, self.string()


class CdrWriter:
    """Little-endian CDR writer for the messages plsgraph writes."""

    def __init__(self) -> None:
        self.parts = bytearray(b"\x00\x01\x00\x00")

    def align(self, n: int) -> None:
        r = (len(self.parts) - 4) % n
        if r:
            self.parts += b"\x00" * (n - r)

    def prim(self, kind: str, v) -> None:
        code, size = _PRIMS[kind]
        self.align(size)
        self.parts += struct.pack("<" + code, v)

    def fixed(self, kind: str, a) -> None:
        code, size = _PRIMS[kind]
        a = np.ascontiguousarray(a, dtype=np.dtype("<" + code) if kind != "bool" else np.dtype(bool))
        if a.size:
            self.align(size)
        self.parts += a.tobytes()

    def sequence(self, kind: str, a) -> None:
        a = np.asarray(a)
        self.prim("uint32", a.size)
        self.fixed(kind, a.ravel())

    def raw_bytes(self, b: bytes) -> None:
        self.prim("uint32", len(b))
        self.parts += b

    def string(self, s: str) -> None:
        b = s.encode("utf-8") + b"\x00"
        self.prim("uint32", len(b))
        self.parts += b

    def string_sequence(self, items: list[str]) -> None:
        self.prim("uint32", len(items))
        for s in items:
            self.string(s)

    def time(self, t_ns: int) -> None:
        sec, nsec = divmod(int(t_ns), 1_000_000_000)
        self.prim("int32", sec)
        self.prim("uint32", nsec)

    def header(self, t_ns: int, frame_id: str) -> None:
        self.time(t_ns)
        self.string(frame_id)

    def getvalue(self) -> bytes:
        return bytes(self.parts)
