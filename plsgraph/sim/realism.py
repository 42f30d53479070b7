"""Real-world effects of the simulated recording: event sensor, robot, scene and driving style.

Every effect is a field of one of four frozen dataclasses (:class:`SensorEffects`, :class:`RobotEffects`,
:class:`SceneEffects`, :class:`MotionStyle`), grouped in :class:`Realism`. Each field documents its unit, its
default (a typical value of a real DAVIS346 on a Jackal-class robot indoors), the value that reproduces the
project's original ideal simulator, and the range a validation study draws it from (``field_specs()`` lists
them all; docs/simulation.md explains the physics).

How to choose:

* ``realistic()`` (the default of :func:`plsgraph.sim.robot.simulate_robot`): every effect at its default;
* ``ideal()``: the original simulator, bit for bit (its mild threshold mismatch, refractory period and
  background activity included: those are the event simulator's own defaults);
* ``draw_realism(rng)``: every effect drawn from its study range;
* ``only(effect, rng)``: the ideal simulator with one effect (a name of ``EFFECTS``) drawn from its range.

A field whose ideal value is ``None`` leaves the corresponding parameter of the event simulator, the renderer
or :func:`simulate_robot` as the caller gave it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.camera import CameraModel
from ..errors import InputError
from .events import EventSimParams
from .render import RenderParams

#: How a study draws a field from its range: uniform, log-uniform, integer (uniform), or one of a set.
DRAWS = ("uniform", "log", "int", "log_int", "choice")


def _fx(
    default: Any,
    *,
    effect: str,
    unit: str,
    doc: str,
    ideal: Any,
    range: tuple | None = None,  # noqa: A002 - the word the docs use
    draw: str = "uniform",
) -> Any:
    """A documented effect parameter (the metadata feeds ``field_specs``, ``draw_realism`` and ``only``)."""
    if draw not in DRAWS:
        raise ValueError(draw)
    return field(
        default=default,
        metadata={"effect": effect, "unit": unit, "doc": doc, "ideal": ideal, "range": range, "draw": draw},
    )


@dataclass(frozen=True)
class SensorEffects:
    """Event-sensor effects (DAVIS346-class pixel circuit and optics)."""

    latency_s: float | None = _fx(
        3e-4, effect="latency", unit="s", ideal=None, range=(1e-4, 1e-3), draw="log",
        doc="photoreceptor time constant at irradiance 1 (white paper in a lit room); scales as 1 / irradiance, "
        "so dim pixels respond later",
    )
    latency_max_s: float | None = _fx(
        0.02, effect="latency", unit="s", ideal=None,
        doc="upper limit of the time constant (very dark pixels)",
    )
    contrast_sigma: float | None = _fx(
        0.03, effect="threshold_mismatch", unit="log intensity", ideal=None, range=(0.01, 0.06),
        doc="per-pixel contrast threshold mismatch (standard deviation)",
    )
    refractory_s: float | None = _fx(
        2e-4, effect="refractory", unit="s", ideal=None, range=(1e-5, 1e-3), draw="log",
        doc="refractory period after each event of a pixel",
    )
    background_rate_hz: float | None = _fx(
        0.5, effect="background_activity", unit="Hz per pixel", ideal=None, range=(0.1, 2.0), draw="log",
        doc="background activity (junction leakage, shot noise): Poisson events of every pixel",
    )
    hot_pixels: int | None = _fx(
        20, effect="hot_pixels", unit="pixels", ideal=None, range=(5, 60), draw="int",
        doc="number of hot pixels",
    )
    hot_rate_min_hz: float | None = _fx(
        10.0, effect="hot_pixels", unit="Hz", ideal=None,
        doc="lowest event rate of a hot pixel (each draws its rate log-uniformly up to hot_rate_max_hz)",
    )
    hot_rate_max_hz: float | None = _fx(
        1000.0, effect="hot_pixels", unit="Hz", ideal=None,
        doc="highest event rate of a hot pixel",
    )
    flicker_depth: float | None = _fx(
        0.05, effect="flicker", unit="1", ideal=None, range=(0.0, 0.12),
        doc="mains flicker modulation depth m: the lighting multiplies by 1 + m sin(2 pi f t)",
    )
    flicker_hz: float | None = _fx(
        100.0, effect="flicker", unit="Hz", ideal=None, range=(100.0, 120.0), draw="choice",
        doc="flicker frequency f: twice the mains frequency (50 Hz or 60 Hz grids)",
    )
    timestamp_resolution_s: float | None = _fx(
        1e-6, effect="timestamp_quantization", unit="s", ideal=None,
        doc="event timestamp resolution (the sensor's microsecond counter)",
    )
    k1: float | None = _fx(
        -0.12, effect="lens_distortion", unit="1", ideal=None, range=(-0.3, 0.1),
        doc="radial distortion k1 (plumb_bob) of the simulated lens; the recording's camera info carries it",
    )
    k2: float | None = _fx(
        0.05, effect="lens_distortion", unit="1", ideal=None, range=(0.0, 0.1),
        doc="radial distortion k2 (plumb_bob)",
    )

    def event_params(self, base: EventSimParams) -> EventSimParams:
        """``base`` with these effects applied (fields that are None leave ``base`` as it is)."""
        pairs = {
            "latency_s": self.latency_s,
            "latency_max_s": self.latency_max_s,
            "contrast_sigma": self.contrast_sigma,
            "refractory_s": self.refractory_s,
            "noise_rate_hz": self.background_rate_hz,
            "hot_pixels": self.hot_pixels,
            "hot_rate_min_hz": self.hot_rate_min_hz,
            "hot_rate_max_hz": self.hot_rate_max_hz,
            "flicker_depth": self.flicker_depth,
            "flicker_hz": self.flicker_hz,
            "timestamp_resolution_s": self.timestamp_resolution_s,
        }
        changes = {k: v for k, v in pairs.items() if v is not None}
        return dataclasses.replace(base, **changes) if changes else base

    def camera(self, base: CameraModel) -> CameraModel:
        """``base`` with this lens distortion (k1, k2; tangential terms as in ``base``)."""
        if self.k1 is None and self.k2 is None:
            return base
        d = base.dist.copy()
        if self.k1 is not None:
            d[0] = self.k1
        if self.k2 is not None:
            d[1] = self.k2
        cam = CameraModel(base.width, base.height, base.K.copy(), d)
        # A real lens maps the image one to one; a polynomial that folds back before the corners cannot be
        # inverted there (the renderer's rays would be wrong).
        corners = np.array([[0.0, 0.0], [cam.width - 1, 0.0], [0.0, cam.height - 1], [cam.width - 1, cam.height - 1]])
        xn = cam.undistort_pixels(corners)
        back = cam.project(np.concatenate([xn, np.ones((4, 1))], axis=1))
        if not np.all(np.isfinite(back)) or np.abs(back - corners).max() > 0.01:
            raise InputError(
                f"lens distortion k1={d[0]:.3g}, k2={d[1]:.3g} folds back inside the image; raise k2 "
                "(plsgraph.sim.realism.invertible_k2 gives the smallest one that works)"
            )
        return cam


def invertible_k2(k1: float, k2: float, rho_max: float = 1.0, min_slope: float = 0.3) -> float:
    """The smallest k2' >= k2 (steps of 0.005) for which the radial distortion r (1 + k1 r^2 + k2' r^4) rises
    with slope >= ``min_slope`` until it reaches the distorted radius ``rho_max`` (normalized; 1.0 covers a
    DAVIS346 with a 4.5 mm lens, whose corners are at 0.89)."""
    r = np.linspace(0.0, 3.0, 3001)
    while True:
        rd = r * (1.0 + k1 * r**2 + k2 * r**4)
        slope = 1.0 + 3.0 * k1 * r**2 + 5.0 * k2 * r**4
        reach = np.flatnonzero(rd >= rho_max)
        if reach.size and np.all(slope[: reach[0] + 1] >= min_slope):
            return float(k2)
        k2 = round(k2 + 0.005, 6)


@dataclass(frozen=True)
class RobotEffects:
    """Wheel odometry of a skid-steer robot (Jackal class) and its timing."""

    wheel_radius_error: float = _fx(
        0.02, effect="wheel_radius", unit="1", ideal=0.0, range=(-0.05, 0.05),
        doc="relative error of the nominal wheel radius: true effective radius = nominal (1 + error)",
    )
    track_ratio: float = _fx(
        1.5, effect="skid_steer", unit="1", ideal=1.0, range=(1.2, 2.0),
        doc="effective track width / geometric track width: a skid-steer robot needs this much more wheel "
        "speed difference to turn",
    )
    slip_sigma: float = _fx(
        0.02, effect="wheel_slip", unit="1", ideal=0.0, range=(0.0, 0.05),
        doc="stationary std of each wheel's correlated scale error (Ornstein-Uhlenbeck) when driving straight",
    )
    slip_tau_s: float = _fx(
        0.5, effect="wheel_slip", unit="s", ideal=0.5, range=(0.2, 2.0), draw="log",
        doc="correlation time of the wheel scale error",
    )
    slip_turn_gain: float = _fx(
        2.0, effect="wheel_slip", unit="s/rad", ideal=0.0, range=(0.0, 4.0),
        doc="the slip std grows as slip_sigma (1 + gain |omega|) when turning",
    )
    encoder_ticks_per_rev: int | None = _fx(
        None, effect="encoder", unit="ticks/rev", ideal=None, range=(256, 16384), draw="log_int",
        doc="encoder resolution; None keeps simulate_robot's encoder_ticks_per_rev (4096)",
    )
    odom_rate_hz: float | None = _fx(
        None, effect="odom_rate", unit="Hz", ideal=None, range=(20.0, 100.0),
        doc="rate of the wheel joint-state messages; None keeps simulate_robot's odom_rate (50 Hz)",
    )
    odom_jitter_s: float = _fx(
        1e-3, effect="odom_jitter", unit="s", ideal=0.0, range=(0.0, 5e-3),
        doc="std of the odometry timestamp jitter (clipped at 0.4 of the sample period)",
    )
    odom_latency_s: float = _fx(
        0.0, effect="odom_latency", unit="s", ideal=0.0, range=(0.0, 0.03),
        doc="odometry stamps later than the motion they measure; adds to the time offset td an estimator sees",
    )


@dataclass(frozen=True)
class SceneEffects:
    """The board, its placement and print, the room behind it and its lighting."""

    board_distance_m: float = _fx(
        1.5, effect="board_distance", unit="m", ideal=1.5, range=(0.8, 2.5),
        doc="mean distance from the camera to the board centre",
    )
    board_yaw_deg: float = _fx(
        10.0, effect="board_yaw", unit="deg", ideal=0.0, range=(-25.0, 25.0),
        doc="board turned about its vertical axis away from facing the robot's mean heading",
    )
    board_scale: float = _fx(
        1.003, effect="board_scale", unit="1", ideal=1.0, range=(0.99, 1.01),
        doc="printed size / size in the board YAML (the pipeline gets the nominal YAML)",
    )
    background: float | None = _fx(
        0.35, effect="background_texture", unit="reflectance", ideal=None, range=(0.15, 0.6),
        doc="mean reflectance of the wall around the board",
    )
    background_texture: float | None = _fx(
        0.3, effect="background_texture", unit="1", ideal=None, range=(0.0, 0.6),
        doc="relative amplitude of the wall texture (it produces events too)",
    )
    texture_wavelength_m: float | None = _fx(
        0.08, effect="background_texture", unit="m", ideal=None, range=(0.03, 0.3), draw="log",
        doc="wavelength of the wall texture",
    )
    white: float | None = _fx(
        0.8, effect="lighting", unit="reflectance", ideal=None, range=(0.6, 0.95),
        doc="reflectance of the board's paper",
    )
    black: float | None = _fx(
        0.08, effect="lighting", unit="reflectance", ideal=None, range=(0.03, 0.2),
        doc="reflectance of the printed circles (white / black is the print contrast)",
    )
    illumination: float | None = _fx(
        1.0, effect="lighting", unit="1", ideal=None, range=(0.2, 2.0), draw="log",
        doc="overall brightness (1 = ordinary lit room); sets the pixel latency with latency_s",
    )

    floor_slope_deg: float = _fx(
        0.3, effect="floor", unit="deg", ideal=0.0, range=(0.0, 1.0),
        doc="RMS slope of the floor the robot drives on (a sum of three random waves): the base rolls and pitches "
        "by it while the wheel odometry stays planar",
    )
    floor_wavelength_m: float = _fx(
        1.5, effect="floor", unit="m", ideal=1.5, range=(0.5, 3.0), draw="log",
        doc="typical wavelength of the floor's undulation",
    )

    def render_params(self, base: RenderParams) -> RenderParams:
        """``base`` with this scene's reflectances, texture and lighting (None fields leave ``base`` as it is)."""
        names = ("background", "background_texture", "texture_wavelength_m", "white", "black", "illumination")
        changes = {k: getattr(self, k) for k in names if getattr(self, k) is not None}
        return dataclasses.replace(base, **changes) if changes else base


