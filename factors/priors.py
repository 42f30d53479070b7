"""Optional priors on the extrinsic and the board, each a custom factor on one Pose3 variable.

* rotation prior: ``Log(R_prior^T R)``, e.g. a weak prior from a closed-form rotation;
* height prior: translation z of a pose, e.g. the camera height above the base frame when the user
  measured it, or the height of the board origin above the floor when the board stands on it;
* vertical-board prior: the board's z axis (its normal) is horizontal, i.e. the board stands upright.

Jacobians are analytic for a right perturbation ``T Exp(w, u)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .lie import hat, so3_log, so3_right_jacobian_inv

_HAT_Z = hat(np.array([0.0, 0.0, 1.0]))


def rotation_prior_residual(T: np.ndarray, R_prior: np.ndarray, with_jacobian: bool = False):
    r = so3_log(R_prior.T @ T[:3, :3])
    if not with_jacobian:
        return r
    J = np.zeros((3, 6))
    J[:, :3] = so3_right_jacobian_inv(r)
    return r, J


def height_residual(T: np.ndarray, height: float, with_jacobian: bool = False):
    r = np.array([T[2, 3] - height])
    if not with_jacobian:
        return r
    J = np.zeros((1, 6))
    J[0, 3:] = T[2, :3]
    return r, J


def vertical_board_residual(T: np.ndarray, with_jacobian: bool = False):
    R = T[:3, :3]
    r = np.array([R[2, 2]])
    if not with_jacobian:
        return r
    J = np.zeros((1, 6))
    J[0, :3] = -R[2] @ _HAT_Z
    return r, J


def _unary(key: int, sigmas, residual) -> gtsam.CustomFactor:
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.atleast_1d(np.asarray(sigmas, dtype=float)))

    def error(this, values, H):
        T = values.atPose3(this.keys()[0]).matrix()
        if H is None:
            return residual(T, False)
        r, J = residual(T, True)
        H[0] = J
        return r

    return gtsam.CustomFactor(noise, [int(key)], error)


def make_rotation_prior(key: int, R_prior: np.ndarray, sigma_rad: float | np.ndarray) -> gtsam.CustomFactor:
    """Prior on the rotation of pose ``key`` only (translation free); sigma per axis or one for all."""
    R_prior = np.asarray(R_prior, dtype=float)
    sig = np.broadcast_to(np.asarray(sigma_rad, dtype=float), (3,))
    return _unary(key, sig, lambda T, j: rotation_prior_residual(T, R_prior, j))


def make_height_prior(key: int, height: float, sigma_m: float) -> gtsam.CustomFactor:
    """Prior on the z of the translation of pose ``key`` (e.g. camera height in the base frame)."""
    return _unary(key, [sigma_m], lambda T, j: height_residual(T, float(height), j))


def make_vertical_board_prior(key: int, sigma: float) -> gtsam.CustomFactor:
    """The board normal (z axis of T_world_board) lies in the floor plane; sigma ~ radians of tilt."""
    return _unary(key, [sigma], vertical_board_residual)


def make_subspace_prior(
    pose_key: int,
    vec_key: int,
    T0: np.ndarray,
    v0: np.ndarray,
    W: np.ndarray,
    sigma: float,
) -> gtsam.CustomFactor:
    """Prior holding chosen linear combinations of (pose, vector) at (T0, v0).

    Residual ``W @ [Log(T0^-1 T); v - v0]`` (GTSAM tangent of the pose at T0, then the vector), one row
    per combination, each with ``sigma``. Used to freeze directions the data cannot observe at their
    seed value so that they do not wander and spoil the linearization of the others.
    """
    W = np.atleast_2d(np.asarray(W, dtype=float))
    v0 = np.atleast_1d(np.asarray(v0, dtype=float))
    if W.shape[1] != 6 + v0.size:
        raise ValueError(f"subspace prior: W must have {6 + v0.size} columns, got {W.shape}")
    P0 = gtsam.Pose3(np.asarray(T0, dtype=float))
    noise = gtsam.noiseModel.Isotropic.Sigma(W.shape[0], float(sigma))

    def error(this, values, H):
        keys = this.keys()
        T = values.atPose3(keys[0])
        v = values.atVector(keys[1])
        xi = gtsam.Pose3.Logmap(P0.between(T))
        r = W @ np.r_[xi, v - v0]
        if H is not None:
            H[0] = W[:, :6] @ gtsam.Pose3.LogmapDerivative(xi)
            H[1] = np.ascontiguousarray(W[:, 6:])
        return r

    return gtsam.CustomFactor(noise, [int(pose_key), int(vec_key)], error)
