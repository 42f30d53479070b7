"""The paper's synthetic protocol (PLS-Calib, Sec. IV-A/B): routes, random ground truth, noisy sample pairs.

Routes are unit-size shapes scaled by ``scale``: the planar Circle, V-shape, Z-shape and S-shape of Table II,
and a smooth 3-D Lissajous curve ("6dof") with its ground-constrained twin ("planar", the same curve with z = 0)
for Table I. A route yields either positions along the curve or velocities (constant speed ``scale`` m/s for the
polyline and arc routes, mean speed ``scale`` for the Lissajous curves): the paper does not say which it used.

Each trial draws R_gt from ZYX Euler angles uniform in [-90, 90] deg and builds, in the paper's row convention,
``Y = X R_gt^T + eps`` with Gaussian noise of std ``sigma`` on X and on Y. R_gt plays the role of R_base_cam:
X is the camera's motion, Y the odometry's.

Two switches cover what the paper leaves open or gets backwards (see docs/paper_tables.md):
``noise_model`` "paper" builds Y from the *noisy* X exactly as written (so X's noise is shared by Y and is not
noise to a regression of Y on X); "independent" gives both sensors their own noise on the clean motion.
``planar_side`` "camera" puts the zero axis on X as the paper does (X = [x1, x2, 0]); "base" puts it on Y, as
on a real ground robot, where it is the odometry whose z motion is exactly zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import random_rotation_zyx
from ..errors import InputError

PLANAR_ROUTES = ("circle", "v_shape", "z_shape", "s_shape")
ROUTES = PLANAR_ROUTES + ("6dof", "planar")
QUANTITIES = ("position", "velocity")
NOISE_MODELS = ("paper", "independent")
PLANAR_SIDES = ("camera", "base")

#: Route names as the paper prints them.
ROUTE_TITLES = {
    "circle": "Circle",
    "v_shape": "V-shape",
    "z_shape": "Z-shape",
    "s_shape": "S-shape",
    "6dof": "Full 6-DoF",
    "planar": "Ground-constrained",
}


def _polyline(vertices: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points at arc-length fraction ``u`` along a polyline and the unit tangent there."""
    seg = np.diff(vertices, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = u * cum[-1]
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[k]) / length[k]
    return vertices[k] + frac[:, None] * seg[k], seg[k] / length[k][:, None]


