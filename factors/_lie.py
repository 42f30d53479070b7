"""Vectorized SO(3) / SE(3) pieces the factors need for their analytic Jacobians.

Tangent ordering and perturbation follow GTSAM's Pose3: (rotation, translation), right perturbation
``T * Exp(xi)``. To first order that is ``R' = R Exp(w)``, ``p' = p + R u`` whatever retraction GTSAM
was built with, which is all a Jacobian evaluated at the linearization point needs.
"""

from __future__ import annotations

import numpy as np

from plsgraph.core.geometry import hat

_SMALL = 1e-6


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


def point_jacobian_wrt_pose_inverse(q: np.ndarray) -> np.ndarray:
    """d(T^-1 x) / d(xi) for a right perturbation T Exp(xi), where q = T^-1 x: (..., 3, 6) = [hat(q), -I]."""
    q = np.asarray(q, dtype=float)
    out = np.zeros(q.shape[:-1] + (3, 6))
    out[..., :3] = hat(q)
    out[..., 3:] = -np.eye(3)
    return out