@dataclass(frozen=True)
class MotionStyle:
    """How the robot is driven: the original smooth sinusoids, or a person with a joystick."""

    joystick: bool = _fx(
        True, effect="joystick", unit="bool", ideal=False,
        doc="piecewise joystick segments (accelerate, hold, turn, stop, reverse), smoothed; the board leaves "
        "the image at times",
    )
    v_max_mps: float = _fx(
        0.4, effect="joystick", unit="m/s", ideal=0.4, range=(0.2, 0.7),
        doc="largest forward / backward speed the driver commands",
    )
    omega_max_rad_s: float = _fx(
        0.6, effect="joystick", unit="rad/s", ideal=0.6, range=(0.3, 1.2),
        doc="largest turn rate the driver commands",
    )
    segment_s: float = _fx(
        1.5, effect="joystick", unit="s", ideal=1.5, range=(0.7, 3.0),
        doc="mean duration of one joystick segment (each lasts 0.5 to 1.5 times this)",
    )
    smoothing_s: float = _fx(
        0.3, effect="joystick", unit="s", ideal=0.3, range=(0.1, 0.6),
        doc="time constant with which the robot follows a new command (hand, controller and inertia)",
    )
    look_away_prob: float = _fx(
        0.15, effect="joystick", unit="1", ideal=0.15, range=(0.0, 0.4),
        doc="chance that a turn segment swings far enough for the board to leave the image",
    )


