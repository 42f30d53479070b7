"""Odometry between-factors with a covariance from the differential-drive error model.

Wheel odometry errors grow like a random walk along the path: for an edge that travelled ``d``
metres and turned ``a`` radians (absolute values, summed along the full-rate odometry between the
two knots)

    sigma_x^2   = sigma_per_metre^2 * d + floor_m^2                        (along the motion)
    sigma_yaw^2 = yaw_per_radian^2 * a + yaw_per_metre^2 * d + floor_rad^2   (heading)
    sigma_y^2   = d^2 sigma_yaw^2 / 3 + lateral_per_metre^2 * d + floor_m^2  (across the motion)
    cov(y, yaw) = d sigma_yaw^2 / 2

The lateral terms are those of a heading error that grows linearly along the arc (the wheels
cannot slide sideways, so the robot only drifts sideways by driving with a wrong heading), plus a
small skid term. Keeping the lateral sigma small matters: it is what ties the heading of the base
to its direction of travel and so makes the camera yaw observable.

z, roll and pitch get the along-track and heading sigmas: the ground constraint is the separate
planar prior (factors.planar), so the between-factor does not need to encode it. The floors keep the
covariance positive definite when the robot stands still.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from .errors import FactorInputError as InputError


@dataclass(frozen=True)
class OdometryNoise:
    """Differential-drive noise. Units: m/sqrt(m), rad/sqrt(rad), rad/sqrt(m), m/sqrt(m), m, rad.

    The defaults describe good wheel odometry on a hard floor: distance about 3x tighter than heading, which
    slips most (the simulation's 0.5 % wheel slip is covered). Too loose a model lets the base trajectory
    float and leaves td with local minima; too tight a heading model turns slip into yaw bias
    (docs/refinement.md).
    """

    sigma_per_metre: float = 0.003
    yaw_per_radian: float = 0.01
    yaw_per_metre: float = 0.02
    lateral_per_metre: float = 0.0006
    floor_m: float = 1e-4
    floor_rad: float = 1e-4

    def __post_init__(self) -> None:
        vals = (self.sigma_per_metre, self.yaw_per_radian, self.yaw_per_metre, self.lateral_per_metre, self.floor_m,
                self.floor_rad)
        if not all(np.isfinite(v) and v >= 0 for v in vals) or self.floor_m <= 0 or self.floor_rad <= 0:
            raise InputError("odometry noise: sigmas must be finite and >= 0, floors > 0")


def odometry_covariance(distance, angle, noise: OdometryNoise | None = None) -> np.ndarray:
    """Covariance(s) (..., 6, 6) of relative base motions in Pose3 tangent order (rot xyz, trans xyz), base axes.

    ``distance`` (m) and ``angle`` (rad) are the path length and the absolute angle turned per edge.
    """
    noise = noise or OdometryNoise()
    d = np.abs(np.asarray(distance, dtype=float))
    a = np.abs(np.asarray(angle, dtype=float))
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(a))):
        raise InputError("odometry covariance: distance and angle must be finite")
    d, a = np.broadcast_arrays(d, a)
    var_x = noise.sigma_per_metre**2 * d + noise.floor_m**2
    var_yaw = noise.yaw_per_radian**2 * a + noise.yaw_per_metre**2 * d + noise.floor_rad**2
    var_y = d**2 * var_yaw / 3.0 + noise.lateral_per_metre**2 * d + noise.floor_m**2
    cov = np.zeros(d.shape + (6, 6))
    cov[..., 0, 0] = var_yaw  # roll
    cov[..., 1, 1] = var_yaw  # pitch
    cov[..., 2, 2] = var_yaw
    cov[..., 3, 3] = var_x
    cov[..., 4, 4] = var_y
    cov[..., 5, 5] = var_x  # z
    cov[..., 2, 4] = cov[..., 4, 2] = d * var_yaw / 2.0
    return cov


def path_increments(t: np.ndarray, T_world_base: np.ndarray, knot_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Path length (m) and absolute angle turned (rad) between consecutive knots, from full-rate odometry.

    ``knot_index`` are increasing indices into the odometry samples.
    """
    T = np.asarray(T_world_base, dtype=float)
    step_d = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=-1)
    R = T[:, :3, :3]
    cos_step = (np.einsum("nij,nij->n", R[:-1], R[1:]) - 1.0) / 2.0
    step_a = np.arccos(np.clip(cos_step, -1.0, 1.0))
    cd = np.concatenate([[0.0], np.cumsum(step_d)])
    ca = np.concatenate([[0.0], np.cumsum(step_a)])
    k = np.asarray(knot_index)
    return np.diff(cd[k]), np.diff(ca[k])


def make_odometry_factors(
    keys, T_knots: np.ndarray, distance: np.ndarray, angle: np.ndarray, noise: OdometryNoise | None = None
) -> list[gtsam.BetweenFactorPose3]:
    """Between-factors between consecutive knot keys, measured relative motion from the odometry poses."""
    T_knots = np.asarray(T_knots, dtype=float)
    rel = np.linalg.inv(T_knots[:-1]) @ T_knots[1:]
    cov = odometry_covariance(distance, angle, noise)
    out = []
    for i in range(len(rel)):
        nm = gtsam.noiseModel.Gaussian.Covariance(cov[i])
        out.append(gtsam.BetweenFactorPose3(int(keys[i]), int(keys[i + 1]), gtsam.Pose3(rel[i]), nm))
    return out
