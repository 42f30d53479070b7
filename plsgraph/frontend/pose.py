"""Board pose from pixel detections: planar PnP, outlier handling, covariance, and the camera track.

OpenCV's PnP returns T_cam_board (rvec, tvec); everything leaving this module is T_board_cam, the
camera pose in the board frame, which is what :class:`plsgraph.core.tracks.CameraTrack` stores.

Covariance convention: T_board_cam(xi) = T_board_cam * Exp(xi), xi = (rotation, translation), so
the 6 x 6 matrices returned here are directly usable as GTSAM Pose3 noise models.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..core.camera import CameraModel
from ..core.geometry import hat, inv_T, make_T
from ..core.tracks import CameraTrack, Detections
from ..errors import InputError, InsufficientDataError

log = logging.getLogger(__name__)

# A planar PnP has 6 unknowns; with fewer than 6 points the pose is barely determined and its
# covariance meaningless, so frames with less are rejected even though IPPE would run on 4.
MIN_POINTS = 6


@dataclass(frozen=True)
class PoseEstimate:
    """One frame's PnP result.

    ``T_board_cam`` (4, 4); ``cov`` (6, 6) in the right tangent space of T_board_cam (rotation
    first); ``rms_px`` reprojection RMS over the inliers; ``inliers`` (N,) bool mask over the
    points given (False for NaN points and rejected outliers); ``residuals_px`` (N,) reprojection
    error norm of every finite point (NaN for points that were not seen).
    """

    T_board_cam: np.ndarray
    cov: np.ndarray
    rms_px: float
    inliers: np.ndarray
    residuals_px: np.ndarray
    sigma_px: float


def reprojection_jacobian(
    T_board_cam: np.ndarray, board_points: np.ndarray, camera: CameraModel
) -> tuple[np.ndarray, np.ndarray]:
    """Projected pixels (n, 2) and d(uv)/d(xi) (n, 2, 6) for the right perturbation of T_board_cam.

    With T_board_cam(xi) = T_board_cam Exp(xi) a board point seen by the camera is
    p_cam(xi) = Exp(-xi) p_cam, whose first-order change is hat(p_cam) w - v.
    """
    T_cam_board = inv_T(T_board_cam)
    p_cam = board_points @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    uv, J_proj = camera.project(p_cam, with_jacobian=True)
    dp = np.concatenate([hat(p_cam), -np.broadcast_to(np.eye(3), p_cam.shape[:1] + (3, 3))], axis=-1)
    return uv, np.einsum("nij,njk->nik", J_proj, dp)


def pose_covariance(
    T_board_cam: np.ndarray, board_points: np.ndarray, camera: CameraModel, sigma_px: float
) -> np.ndarray:
    """Gauss-Newton covariance sigma^2 (J^T J)^-1 of T_board_cam (right tangent, rotation first).

    Raises :class:`InsufficientDataError` when the points do not constrain all six directions.
    """
    _, J = reprojection_jacobian(T_board_cam, board_points, camera)
    J = J.reshape(-1, 6)
    H = J.T @ J
    if np.linalg.cond(H) > 1e12:
        raise InsufficientDataError("PnP: the board points do not constrain the pose (collinear or too few points)")
    cov = np.linalg.inv(H) * sigma_px**2
    return 0.5 * (cov + cov.T)


def _T_cam_board(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    # cv2.Rodrigues is the same map as so3_exp, an order of magnitude cheaper for one vector.
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return make_T(R, np.asarray(tvec, dtype=float).ravel())


def _solve(obj: np.ndarray, img: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray] | None:
    """IPPE (both planar solutions) followed by LM refinement of the better one; None on failure."""
    obj = np.ascontiguousarray(obj, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(img, dtype=np.float64).reshape(-1, 1, 2)
    try:
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error as exc:  # degenerate input (e.g. all points on a line) makes IPPE assert
        log.debug("IPPE failed: %s", exc)
        return None
    if n == 0:
        return None
    best = None
    for rvec, tvec, err in zip(rvecs, tvecs, np.ravel(errs), strict=False):
        # A solution must put the board in front of the camera; the mirrored IPPE solution may not.
        T = _T_cam_board(rvec, tvec)
        z = obj.reshape(-1, 3) @ T[2, :3] + T[2, 3]
        if np.all(z > 0) and (best is None or err < best[2]):
            best = (rvec, tvec, err)
    if best is None:
        return None
    rvec, tvec = best[0].copy(), best[1].copy()
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-10)
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, camera.K, camera.dist, rvec, tvec, crit)
    return rvec.ravel(), tvec.ravel()


def solve_pnp(
    uv: np.ndarray,
    board_points: np.ndarray,
    camera: CameraModel,
    *,
    sigma_px: float | None = None,
    outlier_px: float = 2.0,
    outlier_sigmas: float = 4.0,
    min_points: int = MIN_POINTS,
) -> PoseEstimate:
    """Camera pose in the board frame from pixel detections of board points.

    ``uv`` (N, 2) distorted pixel coordinates, NaN where a point was not seen; ``board_points``
    (N, 3) with z = 0. The pose comes from IPPE + Levenberg-Marquardt on the distorted pixels
    (OpenCV applies the plumb_bob model). Points whose residual exceeds both ``outlier_px`` and
    ``outlier_sigmas`` times a robust residual scale are dropped and the pose re-solved once.

    ``sigma_px`` is the pixel noise used for the covariance; None estimates it from the inlier
    residuals (RMS with a 2N - 6 degrees-of-freedom correction), floored at 0.05 px so a perfect
    fit does not claim an impossible precision.

    Raises :class:`InsufficientDataError` when fewer than ``min_points`` usable points remain or
    no solution puts the board in front of the camera.
    """
    uv = np.asarray(uv, dtype=float)
    pts = np.asarray(board_points, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2 or pts.shape != (uv.shape[0], 3):
        raise InputError(f"PnP: uv {uv.shape} and board points {pts.shape} must be (N, 2) and (N, 3)")
    if np.any(np.abs(pts[:, 2]) > 1e-9):
        raise InputError("PnP: board points must lie in the z = 0 plane of the board frame")
    seen = np.all(np.isfinite(uv), axis=1)
    if np.count_nonzero(seen) < min_points:
        raise InsufficientDataError(
            f"PnP: only {int(np.count_nonzero(seen))} board points seen, need {min_points}; move the board into view"
        )
    inl = seen.copy()
    sol = None
    for it in range(3):  # solve, drop outliers, solve again (the final pose always uses exactly ``inl``)
        sol = _solve(pts[inl], uv[inl], camera)
        if sol is None:
            raise InsufficientDataError("PnP: no pose puts the board in front of the camera (bad detection?)")
        T_cb = _T_cam_board(*sol)
        res = np.full(uv.shape[0], np.nan)
        res[seen] = np.linalg.norm(camera.project(transform_board(T_cb, pts[seen])) - uv[seen], axis=1)
        # Robust sigma from the median residual norm (Rayleigh distributed for isotropic Gaussian pixel
        # noise: median = 1.1774 sigma); the threshold is never below outlier_px so that sub-pixel scatter
        # of a clean frame does not cull good points.
        scale = np.median(res[inl]) / 1.1774
        new_inl = seen & (res <= max(outlier_px, outlier_sigmas * scale))
        if np.array_equal(new_inl, inl) or it == 2:
            break
        if np.count_nonzero(new_inl) < min_points:
            raise InsufficientDataError(
                f"PnP: only {int(np.count_nonzero(new_inl))} points fit a common pose; detection is unreliable"
            )
        inl = new_inl
    T_board_cam = inv_T(T_cb)
    n = int(np.count_nonzero(inl))
    rms = float(np.sqrt(np.mean(res[inl] ** 2)))
    if sigma_px is None:
        sigma_px = max(0.05, float(np.sqrt(np.sum(res[inl] ** 2) / max(2 * n - 6, 1))))
    cov = pose_covariance(T_board_cam, pts[inl], camera, sigma_px)
    return PoseEstimate(T_board_cam, cov, rms, inl, res, float(sigma_px))


def transform_board(T_cam_board: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Board points (n, 3) in the camera frame."""
    return pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]


