"""What a user can set about one calibration, as values: one small dataclass per stage.

The library takes these (or the same names as keyword arguments of :func:`plsgraph.calibrate`); the command
line builds them from its flags. Every field is checked when the object is made, so a bad value fails before
any work, with a message naming the setting.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .errors import InputError

SURFACES = ("count", "polarity", "classic", "leaky")
CLOSED_FORM_METHODS = ("pls", "cca", "procrustes")
CLOCK_ALIGN = ("auto", "always", "never")
#: Widest fine time-offset search (--td-range, seconds); larger clock differences go through the clock alignment.
MAX_TD_RANGE_S = 10.0
WHEEL_ORDER = ("fix", "flag", "off")


def _positive(owner: str, name: str, v: Any) -> None:
    if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
        raise InputError(f"{name} ({owner}) must be a positive number, got {v!r}")


def _finite_or_none(owner: str, name: str, v: Any) -> None:
    if v is not None and (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)):
        raise InputError(f"{name} ({owner}) must be a finite number of metres, got {v!r}")


def _metres_within(owner: str, name: str, v: float | None, lo: float, hi: float, what: str) -> None:
    """A length the user typed, checked against what a ground robot can have (a value in cm or mm, or a sign slip,
    would otherwise be used as it is)."""
    if v is not None and not lo <= v <= hi:
        raise InputError(f"{name} ({owner}) {v:g} m is outside {lo:g} .. {hi:g} m, the range of {what}; lengths "
                         "are in metres")


@dataclass(frozen=True)
class InputOptions:
    """Where the data is: topics (by role: events, joints, odometry), an intrinsics file, a second file with the
    odometry (another clock), and how the two clocks are aligned.

    ``clock_align``: ``auto`` aligns coarsely when ``odometry_file`` is given or the camera and odometry spans
    overlap by less than half the camera's; ``always`` / ``never`` force it. ``clock_offset`` (s, t_odom = t_cam +
    clock_offset) skips the coarse search: the fine search then looks ±td_range around it.
    """

    topics: dict[str, str] = field(default_factory=dict)
    camera_info: Path | None = None
    odometry_file: Path | None = None
    clock_align: str = "auto"
    clock_offset: float | None = None

    def __post_init__(self) -> None:
        if self.camera_info is not None and not isinstance(self.camera_info, Path):
            object.__setattr__(self, "camera_info", Path(self.camera_info))
        if self.odometry_file is not None and not isinstance(self.odometry_file, Path):
            object.__setattr__(self, "odometry_file", Path(self.odometry_file))
        if self.clock_align not in CLOCK_ALIGN:
            raise InputError(f"clock_align must be one of {', '.join(CLOCK_ALIGN)}, got {self.clock_align!r}")
        if self.clock_offset is not None and (isinstance(self.clock_offset, bool)
                                              or not isinstance(self.clock_offset, int | float)
                                              or not math.isfinite(self.clock_offset)):
            raise InputError(f"clock_offset (--clock-offset) must be a finite number of seconds, got "
                             f"{self.clock_offset!r}")
        bad = set(self.topics) - {"events", "joints", "odometry"}
        if bad:
            raise InputError(f"topics: unknown role(s) {sorted(bad)}; use events, joints, odometry")


@dataclass(frozen=True)
class OdometryOptions:
    """The robot's nominal wheel geometry, which joints are its wheels, and what to do when the data say the
    wheels are swapped or one is reversed (``wheel_order``: ``fix`` corrects and says so, ``flag`` keeps them and
    flags the result, ``off`` does not check)."""

    wheel_radius: float = 0.098
    track_width: float = 0.37
    left_joint: str | None = None
    right_joint: str | None = None
    wheel_order: str = "fix"

    def __post_init__(self) -> None:
        _positive("--wheel-radius", "wheel_radius", self.wheel_radius)
        _positive("--track-width", "track_width", self.track_width)
        _metres_within("--wheel-radius", "wheel_radius", self.wheel_radius, 0.005, 2.0, "a ground robot's wheel radius")
        _metres_within("--track-width", "track_width", self.track_width, 0.05, 5.0,
                       "a ground robot's track width (the distance between its left and right wheels)")
        if self.left_joint is not None and self.left_joint == self.right_joint:
            raise InputError(f"--left-joint and --right-joint name the same joint ({self.left_joint!r}): give the "
                             "left and the right wheel's joint")
        if self.wheel_order not in WHEEL_ORDER:
            raise InputError(f"wheel_order must be one of {', '.join(WHEEL_ORDER)}, got {self.wheel_order!r}")


#: The slowest detection rate accepted: a window of 0.2 s already smears a board the robot drives past.
MIN_RATE_HZ = 5.0


@dataclass(frozen=True)
class FrontendOptions:
    """The event front end: the surface the board is detected on and the detection rate."""

    surface: str = "count"
    rate_hz: float = 30.0
    #: processes detecting streamed spans side by side (same result as one); 0: one per processor, at most 2
    frontend_workers: int = 0
    #: each window's look-back (s); None: one period of rate_hz (5 tau for the decaying surfaces)
    window_s: float | None = None
    #: the decaying surfaces' time constant (s; classic time surface and leaky only); None: their default
    tau_s: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.frontend_workers, bool) or not isinstance(self.frontend_workers, int) \
                or self.frontend_workers < 0:
            raise InputError(f"frontend_workers must be a whole number >= 0, got {self.frontend_workers!r}")
        if self.surface not in SURFACES:
            raise InputError(f"surface must be one of {', '.join(SURFACES)}, got {self.surface!r}")
        _positive("--rate", "rate_hz", self.rate_hz)
        if self.rate_hz < MIN_RATE_HZ:
            raise InputError(f"rate_hz (--rate) {self.rate_hz:g} Hz is below {MIN_RATE_HZ:g} Hz: windows of "
                             f"{1.0 / self.rate_hz:.2g} s smear a moving board into streaks; use 10-100 Hz")
        if self.rate_hz > 1000:
            raise InputError(f"rate_hz (--rate) {self.rate_hz:g} Hz is above 1000 Hz: windows that short hold too "
                             "few events to show the board; use 10-100 Hz")
        if self.window_s is not None:
            _positive("--window", "window_s", self.window_s)
            if not 1e-3 <= self.window_s <= 5.0:
                raise InputError(f"window_s (--window) {self.window_s:g} s is outside 0.001 .. 5 s: windows are "
                                 "seconds long at most (the board moves)")
        if self.tau_s is not None:
            _positive("--tau", "tau_s", self.tau_s)
            if self.surface not in ("classic", "leaky"):
                raise InputError(f"tau_s (--tau) is the decaying surfaces' time constant (--surface classic or "
                                 f"leaky); the {self.surface} surface has none")
            if self.tau_s > 5.0:
                raise InputError(f"tau_s (--tau) {self.tau_s:g} s is above 5 s")


@dataclass(frozen=True)
class ClosedFormSettings:
    """The closed form that seeds the refinement: its rotation solver and the time-offset search range."""

    method: str = "pls"
    td_range: float = 0.5

    def __post_init__(self) -> None:
        if self.method not in CLOSED_FORM_METHODS:
            raise InputError(f"method must be one of {', '.join(CLOSED_FORM_METHODS)}, got {self.method!r}")
        _positive("--td-range", "td_range", self.td_range)
        if self.td_range > MAX_TD_RANGE_S:
            raise InputError(f"td_range (--td-range) {self.td_range:g} s is above {MAX_TD_RANGE_S:g} s: the fine "
                             "search is for offsets of a fraction of a second; for clocks seconds to hours apart "
                             "give the odometry's file with --odometry, or --clock-align always (the clocks are "
                             "aligned first), or --clock-offset SECONDS")


@dataclass(frozen=True)
class RefineSettings:
    """User measurements the refinement can use: the camera height, or the board origin's height; and how well the
    focal length is known."""

    camera_height: float | None = None
    board_height: float | None = None
    #: How well the camera intrinsics' focal length is known (relative, one sigma): the lever arm along the optical
    #: axis moves with it (about 2 cm per 1 % for a board 2-3 m away), and the sigmas hold this much of it. 0: they
    #: hold none (the focal length taken as exact); the move per 1 % is reported either way.
    focal_sigma: float = 0.005

    def __post_init__(self) -> None:
        _finite_or_none("--camera-height", "camera_height", self.camera_height)
        _finite_or_none("--board-height", "board_height", self.board_height)
        if (isinstance(self.focal_sigma, bool) or not isinstance(self.focal_sigma, int | float)
                or not 0.0 <= self.focal_sigma <= 0.2):
            raise InputError(f"focal_sigma (--focal-sigma) must be a number from 0 to 0.2 (relative: 0.005 is 0.5 %), "
                             f"got {self.focal_sigma!r}")
        _metres_within("--camera-height", "camera_height", self.camera_height, -1.0, 3.0,
                       "a camera's height above a ground robot's base frame")
        _metres_within("--board-height", "board_height", self.board_height, 0.0, 5.0,
                       "a board origin's height above the floor")


@dataclass(frozen=True)
class MountOptions:
    """How the camera is mounted, as far as the user knows, and the frame names written into the robot files."""

    upside_down_camera: bool = False
    #: Said to be upright: a swapped pair of wheel joints is then corrected; unsaid, the camera is taken as upright
    #: for the checks, but a correction that only an upright camera justifies is flagged (wheel_order, pairing).
    upright_camera: bool = False
    parent_frame: str = "base_link"
    child_frame: str = "event_camera"

    @property
    def stated(self) -> bool:
        """Whether the user said how the camera is mounted (--upright-camera or --upside-down-camera)."""
        return bool(self.upright_camera or self.upside_down_camera)

    def __post_init__(self) -> None:
        for name in ("upright_camera", "upside_down_camera"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.upright_camera and self.upside_down_camera:
            raise InputError("upright_camera and upside_down_camera (--upright-camera, --upside-down-camera) "
                             "contradict each other; give one")
        for name in ("parent_frame", "child_frame"):
            v = getattr(self, name)
            if not isinstance(v, str) or not re.fullmatch(r"[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+)*", v):
                raise InputError(f"{name} (--{name.replace('_', '-')}) must be a frame name of letters, digits and "
                                 "_ . - with / between parts (not first or last: tf2 refuses a leading /), got "
                                 f"{v!r}")
        if self.parent_frame == self.child_frame:
            raise InputError(f"--parent-frame and --child-frame are the same frame ({self.parent_frame!r}): the robot "
                             "files would join a frame to itself, which tf2 refuses; name the camera's own frame")


@dataclass(frozen=True)
class CalibrationOptions:
    """Everything about one calibration run."""

    board: str = "acircles_4x11"
    inputs: InputOptions = field(default_factory=InputOptions)
    odometry: OdometryOptions = field(default_factory=OdometryOptions)
    frontend: FrontendOptions = field(default_factory=FrontendOptions)
    closed_form: ClosedFormSettings = field(default_factory=ClosedFormSettings)
    refine: RefineSettings = field(default_factory=RefineSettings)
    mount: MountOptions = field(default_factory=MountOptions)
    truth: Path | None = None

    SECTIONS = ("inputs", "odometry", "frontend", "closed_form", "refine", "mount")

    #: The command line's names for settings whose option names differ (``--rate`` is ``rate_hz``), taken as well.
    ALIASES = {"rate": "rate_hz", "window": "window_s", "tau": "tau_s", "odometry": "odometry_file"}
    #: ``--events-topic`` and its kind: a role of ``topics``.
    TOPIC_FLAGS = {"events_topic": "events", "joints_topic": "joints", "odom_topic": "odometry"}

    @classmethod
    def _canonical_names(cls, base: CalibrationOptions, kwargs: dict[str, Any]) -> dict[str, Any]:
        """``kwargs`` under the option names: dashes as underscores, the command line's names (ALIASES) and its topic
        flags (into ``topics``). A name said twice, in two spellings, is refused."""
        out: dict[str, Any] = {}
        roles: dict[str, Any] = {}
        for k, v in kwargs.items():
            name = k.replace("-", "_") if isinstance(k, str) else k
            if name in cls.TOPIC_FLAGS:
                roles[cls.TOPIC_FLAGS[name]] = v
                continue
            name = cls.ALIASES.get(name, name)
            if name in out:
                raise InputError(f"calibration option {name} is given twice (as {k} and another spelling)")
            out[name] = v
        if roles:
            topics = out.get("topics", dict(base.inputs.topics))
            if not isinstance(topics, dict):
                raise InputError(f"topics must map roles (events, joints, odometry) to topic names, got {topics!r}")
            out["topics"] = {**topics, **roles}
        return out

    @classmethod
    def option_names(cls) -> list[str]:
        """Every name :meth:`build` takes (its aliases aside)."""
        base = cls()
        return sorted({"board", "truth"} | {f.name for sec in cls.SECTIONS for f in fields(getattr(base, sec))})

    @classmethod
    def build(cls, base: CalibrationOptions | None = None, **kwargs: Any) -> CalibrationOptions:
        """Options from flat keyword arguments (``wheel_radius=0.1, surface="polarity", ...``): each name goes to
        the section that has it; unknown names are an error."""
        base = base or cls()
        kwargs = cls._canonical_names(base, kwargs)
        top = {k: kwargs.pop(k) for k in ("board", "truth") if k in kwargs}
        # The mount said here replaces the base's (a recording's options file over the batch's flags), unless this
        # call says both (a contradiction MountOptions refuses).
        said = [k for k in ("upright_camera", "upside_down_camera") if kwargs.get(k) is True]
        if len(said) == 1:
            kwargs.setdefault("upside_down_camera" if said[0] == "upright_camera" else "upright_camera", False)
        sections: dict[str, Any] = {}
        for sec in cls.SECTIONS:
            obj = getattr(base, sec)
            names = {f.name for f in fields(obj)}
            mine = {k: kwargs.pop(k) for k in list(kwargs) if k in names}
            if mine:
                sections[sec] = replace(obj, **mine)
        if kwargs:
            import difflib

            known = cls.option_names()
            hints = []
            for k in sorted(kwargs):
                near = difflib.get_close_matches(k, [*known, *cls.ALIASES, *cls.TOPIC_FLAGS], n=1, cutoff=0.6)
                hints.append(f"{k} (did you mean {near[0]}?)" if near else k)
            raise InputError(f"unknown calibration option(s): {', '.join(hints)}; the names are calibrate's options "
                             f"with underscores (rate, window, tau, events_topic, ... are taken too): "
                             f"{', '.join(known)}")
        if "truth" in top and top["truth"] is not None:
            top["truth"] = Path(top["truth"])
        return replace(base, **top, **sections)

    def to_dict(self) -> dict[str, Any]:
        """The options as report.json records them; file paths absolute (a report read elsewhere still names the
        files)."""
        board = self.board  # a bundled board's name as it is, a board file's path absolute
        if Path(board).is_file():
            board = str(Path(board).absolute())
        out: dict[str, Any] = {"board": board,
                               "truth": None if self.truth is None else str(Path(self.truth).absolute())}
        for sec in self.SECTIONS:
            obj = getattr(self, sec)
            out[sec] = {f.name: (str(v.absolute()) if isinstance(v := getattr(obj, f.name), Path) else v)
                        for f in fields(obj)}
        return out
