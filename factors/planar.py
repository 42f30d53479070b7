"""Planar-motion prior on a base pose: the robot drives on a flat floor.

Residual (3): ``(z - z0, R[2, 1], -R[2, 0])`` of ``T_world_base = (R, p)``. For small tilts these are the
height, the roll and the pitch (ZYX Euler angles: R[2, 0] = -sin(pitch), R[2, 1] = sin(roll) cos(pitch)),
independent of the heading. Sigmas are configurable; the floor is never perfectly flat.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .lie import hat

_HAT_X = hat(np.array([1.0, 0.0, 0.0]))
_HAT_Y = hat(np.array([0.0, 1.0, 0.0]))


def planar_residual(T: np.ndarray, z0: float = 0.0, with_jacobian: bool = False):
    """Residual (3,) and optionally its Jacobian (3, 6) for a right perturbation of T."""
    R, p = T[:3, :3], T[:3, 3]
    r = np.array([p[2] - z0, R[2, 1], -R[2, 0]])
    if not with_jacobian:
        return r
    J = np.zeros((3, 6))
    # delta R[2, j] = (R hat(w))[2, j] = -R[2, :] hat(e_j) w ;  delta p = R u
    J[0, 3:] = R[2]
    J[1, :3] = -R[2] @ _HAT_Y
    J[2, :3] = R[2] @ _HAT_X
    return r, J


def make_planar_factor(key: int, sigma_z: float = 0.005, sigma_tilt: float = 0.005, z0: float = 0.0):
    """Custom factor pulling base pose ``key`` onto the floor plane z = z0 with zero roll and pitch."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_z, sigma_tilt, sigma_tilt], dtype=float))

    def error(this, values, H):
        T = values.atPose3(this.keys()[0]).matrix()
        if H is None:
            return planar_residual(T, z0)
        r, J = planar_residual(T, z0, True)
        H[0] = J
        return r

    return gtsam.CustomFactor(noise, [int(key)], error)