GROUPS: dict[str, type] = {
    "sensor": SensorEffects,
    "robot": RobotEffects,
    "scene": SceneEffects,
    "motion": MotionStyle,
}


@dataclass(frozen=True)
class Realism:
    """All effects of one simulated recording; ``name`` says how they were chosen (ideal, realistic, ...)."""

    sensor: SensorEffects = field(default_factory=SensorEffects)
    robot: RobotEffects = field(default_factory=RobotEffects)
    scene: SceneEffects = field(default_factory=SceneEffects)
    motion: MotionStyle = field(default_factory=MotionStyle)
    name: str = "realistic"

    def event_params(self, base: EventSimParams | None = None) -> EventSimParams:
        """Event-simulator parameters: ``base`` (default EventSimParams()) with the sensor and scene effects."""
        base = base if base is not None else EventSimParams()
        p = self.sensor.event_params(base)
        render = self.scene.render_params(p.render)
        return p if render is p.render else dataclasses.replace(p, render=render)

    def to_dict(self) -> dict:
        """Plain nested dict (for the truth YAML): name and every field of every group."""
        out: dict[str, Any] = {"name": self.name}
        for g in GROUPS:
            out[g] = dataclasses.asdict(getattr(self, g))
        return out


def field_specs() -> list[dict]:
    """One row per effect parameter: group, name, effect, unit, default, ideal, range, draw, doc."""
    rows = []
    for g, cls in GROUPS.items():
        for f in dataclasses.fields(cls):
            m = f.metadata
            rows.append({"group": g, "name": f.name, "effect": m["effect"], "unit": m["unit"], "default": f.default,
                         "ideal": m["ideal"], "range": m["range"], "draw": m["draw"], "doc": m["doc"]})
    return rows


