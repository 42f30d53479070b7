"""Reprojection of the detected board points under a calibration: the one place that predicts pixels from
(odometry pose, T_base_cam, td, board pose). The refinement's comparison and the report's pictures use it."""

from __future__ import annotations

import numpy as np

from ..core.camera import CameraModel
from ..core.geometry import inv_T
from ..core.tracks import BaseTrack, Detections

MIN_DEPTH_M = 1e-6  # points nearer than this (or behind the camera) have no pixel


def predicted_pixels(
    det: Detections, base_track: BaseTrack, camera: CameraModel, T_base_cam: np.ndarray, td: float,
    T_world_board: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted pixels (m, N, 2) of the detections whose time (+ td) lies inside the odometry, and the mask (n,)
    of those detections. Points behind the camera are NaN."""
    t_odom = det.t + td
    ok = (t_odom >= base_track.t[0]) & (t_odom <= base_track.t[-1])
    T_cam_board = inv_T(base_track.poses_at(t_odom[ok]) @ T_base_cam) @ T_world_board
    pts = det.board_points
    p_cam = np.einsum("fij,nj->fni", T_cam_board[:, :3, :3], pts) + T_cam_board[:, None, :3, 3]
    valid = p_cam[..., 2] > MIN_DEPTH_M
    uv = np.full(p_cam.shape[:2] + (2,), np.nan)
    uv[valid] = camera.project(p_cam[valid])
    return uv, ok


def residuals(
    det: Detections, base_track: BaseTrack, camera: CameraModel, T_base_cam: np.ndarray, td: float,
    T_world_board: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(times (m,), residual vectors (m, N, 2) = predicted - detected) of the detections inside the odometry."""
    uv, ok = predicted_pixels(det, base_track, camera, T_base_cam, td, T_world_board)
    return det.t[ok], uv - det.uv[ok]