def _s_curve(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two opposite arcs of radius 0.5 (centres (0, +-0.5)) of 240 deg each, like the letter S, at constant speed."""
    sweep = 4.0 * np.pi / 3.0
    upper = u < 0.5
    a = np.where(upper, u, u - 0.5) * 2.0 * sweep
    # Upper arc counter-clockwise from 30 deg; lower arc clockwise from 90 deg; they meet tangentially at (0, 0).
    ang = np.where(upper, np.pi / 6 + a, np.pi / 2 - a)
    cy = np.where(upper, 0.5, -0.5)
    p = np.stack([0.5 * np.cos(ang), cy + 0.5 * np.sin(ang), np.zeros_like(u)], axis=1)
    sgn = np.where(upper, 1.0, -1.0)
    tan = np.stack([-np.sin(ang) * sgn, np.cos(ang) * sgn, np.zeros_like(u)], axis=1)
    return p, tan


def _lissajous(u: np.ndarray, planar: bool) -> tuple[np.ndarray, np.ndarray]:
    """A closed 3-D curve whose three coordinates have different frequencies, so it excites every axis."""
    w = 2.0 * np.pi * np.array([1.0, 2.0, 3.0])
    ph = np.array([0.0, np.pi / 3, np.pi / 7])
    arg = u[:, None] * w + ph
    p = np.sin(arg)
    dp = np.cos(arg) * w
    if planar:
        p[:, 2] = 0.0
        dp[:, 2] = 0.0
    return p, dp / np.mean(np.linalg.norm(dp, axis=1))


def route_samples(name: str, n: int = 100, scale: float = 1.0, quantity: str = "position") -> np.ndarray:
    """Clean motion samples (n x 3) along route ``name``: positions (size ~ ``scale`` m) or velocities (~ ``scale``
    m/s), sampled uniformly over one traversal. Planar routes lie in z = 0."""
    if name not in ROUTES:
        raise InputError(f"unknown route {name!r}; choose one of {', '.join(ROUTES)}")
    if quantity not in QUANTITIES:
        raise InputError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
    if n < 3:
        raise InputError(f"need at least 3 samples per route, got {n}")
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale must be a positive number, got {scale}")
    u = np.arange(n) / n
    if name == "circle":
        ang = 2.0 * np.pi * u
        p = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], axis=1)
        d = np.stack([-np.sin(ang), np.cos(ang), np.zeros(n)], axis=1)
    elif name == "v_shape":
        p, d = _polyline(np.array([[-1.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 0.0]]), u)
    elif name == "z_shape":
        p, d = _polyline(np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, -1.0, 0.0], [1.0, -1.0, 0.0]]), u)
    elif name == "s_shape":
        p, d = _s_curve(u)
    else:
        p, d = _lissajous(u, planar=(name == "planar"))
    return scale * (p if quantity == "position" else d)


@dataclass(frozen=True)
class TrialSet:
    """``count`` paired trials: X, Y (count, n, 3) and the ground truth R_gt = R_base_cam (count, 3, 3)."""

    route: str
    X: np.ndarray
    Y: np.ndarray
    R_gt: np.ndarray

    @property
    def count(self) -> int:
        return int(self.R_gt.shape[0])


def make_trials(
    route: str,
    count: int = 200,
    seed: int = 0,
    n: int = 100,
    sigma: float = 0.10,
    scale: float = 1.0,
    quantity: str = "position",
    noise_model: str = "independent",
    planar_side: str = "camera",
    offset: np.ndarray | None = None,
    exact_zero_axis: bool = False,
) -> TrialSet:
    """Draw ``count`` trials of the paper's protocol on ``route`` with a fixed seed.

    ``offset`` (3,) is added to the clean motion of the planar side before rotation, to study a motion with a
    non-zero mean (e.g. a route that does not start at the origin); velocities already have one on every route
    but the circle.
    ``exact_zero_axis`` leaves the zero axis of the planar side noise-free, as for wheel odometry, whose z motion
    is exactly zero (only with ``noise_model="independent"``).
    """
    if noise_model not in NOISE_MODELS:
        raise InputError(f"noise_model must be one of {NOISE_MODELS}, got {noise_model!r}")
    if planar_side not in PLANAR_SIDES:
        raise InputError(f"planar_side must be one of {PLANAR_SIDES}, got {planar_side!r}")
    if count < 1:
        raise InputError(f"count must be positive, got {count}")
    if not (np.isfinite(sigma) and sigma >= 0):
        raise InputError(f"sigma must be a non-negative number, got {sigma}")
    # One generator per (seed, route) so a route's trials do not depend on which other routes were run.
    rng = np.random.default_rng([int(seed), ROUTES.index(route) if route in ROUTES else 0])
    P = route_samples(route, n, scale, quantity)
    if offset is not None:
        P = P + np.asarray(offset, dtype=float)
    R = np.stack([random_rotation_zyx(rng) for _ in range(count)])
    nx = sigma * rng.standard_normal((count, n, 3))
    ny = sigma * rng.standard_normal((count, n, 3))
    if exact_zero_axis:
        if noise_model != "independent":
            raise InputError("exact_zero_axis needs noise_model='independent' (the paper model mixes X noise into Y)")
        (nx if planar_side == "camera" else ny)[..., 2] = 0.0
    Rt = np.swapaxes(R, 1, 2)
    if planar_side == "camera":
        X_clean = np.broadcast_to(P, (count, n, 3))
    else:
        # The base (odometry) moves in its plane; the camera sees the same motion rotated: x_cam = R^T y_base.
        X_clean = P @ R
    X = X_clean + nx
    if noise_model == "paper":
        Y = X @ Rt + ny
    else:
        # On the base side the clean odometry motion is the route itself; taking it directly keeps its zero axis
        # exactly zero instead of a rotated-and-back rounding residue.
        Y = (X_clean @ Rt if planar_side == "camera" else np.broadcast_to(P, (count, n, 3))) + ny
    return TrialSet(route, X, Y, R)