#: Names of the effects that ``only`` switches on one at a time, in the order of the field lists.
EFFECTS: tuple[str, ...] = tuple(dict.fromkeys(r["effect"] for r in field_specs()))


def effect_fields(effect: str) -> list[tuple[str, str]]:
    """(group, field name) pairs of one effect."""
    if effect not in EFFECTS:
        raise InputError(f"unknown effect {effect!r}; use one of {', '.join(EFFECTS)}")
    return [(r["group"], r["name"]) for r in field_specs() if r["effect"] == effect]


def _draw(spec: dict, rng: np.random.Generator) -> Any:
    lo, hi = spec["range"]
    d = spec["draw"]
    if d == "uniform":
        return float(rng.uniform(lo, hi))
    if d == "log":
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    if d == "int":
        return int(rng.integers(lo, hi + 1))
    if d == "log_int":
        return int(np.rint(np.exp(rng.uniform(np.log(lo), np.log(hi)))))
    return type(lo)(spec["range"][int(rng.integers(0, len(spec["range"])))])


def _middle(spec: dict) -> Any:
    """The centre of a range (geometric for log draws), for an effect switched on without a generator."""
    lo, hi = spec["range"]
    d = spec["draw"]
    if d == "choice":
        return lo
    mid = float(np.sqrt(lo * hi)) if d in ("log", "log_int") else 0.5 * (lo + hi)
    return int(round(mid)) if d in ("int", "log_int") else mid


