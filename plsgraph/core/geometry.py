"""Rotation and rigid-transform helpers on numpy arrays.

Conventions (see docs/ARCHITECTURE.md): ``T_a_b`` is a 4 x 4 homogeneous matrix mapping points from
frame b into frame a. Tangent vectors are ordered (rotation, translation), as in GTSAM's Pose3.
Every function accepts a single item or a stack along the leading axis.
"""

from __future__ import annotations

import numpy as np

# The one implementation of these maps is the factor library's; re-exported here for the rest of plsgraph.
from factors.lie import hat as hat
from factors.lie import inv_T as inv_T
from factors.lie import make_T as make_T
from factors.lie import so3_exp as so3_exp
from factors.lie import so3_log as so3_log

_EPS = 1e-12


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply T (4 x 4) to points p (n, 3)."""
    T = np.asarray(T, dtype=float)
    return np.asarray(p, dtype=float) @ T[:3, :3].T + T[:3, 3]


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """True if R is orthonormal with determinant +1 (within ``tol``)."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R @ R.T, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) to a 3 x 3 matrix, with the determinant fixed to +1."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Geodesic angle arccos((tr(R_est R_gt^T) - 1) / 2) in degrees; works on stacks."""
    R_est = np.asarray(R_est, dtype=float)
    R_gt = np.asarray(R_gt, dtype=float)
    tr = np.einsum("...ij,...ij->...", R_est, R_gt)
    c = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(c))


def random_rotation_zyx(rng: np.random.Generator, max_deg: float = 90.0) -> np.ndarray:
    """Rotation from ZYX Euler angles drawn uniformly in [-max_deg, max_deg] (the paper's protocol)."""
    from scipy.spatial.transform import Rotation  # imported when needed: scipy.spatial costs 0.25 s to load

    angles = rng.uniform(-max_deg, max_deg, size=3)
    return Rotation.from_euler("ZYX", angles, degrees=True).as_matrix()


def se3_log(T: np.ndarray) -> np.ndarray:
    """Tangent vector(s) (rotation, translation) of transform(s), GTSAM Pose3.Logmap ordering."""
    T = np.asarray(T, dtype=float)
    w = so3_log(T[..., :3, :3])
    theta = np.linalg.norm(w, axis=-1)
    W = hat(w)
    W2 = W @ W
    th = np.where(theta < 1e-8, 1.0, theta)
    small = theta < 1e-8
    a = np.where(small, 1.0 / 12.0, (1.0 - (th * np.sin(th)) / (2.0 * (1.0 - np.cos(th)))) / th**2)
    eye = np.broadcast_to(np.eye(3), W.shape)
    Vinv = eye - 0.5 * W + a[..., None, None] * W2
    u = np.einsum("...ij,...j->...i", Vinv, T[..., :3, 3])
    return np.concatenate([w, u], axis=-1)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Transform(s) from tangent vector(s) (rotation, translation)."""
    xi = np.asarray(xi, dtype=float)
    w, u = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(w, axis=-1)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    W = hat(w)
    W2 = W @ W
    b = np.where(small, 0.5, (1.0 - np.cos(th)) / th**2)
    c = np.where(small, 1.0 / 6.0, (th - np.sin(th)) / th**3)
    V = np.broadcast_to(np.eye(3), W.shape) + b[..., None, None] * W + c[..., None, None] * W2
    return make_T(so3_exp(w), np.einsum("...ij,...j->...i", V, u))


def interpolate_poses(t_query: np.ndarray, t: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Poses at ``t_query`` by slerp on rotation and linear interpolation of translation.

    ``t`` must be strictly increasing; queries outside [t[0], t[-1]] raise ValueError.
    """
    return PoseInterpolator(t, T)(t_query)


class PoseInterpolator:
    """:func:`interpolate_poses` of one trajectory, set up once for any number of queries (the slerp's rotations
    and their increments are computed when it is made, not per query)."""

    def __init__(self, t: np.ndarray, T: np.ndarray) -> None:
        from scipy.spatial.transform import Rotation, Slerp  # imported when needed (see random_rotation_zyx)

        self.t = np.asarray(t, dtype=float)
        self._p = T[:, :3, 3]
        self._slerp = Slerp(self.t, Rotation.from_matrix(T[:, :3, :3]))

    def __call__(self, t_query: np.ndarray) -> np.ndarray:
        t = self.t
        tq = np.atleast_1d(np.asarray(t_query, dtype=float))
        if tq.size and (tq.min() < t[0] - 1e-12 or tq.max() > t[-1] + 1e-12):
            raise ValueError(f"query times [{tq.min():.6f}, {tq.max():.6f}] outside [{t[0]:.6f}, {t[-1]:.6f}]")
        tq = np.clip(tq, t[0], t[-1])
        R = self._slerp(tq).as_matrix()
        p = np.stack([np.interp(tq, t, self._p[:, k]) for k in range(3)], axis=-1)
        return make_T(R, p)


def yaw_of(R: np.ndarray) -> np.ndarray:
    """Heading angle (rotation about z) of rotation(s), from the first column."""
    R = np.asarray(R, dtype=float)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def rot_z(yaw: np.ndarray) -> np.ndarray:
    """Rotation(s) about z by ``yaw`` radians."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(yaw.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R
