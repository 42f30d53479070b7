"""What a user can set about one calibration, as values: one small dataclass per stage.

The library takes these (or the same names as keyword arguments of :func:`plsgraph.calibrate`); the command
line builds them from its flags. Every field is checked when the object is made, so a bad value fails before
any work, with a message naming the setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .errors import InputError

SURFACES = ("count", "polarity", "classic", "leaky")
CLOSED_FORM_METHODS = ("pls", "cca", "procrustes")


def _positive(owner: str, name: str, v: Any) -> None:
    if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
        raise InputError(f"{name} ({owner}) must be a positive number, got {v!r}")


def _finite_or_none(owner: str, name: str, v: Any) -> None:
    if v is not None and (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)):
        raise InputError(f"{name} ({owner}) must be a finite number of metres, got {v!r}")


@dataclass(frozen=True)
class InputOptions:
    """Where the data is: topics (by role: events, joints, odometry) and an intrinsics file."""

    topics: dict[str, str] = field(default_factory=dict)
    camera_info: Path | None = None

    def __post_init__(self) -> None:
        if self.camera_info is not None and not isinstance(self.camera_info, Path):
            object.__setattr__(self, "camera_info", Path(self.camera_info))
        bad = set(self.topics) - {"events", "joints", "odometry"}
        if bad:
            raise InputError(f"topics: unknown role(s) {sorted(bad)}; use events, joints, odometry")


@dataclass(frozen=True)
class OdometryOptions:
    """The robot's nominal wheel geometry and which joints are its wheels."""

    wheel_radius: float = 0.098
    track_width: float = 0.37
    left_joint: str | None = None
    right_joint: str | None = None

    def __post_init__(self) -> None:
        _positive("--wheel-radius", "wheel_radius", self.wheel_radius)
        _positive("--track-width", "track_width", self.track_width)


@dataclass(frozen=True)
class FrontendOptions:
    """The event front end: the surface the board is detected on and the detection rate."""

    surface: str = "count"
    rate_hz: float = 30.0

    def __post_init__(self) -> None:
        if self.surface not in SURFACES:
            raise InputError(f"surface must be one of {', '.join(SURFACES)}, got {self.surface!r}")
        _positive("--rate", "rate_hz", self.rate_hz)
        if self.rate_hz > 1000:
            raise InputError(f"rate_hz (--rate) {self.rate_hz:g} Hz is above 1000 Hz: windows that short hold too "
                             "few events to show the board; use 10-100 Hz")


@dataclass(frozen=True)
class ClosedFormSettings:
    """The closed form that seeds the refinement: its rotation solver and the time-offset search range."""

    method: str = "pls"
    td_range: float = 0.5

    def __post_init__(self) -> None:
        if self.method not in CLOSED_FORM_METHODS:
            raise InputError(f"method must be one of {', '.join(CLOSED_FORM_METHODS)}, got {self.method!r}")
        _positive("--td-range", "td_range", self.td_range)


@dataclass(frozen=True)
class RefineSettings:
    """User measurements the refinement can use: the camera height, or the board origin's height."""

    camera_height: float | None = None
    board_height: float | None = None
    upside_down: bool = False  # the camera is mounted upside down on purpose: the gate must not flag it

    def __post_init__(self) -> None:
        _finite_or_none("--camera-height", "camera_height", self.camera_height)
        _finite_or_none("--board-height", "board_height", self.board_height)


@dataclass(frozen=True)
class CalibrationOptions:
    """Everything about one calibration run."""

    board: str = "acircles_4x11"
    inputs: InputOptions = field(default_factory=InputOptions)
    odometry: OdometryOptions = field(default_factory=OdometryOptions)
    frontend: FrontendOptions = field(default_factory=FrontendOptions)
    closed_form: ClosedFormSettings = field(default_factory=ClosedFormSettings)
    refine: RefineSettings = field(default_factory=RefineSettings)
    truth: Path | None = None

    SECTIONS = ("inputs", "odometry", "frontend", "closed_form", "refine")

    @classmethod
    def build(cls, base: CalibrationOptions | None = None, **kwargs: Any) -> CalibrationOptions:
        """Options from flat keyword arguments (``wheel_radius=0.1, surface="polarity", ...``): each name goes to
        the section that has it; unknown names are an error."""
        base = base or cls()
        top = {k: kwargs.pop(k) for k in ("board", "truth") if k in kwargs}
        sections: dict[str, Any] = {}
        for sec in cls.SECTIONS:
            obj = getattr(base, sec)
            names = {f.name for f in fields(obj)}
            mine = {k: kwargs.pop(k) for k in list(kwargs) if k in names}
            if mine:
                sections[sec] = replace(obj, **mine)
        if kwargs:
            raise InputError(f"unknown calibration option(s): {', '.join(sorted(kwargs))}")
        if "truth" in top and top["truth"] is not None:
            top["truth"] = Path(top["truth"])
        return replace(base, **top, **sections)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"board": self.board, "truth": None if self.truth is None else str(self.truth)}
        for sec in self.SECTIONS:
            obj = getattr(self, sec)
            out[sec] = {f.name: (str(v) if isinstance(v := getattr(obj, f.name), Path) else v) for f in fields(obj)}
        return out