def _build(values: dict[str, dict[str, Any]], name: str) -> Realism:
    groups = {g: GROUPS[g](**values[g]) for g in GROUPS}
    return Realism(**groups, name=name)


def _values(which: str) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {g: {} for g in GROUPS}
    for r in field_specs():
        out[r["group"]][r["name"]] = r["ideal"] if which == "ideal" else r["default"]
    return out


def ideal() -> Realism:
    """The original ideal simulator, reproduced exactly."""
    return _build(_values("ideal"), "ideal")


def realistic() -> Realism:
    """Every effect at its default (typical real) value."""
    return Realism()


def _switch_on(values: dict, specs: list[dict], rng: np.random.Generator) -> None:
    for r in specs:
        values[r["group"]][r["name"]] = _draw(r, rng) if r["range"] is not None else r["default"]


def _lens_fix(values: dict) -> None:
    s = values["sensor"]
    if s["k1"] is not None and s["k2"] is not None:
        s["k2"] = invertible_k2(s["k1"], s["k2"])


#: Effects added after the study's recordings were first drawn: drawn from a generator of their own (derived from,
#: but not advancing, the caller's), so that every other effect and whatever the caller draws next stay the same.
LATE_EFFECTS = ("floor",)


def _side_generator(rng: np.random.Generator) -> np.random.Generator:
    """A generator seeded from ``rng``'s state without drawing from it."""
    import hashlib

    digest = hashlib.sha256(repr(rng.bit_generator.state).encode()).hexdigest()
    return np.random.default_rng(int(digest[:16], 16))


def draw_realism(rng: np.random.Generator) -> Realism:
    """Every effect drawn from its study range (fields without a range take their default). A drawn k2 is
    raised where needed so that the lens maps the whole image one to one (``invertible_k2``)."""
    values = _values("ideal")
    specs = field_specs()
    _switch_on(values, [r for r in specs if r["effect"] not in LATE_EFFECTS], rng)
    _switch_on(values, [r for r in specs if r["effect"] in LATE_EFFECTS], _side_generator(rng))
    _lens_fix(values)
    return _build(values, "drawn")


def only(effect: str, rng: np.random.Generator | None = None) -> Realism:
    """The ideal simulator with one effect switched on: drawn from its range with ``rng``, else at its default."""
    effect_fields(effect)  # validates the name
    specs = [r for r in field_specs() if r["effect"] == effect]
    values = _values("ideal")
    if rng is None:
        for r in specs:
            values[r["group"]][r["name"]] = r["default"] if r["default"] is not None else _middle(r)
    else:
        _switch_on(values, specs, rng)
    _lens_fix(values)
    return _build(values, f"only:{effect}")


def resolve(realism: Realism | str) -> Realism:
    """A Realism from an instance or one of the names "realistic" and "ideal"."""
    if isinstance(realism, Realism):
        return realism
    if realism == "realistic":
        return realistic()
    if realism == "ideal":
        return ideal()
    raise InputError(f"realism must be a Realism, 'realistic' or 'ideal', got {realism!r}")