def frame_pose(uv: np.ndarray, board_points: np.ndarray, camera: CameraModel, **options: Any
               ) -> PoseEstimate | str | Exception:
    """:func:`solve_pnp` of one detection frame (``options``: its keyword settings); why it gave no pose (the
    message of its :class:`InsufficientDataError`); or any other error it raised, kept to be raised if the frame is
    used (a frame solved ahead may yet be dropped). Each frame's pose depends on that frame alone."""
    try:
        return solve_pnp(uv, board_points, camera, **options)
    except InsufficientDataError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - raised by camera_track_from_detections if the frame is kept
        return exc


def camera_track_from_detections(
    detections: Detections,
    camera: CameraModel,
    *,
    max_rms_px: float = 1.5,
    sigma_px: float | None = None,
    outlier_px: float = 2.0,
    min_points: int = MIN_POINTS,
    progress: Callable[[int, int], None] | None = None,
    estimates: list[PoseEstimate | str | Exception] | None = None,
) -> CameraTrack:
    """PnP on every detection frame; frames that fail or fit worse than ``max_rms_px`` are dropped.

    ``estimates`` (one per frame, from :func:`frame_pose` with the same settings, e.g. computed beside the
    detection in a worker process) are used instead of solving again.

    The returned track keeps, in ``detections``, the accepted frames with rejected outlier points
    set to NaN, so the reprojection factors see exactly the points the poses came from.
    ``info`` holds ``frames_in``, ``frames_ok`` and ``rejected`` (reason -> count).
    Raises :class:`InsufficientDataError` when no frame yields a pose.
    """
    m = len(detections)
    keep = np.zeros(m, dtype=bool)
    T = np.zeros((m, 4, 4))
    cov = np.zeros((m, 6, 6))
    rms = np.zeros(m)
    uv_out = np.array(detections.uv, copy=True)
    rejected: Counter[str] = Counter()
    if estimates is not None and len(estimates) != m:
        raise InputError(f"PnP: {len(estimates)} precomputed poses for {m} detection frames")
    for k in range(m):
        est = estimates[k] if estimates is not None else \
            frame_pose(detections.uv[k], detections.board_points, camera, sigma_px=sigma_px, outlier_px=outlier_px,
                       min_points=min_points)
        if progress is not None:
            progress(k + 1, m)
        if isinstance(est, Exception):
            raise est
        if isinstance(est, str):
            rejected["pnp_failed"] += 1
            log.debug("frame %d at t=%.4f: %s", k, detections.t[k], est)
            continue
        if est.rms_px > max_rms_px:
            rejected["rms_above_threshold"] += 1
            log.debug("frame %d at t=%.4f: reprojection RMS %.2f px > %.2f", k, detections.t[k], est.rms_px, max_rms_px)
            continue
        keep[k] = True
        T[k], cov[k], rms[k] = est.T_board_cam, est.cov, est.rms_px
        uv_out[k][~est.inliers] = np.nan
    if not np.any(keep):
        raise InsufficientDataError(
            f"PnP: none of {m} detection frames gave a pose with RMS <= {max_rms_px} px "
            f"({dict(rejected)}); check the intrinsics and the board definition"
        )
    dets = Detections(detections.t[keep], uv_out[keep], detections.board_points)
    info = {
        "frames_in": m,
        "frames_ok": int(np.count_nonzero(keep)),
        "rejected": dict(rejected),
        "median_rms_px": float(np.median(rms[keep])),
    }
    return CameraTrack(dets.t, T[keep], cov=cov[keep], rms_px=rms[keep], detections=dets, info=info)
