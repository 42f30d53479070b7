"""ESIM-style event simulator: render the board in log intensity along a camera trajectory and emit an event
whenever a pixel's log intensity moves a contrast threshold away from its reference level.

Model (per pixel, between two consecutive renders at t_a and t_b the log intensity is taken as linear):

* a pixel keeps a reference level ``ref``, initialised to the first render; an ON event fires each time
  L - ref reaches +C_on, an OFF event each time it reaches -C_off, and ``ref`` moves by that threshold, so a
  large change gives several events, spaced by linear interpolation of their crossing times in [t_a, t_b];
* thresholds differ per pixel (mismatch): C = N(C_nominal, sigma_C), clipped at ``contrast_min``, drawn once;
* refractory period: a crossing less than ``refractory_s`` after the pixel's previous event is dropped;
  its contrast is lost (``ref`` still moves), as a real pixel is blind while it resets;
* background-activity noise: Poisson events at ``noise_rate_hz`` per pixel, uniform in time and space, ON
  with probability ``noise_on_fraction``; they do not disturb the pixel's reference.

Real-sensor effects, all off by default (plsgraph.sim.realism switches them on; docs/simulation.md):

* photoreceptor bandwidth (``latency_s`` > 0): the pixel compares a first-order low-pass of its log
  intensity, whose time constant is ``latency_s / I`` (I the irradiance, 1 = white paper in a lit room),
  capped at ``latency_max_s``. A ramp comes out late by the time constant, so dim pixels fire later, and
  fast modulation (flicker) is attenuated in dim pixels. For input that is linear over a step the filter is
  integrated exactly; the time constant is taken from the intensity at the step's start;
* mains flicker (``flicker_depth`` m > 0): the lighting multiplies by 1 + m sin(2 pi ``flicker_hz`` t + phase);
  each render interval is split into sub-steps of at most 1 / (``flicker_steps_per_period`` f), the scene's
  intensity being interpolated linearly in between (no extra renders);
* hot pixels (``hot_pixels``): that many pixels fire Poisson events at rates drawn log-uniformly in
  [``hot_rate_min_hz``, ``hot_rate_max_hz``], each with its own ON share; they bypass the refractory period;
* timestamp quantization (``timestamp_resolution_s`` > 0): stamps are floored to multiples of it (1e-6 for a
  sensor's microsecond counter), in the absolute clock.
These effects draw their random numbers from a second generator, so with them off a seed gives exactly the
events it gave before they existed.

Render times are adaptive: the camera path is probed at ``probe_rate_hz``; on each probe interval the
wanted render rate is the image motion of the scene plane (measured on a grid of pixels, plus |rotation| f
for rays that miss the plane) divided by ``max_px_per_step``, clipped to [``min_rate_hz``, ``max_rate_hz``];
steps are placed where the integral of that rate crosses whole numbers. ``fixed_rate_hz`` replaces this
with a fixed rate. Work is chunked by ``chunk_steps`` render steps, so memory holds one frame pair, the
per-pixel state and the events.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core.board import Board
from ..core.camera import CameraModel
from ..core.events import EventStream
from ..core.geometry import interpolate_poses, inv_T
from ..errors import InputError
from .render import BoardRenderer, RenderParams

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EventSimParams:
    """Parameters of :func:`simulate_events` (see the module docstring and docs/surfaces_and_event_sim.md)."""

    contrast_on: float = 0.25
    contrast_off: float = 0.25
    contrast_sigma: float = 0.03  # per-pixel threshold mismatch (std, log units)
    contrast_min: float = 0.05
    refractory_s: float = 1e-4
    noise_rate_hz: float = 0.1  # background activity per pixel
    noise_on_fraction: float = 0.5
    max_px_per_step: float = 0.5
    probe_rate_hz: float = 200.0
    min_rate_hz: float = 50.0
    max_rate_hz: float = 20000.0
    fixed_rate_hz: float | None = None
    chunk_steps: int = 256
    render: RenderParams = field(default_factory=RenderParams)
    latency_s: float = 0.0  # photoreceptor time constant at irradiance 1; 0: no low-pass
    latency_max_s: float = 0.02
    hot_pixels: int = 0
    hot_rate_min_hz: float = 10.0
    hot_rate_max_hz: float = 1000.0
    flicker_depth: float = 0.0
    flicker_hz: float = 100.0
    flicker_steps_per_period: int = 12
    timestamp_resolution_s: float = 0.0  # 0: nanoseconds

    def __post_init__(self) -> None:
        positive = ("contrast_on", "contrast_off", "contrast_min", "max_px_per_step", "probe_rate_hz")
        for name in positive + ("min_rate_hz", "max_rate_hz"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"EventSimParams: {name} must be positive, got {v}")
        for name in ("contrast_sigma", "refractory_s", "noise_rate_hz", "latency_s", "flicker_depth",
                     "timestamp_resolution_s"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise InputError(f"EventSimParams: {name} must be >= 0, got {v}")
        if not 0.0 <= self.noise_on_fraction <= 1.0:
            raise InputError(f"EventSimParams: noise_on_fraction must be in [0, 1], got {self.noise_on_fraction}")
        if self.min_rate_hz > self.max_rate_hz:
            raise InputError("EventSimParams: min_rate_hz must not exceed max_rate_hz")
        if self.fixed_rate_hz is not None and not self.fixed_rate_hz > 0:
            raise InputError(f"EventSimParams: fixed_rate_hz must be positive, got {self.fixed_rate_hz}")
        if self.chunk_steps < 1:
            raise InputError(f"EventSimParams: chunk_steps must be >= 1, got {self.chunk_steps}")
        if not self.flicker_depth < 1.0:
            raise InputError(f"EventSimParams: flicker_depth must be < 1, got {self.flicker_depth}")
        for name in ("latency_max_s", "hot_rate_min_hz", "flicker_hz"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"EventSimParams: {name} must be positive, got {v}")
        if self.hot_rate_max_hz < self.hot_rate_min_hz:
            raise InputError("EventSimParams: hot_rate_max_hz must not be below hot_rate_min_hz")
        if self.hot_pixels < 0 or self.flicker_steps_per_period < 4:
            raise InputError("EventSimParams: hot_pixels must be >= 0 and flicker_steps_per_period >= 4")

    @property
    def photoreceptor(self) -> bool:
        """True if the pixel front end needs the intensity (latency or flicker), not just log intensity."""
        return self.latency_s > 0 or self.flicker_depth > 0


@dataclass(frozen=True)
class _Chunk:
    t: np.ndarray  # float64 seconds relative to the start
    pix: np.ndarray
    p: np.ndarray


def _check_trajectory(t_cam: np.ndarray, T_board_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_cam, dtype=np.float64).ravel()
    T = np.asarray(T_board_cam, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] != t.size:
        raise InputError(f"simulate_events: T_board_cam must be (n, 4, 4) with n = len(t_cam) = {t.size}")
    if t.size < 2:
        raise InputError("simulate_events: need at least two camera poses")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(T))):
        raise InputError("simulate_events: camera times or poses contain NaN or inf")
    if np.any(np.diff(t) <= 0):
        raise InputError("simulate_events: camera times must be strictly increasing")
    R = T[:, :3, :3]
    orth = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((orth > 1e-6) | (np.linalg.det(R) < 0))
    if bad.size:
        raise InputError(
            f"simulate_events: {bad.size} poses (first at index {bad[0]}) have no proper rotation; "
            "re-orthonormalize them (plsgraph.core.geometry.project_to_so3)"
        )
    return t, T


def render_times(
    t_cam: np.ndarray, T_board_cam: np.ndarray, camera: CameraModel, params: EventSimParams
) -> np.ndarray:
    """Render times (s, absolute, increasing, from t_cam[0] to t_cam[-1]) chosen as the module docstring says."""
    t, T = _check_trajectory(t_cam, T_board_cam)
    t0, t1 = t[0], t[-1]
    if params.fixed_rate_hz is not None:
        n = max(1, int(np.ceil((t1 - t0) * params.fixed_rate_hz)))
        return np.linspace(t0, t1, n + 1)
    n_probe = max(1, int(np.ceil((t1 - t0) * params.probe_rate_hz)))
    probe = np.linspace(t0, t1, n_probe + 1)
    Tp = interpolate_poses(probe, t, T)
    # Image motion of the scene plane z = 0 at a grid of pixels: back-project at the earlier pose,
    # project at the later one. Rays that miss the plane, or hit it very far away, are skipped.
    gu, gv = np.meshgrid(np.linspace(0, camera.width - 1, 9), np.linspace(0, camera.height - 1, 7))
    xn = camera.undistort_pixels(np.stack([gu.ravel(), gv.ravel()], axis=-1))
    rays = np.concatenate([xn, np.ones((xn.shape[0], 1))], axis=1)  # (g, 3) in the camera
    R, o = Tp[:-1, :3, :3], Tp[:-1, :3, 3]
    d = np.einsum("kij,gj->kgi", R, rays)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[:, None, 2] / d[:, :, 2]
    ok = np.isfinite(s) & (s > 0) & (s < 50.0)
    P = o[:, None, :] + np.where(ok, s, 0.0)[:, :, None] * d  # (k, g, 3) board points
    T_cam_board = inv_T(Tp[1:])
    Pc = np.einsum("kij,kgj->kgi", T_cam_board[:, :3, :3], P) + T_cam_board[:, None, :3, 3]
    ok &= Pc[:, :, 2] > 1e-3
    uv0 = np.broadcast_to(np.stack([gu.ravel(), gv.ravel()], axis=-1), Pc.shape[:2] + (2,))
    uv1 = camera.project(np.where(ok[:, :, None], Pc, [0.0, 0.0, 1.0]).reshape(-1, 3)).reshape(uv0.shape)
    disp = np.where(ok, np.linalg.norm(uv1 - uv0, axis=-1), 0.0)
    # Rotation alone moves every pixel, even those that see no plane: |omega| f dt bounds that part.
    rotvec_angle = np.arccos(np.clip((np.einsum("kii->k", R.transpose(0, 2, 1) @ Tp[1:, :3, :3]) - 1) / 2, -1, 1))
    disp_max = np.maximum(disp.max(axis=1), rotvec_angle * max(camera.fx, camera.fy))
    dt = np.diff(probe)
    # Wanted render rate on each probe interval; the step count N(t) = integral of the rate is piecewise
    # linear, and steps are placed where it crosses whole numbers (a slow stretch may span several probes).
    rate = np.clip(disp_max / params.max_px_per_step / dt, params.min_rate_hz, params.max_rate_hz)
    cum = np.concatenate([[0.0], np.cumsum(rate * dt)])
    n = max(1, int(np.ceil(cum[-1] - 1e-9)))
    return np.interp(np.linspace(0.0, cum[-1], n + 1), cum, probe)


def _pixel_thresholds(params: EventSimParams, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    c_on = params.contrast_on + params.contrast_sigma * rng.standard_normal(n)
    c_off = params.contrast_off + params.contrast_sigma * rng.standard_normal(n)
    # float32 like the rendered log intensity: the per-step comparison over all pixels is the hot loop.
    return (
        np.maximum(c_on, params.contrast_min).astype(np.float32),
        np.maximum(c_off, params.contrast_min).astype(np.float32),
    )


def _step_events(
    L0: np.ndarray,
    L1: np.ndarray,
    ta: float,
    tb: float,
    ref: np.ndarray,
    last_t: np.ndarray,
    c_on: np.ndarray,
    c_off: np.ndarray,
    refractory: float,
) -> _Chunk | None:
    """Events of one render step (log intensity L0 at ta to L1 at tb); updates ``ref`` and ``last_t`` in place."""
    dL = L1 - ref
    idx = np.flatnonzero((dL >= c_on) | (dL <= -c_off))
    if idx.size == 0:
        return None
    d = dL[idx]
    on = d > 0
    C = np.where(on, c_on[idx], c_off[idx]).astype(np.float64)
    sgn = np.where(on, 1.0, -1.0)
    n = np.floor(np.abs(d) / C).astype(np.int64)
    l0, l1, r = L0[idx].astype(np.float64), L1[idx].astype(np.float64), ref[idx].astype(np.float64)
    slope = (l1 - l0) / (tb - ta)  # log intensity per second; of sign sgn for these pixels ...
    # ... except where float32 rounding let the reference sit a threshold away from an unchanged pixel:
    # no crossing happened inside this step there, so it emits nothing (and no division by zero).
    flat = slope == 0.0
    if flat.any():
        n[flat] = 0
        slope[flat] = sgn[flat]
    # Crossing j (0-based) sits at level r + sgn C (j + 1), reached at ta + (level - l0) / slope.
    t_first = ta + (r + sgn * C - l0) / slope
    spacing = C / np.abs(slope)
    ref[idx] = r + sgn * C * n  # every crossing moves the reference, emitted or not
    pix = np.repeat(idx, n)
    j = np.arange(pix.size) - np.repeat(np.cumsum(n) - n, n)
    t_ev = np.repeat(t_first, n) + j * np.repeat(spacing, n)
    if refractory > 0:
        # First crossing past the pixel's refractory time, then every ceil(refractory / spacing) crossings.
        j0 = np.maximum(0.0, np.ceil((last_t[idx] + refractory - t_first) / spacing - 1e-9))
        stride = np.maximum(1.0, np.ceil(refractory / spacing - 1e-9))
        jj = j - np.repeat(j0, n).astype(np.int64)
        keep = (jj >= 0) & (jj % np.repeat(stride, n).astype(np.int64) == 0)
        pix, t_ev, j = pix[keep], t_ev[keep], j[keep]
        p_ev = np.repeat(sgn, n)[keep]
    else:
        p_ev = np.repeat(sgn, n)
    if pix.size == 0:
        return None
    np.clip(t_ev, ta, tb, out=t_ev)  # guard against rounding at the interval ends
    np.maximum.at(last_t, pix, t_ev)
    return _Chunk(t_ev, pix, p_ev.astype(np.int8))


def _noise(
    t_a: float, t_b: float, n_pixels: int, params: EventSimParams, rng: np.random.Generator
) -> _Chunk | None:
    lam = params.noise_rate_hz * n_pixels * (t_b - t_a)
    if lam <= 0:
        return None
    k = int(rng.poisson(lam))
    if k == 0:
        return None
    t = rng.uniform(t_a, t_b, k)
    pix = rng.integers(0, n_pixels, k)
    p = np.where(rng.random(k) < params.noise_on_fraction, 1, -1).astype(np.int8)
    return _Chunk(t, pix, p)


class _Photoreceptor:
    """Pixel front end with photoreceptor bandwidth and flickering light (see the module docstring).

    ``y`` is the low-passed log intensity the change detector compares; ``advance`` moves it over one render
    interval and returns the (y0, y1, ta, tb) sub-steps to feed to the change detector.
    """

    def __init__(self, I0: np.ndarray, params: EventSimParams, rng: np.random.Generator):
        self.p = params
        self.eps = np.float32(params.render.log_eps)
        self.phase = float(rng.uniform(0.0, 2 * np.pi)) if params.flicker_depth > 0 else 0.0
        self.I = I0.astype(np.float32)
        self.L = self._log(self.I, 0.0)  # unfiltered input at the last sub-step
        self.y = self.L.copy()  # the filter starts in steady state

    def _log(self, I: np.ndarray, t: float) -> np.ndarray:
        p = self.p
        if p.flicker_depth > 0:
            g = 1.0 + p.flicker_depth * np.sin(2 * np.pi * p.flicker_hz * t + self.phase)
            return np.log(I * np.float32(g) + self.eps)
        return np.log(I + self.eps)

    def advance(self, I1: np.ndarray, ta: float, tb: float) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
        p = self.p
        n = 1
        if p.flicker_depth > 0:
            n = max(1, int(np.ceil((tb - ta) * p.flicker_hz * p.flicker_steps_per_period - 1e-9)))
        h = (tb - ta) / n
        if p.latency_s > 0:
            # Time constant from the irradiance at the interval's start; the exact response of a first-order
            # low-pass to input that is linear over h: y1 = L1 + (y0 - L0) a - (L1 - L0) (tau / h) (1 - a).
            tau = np.float32(p.latency_s) / np.maximum(self.I, np.float32(1e-6))
            np.minimum(tau, np.float32(p.latency_max_s), out=tau)
            x = np.float32(-h) / tau
            a = np.exp(x)
            c = -np.expm1(x) * tau / np.float32(h)
        I0 = self.I
        out = []
        t_prev = ta
        for j in range(1, n + 1):
            t = ta + j * h if j < n else tb
            I = I1 if j == n else I0 + (I1 - I0) * np.float32(j / n)
            L = self._log(I, t)
            if p.latency_s > 0:
                y = L + (self.y - self.L) * a - (L - self.L) * c
            else:
                y = L
            out.append((self.y, y, t_prev, t))
            self.y, self.L, t_prev = y, L, t
        self.I = I1.astype(np.float32, copy=False)
        return out


class _HotPixels:
    """Pixels that fire Poisson events at their own high rate, whatever they see."""

    def __init__(self, params: EventSimParams, n_pix: int, rng: np.random.Generator):
        k = min(int(params.hot_pixels), n_pix)
        self.pix = rng.choice(n_pix, k, replace=False)
        lo, hi = np.log(params.hot_rate_min_hz), np.log(params.hot_rate_max_hz)
        self.rate = np.exp(rng.uniform(lo, hi, k))
        self.on_share = rng.uniform(0.0, 1.0, k)

    def events(self, ta: float, tb: float, rng: np.random.Generator) -> _Chunk:
        counts = rng.poisson(self.rate * (tb - ta))
        pix = np.repeat(self.pix, counts)
        t = rng.uniform(ta, tb, pix.size)
        on = rng.random(pix.size) < np.repeat(self.on_share, counts)
        return _Chunk(t, pix, np.where(on, 1, -1).astype(np.int8))


def simulate_events(
    t_cam: np.ndarray,
    T_board_cam: np.ndarray,
    camera: CameraModel,
    board: Board,
    params: EventSimParams | None = None,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> EventStream:
    """Events (t in int64 ns, same clock as ``t_cam``) of ``camera`` moving along T_board_cam(t_cam).

    ``t_cam`` (n,) seconds, strictly increasing; ``T_board_cam`` (n, 4, 4) camera poses in the board frame,
    interpolated in between (slerp + linear). Deterministic for a given ``seed``.
    """
    params = params or EventSimParams()
    t, T = _check_trajectory(t_cam, T_board_cam)
    rng = np.random.default_rng(seed)
    renderer = BoardRenderer(camera, board, params.render)
    n_pix = camera.width * camera.height
    # Work in seconds relative to the first stamp: absolute epoch seconds in float64 lose sub-microsecond detail.
    t_origin_ns = int(round(t[0] * 1e9))
    times = render_times(t, T, camera, params)
    rel = times - t[0]
    c_on, c_off = _pixel_thresholds(params, n_pix, rng)
    n_steps = times.size - 1
    log.info("simulating events: %d renders over %.3f s (%.0f Hz mean)", times.size, rel[-1], n_steps / rel[-1])
    if not _board_ever_visible(T, camera, board):
        log.warning("simulate_events: the board is never in view along this trajectory; only the wall gives events")
    # Real-sensor effects draw from their own generator: with them off, ``rng`` gives what it always gave.
    rng_fx = np.random.default_rng([seed, 1])
    front = _Photoreceptor(renderer.intensity(T[0]).ravel(), params, rng_fx) if params.photoreceptor else None
    L_prev = front.y if front is not None else renderer.log_intensity(T[0]).ravel()
    ref = L_prev.copy()
    last_t = np.full(n_pix, -np.inf)
    hot = _HotPixels(params, n_pix, rng_fx) if params.hot_pixels > 0 else None
    chunks: list[EventStream] = []
    for c0 in range(0, n_steps, params.chunk_steps):
        c1 = min(n_steps, c0 + params.chunk_steps)
        poses = interpolate_poses(times[c0 + 1 : c1 + 1], t, T)
        parts: list[_Chunk] = []
        for k in range(c1 - c0):
            ta, tb = rel[c0 + k], rel[c0 + k + 1]
            if front is None:
                L = renderer.log_intensity(poses[k]).ravel()
                sub = [(L_prev, L, ta, tb)]
                L_prev = L
            else:
                sub = front.advance(renderer.intensity(poses[k]).ravel(), ta, tb)
            for y0, y1, sa, sb in sub:
                ev = _step_events(y0, y1, sa, sb, ref, last_t, c_on, c_off, params.refractory_s)
                if ev is not None:
                    parts.append(ev)
        noise = _noise(rel[c0], rel[c1], n_pix, params, rng)
        if noise is not None:
            parts.append(noise)
        if hot is not None:
            hot_ev = hot.events(rel[c0], rel[c1], rng_fx)
            if hot_ev.t.size:
                parts.append(hot_ev)
        if parts:
            chunks.append(_to_stream(parts, t_origin_ns, camera, params.timestamp_resolution_s))
        if progress is not None:
            progress(c1, n_steps)
    if not chunks:
        return EventStream.empty(camera.width, camera.height)
    out = EventStream.concatenate(chunks)
    log.info("simulated %d events (%.1f%% ON)", len(out), 100.0 * out.n_on / max(1, len(out)))
    return out


def _board_ever_visible(T_board_cam: np.ndarray, camera: CameraModel, board: Board) -> bool:
    """True if some board point projects into the image, in front of the camera, at some given pose."""
    T_cam_board = inv_T(T_board_cam)
    P = np.einsum("kij,nj->kni", T_cam_board[:, :3, :3], board.points) + T_cam_board[:, None, :3, 3]
    front = P[:, :, 2] > 1e-3
    if not front.any():
        return False
    uv = camera.project(P[front])
    return bool(np.any((uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)))


def _to_stream(parts: list[_Chunk], t_origin_ns: int, camera: CameraModel, resolution_s: float = 0.0) -> EventStream:
    t = np.concatenate([c.t for c in parts])
    pix = np.concatenate([c.pix for c in parts])
    p = np.concatenate([c.p for c in parts])
    t_ns = np.rint(t * 1e9).astype(np.int64) + t_origin_ns
    if resolution_s > 0:
        # A sensor's counter ticks in whole units of the absolute clock: floor, which keeps the order.
        q = max(1, int(round(resolution_s * 1e9)))
        t_ns = (t_ns // q) * q
    order = np.argsort(t_ns, kind="stable")
    y, x = np.divmod(pix[order], camera.width)
    return EventStream.from_arrays(t_ns[order], x, y, p[order], camera.width, camera.height, validate=False)
