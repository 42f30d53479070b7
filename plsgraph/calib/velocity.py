"""Camera angular and linear velocity, in the camera frame, from a camera pose track.

The board is static, so the body velocity of T_board_cam is the camera's motion relative to the
world expressed in the camera frame: omega_cam = vee(R^T dR/dt), v_cam = R^T dp/dt with
(R, p) = T_board_cam.

Method: a local polynomial (Savitzky-Golay on irregular samples) around every pose. For pose i
the neighbours k in its window are expressed relative to it, log(R_i^T R_k) and p_k - p_i, a
polynomial in (t_k - t_i) is fitted by least squares and its slope at t_i is the derivative. In
the local chart the slope of log(R_i^T R(t)) at t_i is exactly the body angular velocity, so no
small-angle or constant-axis assumption enters. Windows never reach across gaps: the track is
split where frames are missing and each piece is differentiated on its own (windows become
one-sided near a piece's ends); pieces shorter than a window give no velocities.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.tracks import CameraTrack
from ..errors import InputError, InsufficientDataError

log = logging.getLogger(__name__)


def split_at_gaps(t: np.ndarray, max_gap_s: float) -> list[tuple[int, int]]:
    """Index ranges [i0, i1) of the pieces of ``t`` whose consecutive samples are at most ``max_gap_s`` apart."""
    cuts = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    edges = np.r_[0, cuts, t.size]
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _local_slopes(t: np.ndarray, T: np.ndarray, half: int, polyorder: int) -> tuple[np.ndarray, np.ndarray]:
    """Body angular and linear velocity (n, 3) of one gap-free piece of n >= 2 half + 1 poses."""
    n = t.size
    m = 2 * half + 1
    start = np.clip(np.arange(n) - half, 0, n - m)
    idx = start[:, None] + np.arange(m)[None, :]  # (n, m) window members
    R = T[:, :3, :3]
    p = T[:, :3, 3]
    # Relative rotations R_i^T R_k and displacements, all windows at once.
    R_rel = np.einsum("nji,nmjk->nmik", R, R[idx])
    phi = Rotation.from_matrix(R_rel.reshape(-1, 3, 3)).as_rotvec().reshape(n, m, 3)
    dp = p[idx] - p[:, None, :]
    tau = t[idx] - t[:, None]
    scale = np.max(np.abs(tau), axis=1, keepdims=True)  # conditioning: fit in tau / scale
    A = (tau / scale)[..., None] ** np.arange(polyorder + 1)  # (n, m, polyorder + 1)
    AtA = np.einsum("nmi,nmj->nij", A, A)
    Y = np.concatenate([phi, dp], axis=-1)  # (n, m, 6)
    AtY = np.einsum("nmi,nmk->nik", A, Y)
    coef = np.linalg.solve(AtA, AtY)  # (n, polyorder + 1, 6)
    slope = coef[:, 1, :] / scale
    omega = slope[:, :3]
    v = np.einsum("nji,nj->ni", R, slope[:, 3:])
    return omega, v


def camera_velocities(
    track: CameraTrack,
    *,
    window_s: float = 0.2,
    polyorder: int = 2,
    max_gap_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera angular velocity ``omega_cam`` (rad/s) and linear velocity ``v_cam`` (m/s), both (n, 3)
    in the camera frame, at the track times ``t`` (n,) where they can be computed.

    ``window_s`` is the nominal length of the fitting window (converted to an odd number of samples
    at the median frame interval, at least ``polyorder + 2``); ``max_gap_s`` the longest step
    between consecutive poses that is not a gap (default 2.5 median intervals). Poses in pieces
    between gaps that are shorter than a window are dropped; so the output may have fewer samples
    than the track. Raises :class:`InsufficientDataError` when no piece is long enough.
    """
    t = np.asarray(track.t, dtype=float)
    if polyorder < 1:
        raise InputError(f"camera_velocities: polyorder must be >= 1, got {polyorder}")
    if t.size < polyorder + 2:
        raise InsufficientDataError(
            f"camera_velocities: {t.size} poses are too few for a degree-{polyorder} fit; record longer"
        )
    dt = float(np.median(np.diff(t)))
    max_gap_s = 2.5 * dt if max_gap_s is None else float(max_gap_s)
    if not window_s > 0 or not max_gap_s > 0:
        raise InputError("camera_velocities: window_s and max_gap_s must be positive")
    half = max(int(round(0.5 * window_s / dt)), (polyorder + 1) // 2 + (polyorder + 1) % 2)
    m = 2 * half + 1
    ts, ws, vs = [], [], []
    dropped = 0
    for i0, i1 in split_at_gaps(t, max_gap_s):
        if i1 - i0 < m:
            dropped += i1 - i0
            continue
        w, v = _local_slopes(t[i0:i1], track.T_board_cam[i0:i1], half, polyorder)
        ts.append(t[i0:i1])
        ws.append(w)
        vs.append(v)
    if not ts:
        raise InsufficientDataError(
            f"camera_velocities: no run of {m} poses without a gap longer than {max_gap_s:.3f} s; "
            "shorten window_s or raise max_gap_s"
        )
    if dropped:
        log.info("camera_velocities: %d poses in pieces shorter than %d samples between gaps were dropped", dropped, m)
    return np.concatenate(ts), np.concatenate(ws), np.concatenate(vs)
