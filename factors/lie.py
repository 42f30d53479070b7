"""Vectorized SO(3) / SE(3) in numpy: hat, exp, log, homogeneous transforms and the Jacobians the factors need.

This is the package's (and plsgraph's) one implementation of these maps; it needs numpy only.

Tangent ordering and perturbation follow GTSAM's Pose3: (rotation, translation), right perturbation
``T * Exp(xi)``. To first order that is ``R' = R Exp(w)``, ``p' = p + R u`` whatever retraction GTSAM
was built with, which is all a Jacobian evaluated at the linearization point needs.
"""

from __future__ import annotations

import numpy as np

_SMALL = 1e-6


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix(es) of vector(s) ``w`` (..., 3) -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix(es) (..., 3, 3) from rotation vector(s) (..., 3) (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < _SMALL
    t = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    W = hat(w)
    return np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector(s) (..., 3) of rotation matrix(es) (..., 3, 3); exact near 0 and near pi."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    th = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.sin(th)
    small = th < _SMALL
    scale = np.where(small, 0.5 + th**2 / 12.0, th / (2.0 * np.where(small, 1.0, s)))
    out = scale[..., None] * v
    near_pi = th > np.pi - 1e-3
    if np.any(near_pi):
        # sin(th) -> 0: read the axis from the symmetric part, R + R^T = 2 cos(th) I + 2 (1 - cos(th)) a a^T.
        Rp = R[near_pi]
        thp = th[near_pi]
        B = (Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - np.cos(thp)[..., None, None] * np.eye(3)
        B = B / (1.0 - np.cos(thp))[..., None, None]
        k = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        col = np.take_along_axis(B, k[..., None, None].repeat(3, axis=-1), axis=-2)[..., 0, :]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        vp = v[near_pi]
        sign = np.where(np.sum(axis * vp, axis=-1) < 0, -1.0, 1.0)
        out[near_pi] = (sign * thp)[..., None] * axis
    return out


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack rotation(s) (..., 3, 3) and translation(s) (..., 3) into homogeneous matrices."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of homogeneous transform(s)."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """Right Jacobian Jr(w) of SO(3), (..., 3) -> (..., 3, 3): Exp(w + d) ~ Exp(w) Exp(Jr(w) d)."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < _SMALL
    t = np.where(small, 1.0, th)
    # Series below _SMALL keep the coefficients exact to double precision instead of 0/0.
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (t - np.sin(t)) / t**3)
    W = hat(w)
    return np.eye(3) - a[..., None, None] * W + b[..., None, None] * (W @ W)


def so3_right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """Inverse of the right Jacobian of SO(3): Log(Exp(w) Exp(d)) ~ w + Jr^-1(w) d."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < _SMALL
    t = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th**2 / 720.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    W = hat(w)
    return np.eye(3) + 0.5 * W + c[..., None, None] * (W @ W)


def pose_adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint (..., 6, 6) of transform(s) (..., 4, 4) in (rotation, translation) ordering."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = hat(T[..., :3, 3]) @ R
    return out
