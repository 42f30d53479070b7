"""Shared simulated recordings for the refinement tests (small: 10 s, 30 Hz camera, 50 Hz wheels)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from plsgraph.core.geometry import make_T, so3_exp
from plsgraph.core.tracks import BaseTrack, CameraTrack
from plsgraph.frontend.pose import camera_track_from_detections
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.sim.robot import SimRecording, simulate_robot

# A closed-form-like seed: rotation off by ~2.7 deg, translation unknown (zero), td off by 5 ms.
SEED_ROT_DEG = np.array([1.0, -1.5, 2.0])
SEED_TD_OFFSET = 0.005


@dataclass(frozen=True)
class Case:
    rec: SimRecording
    base: BaseTrack
    track: CameraTrack
    seed_T: np.ndarray
    seed_td: float


@lru_cache(maxsize=8)
def sim_case(motion: str, duration: float = 10.0, seed: int = 3, noise_px: float = 0.3) -> Case:
    rec = simulate_robot(motion, duration=duration, seed=seed, realism="ideal")
    base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius, rec.track_width)
    track = camera_track_from_detections(rec.detections(noise_px, seed=seed + 10), rec.camera)
    seed_R = so3_exp(np.radians(SEED_ROT_DEG)) @ rec.T_base_cam[:3, :3]
    return Case(rec, base, track, make_T(seed_R, np.zeros(3)), rec.td + SEED_TD_OFFSET)


def rotation_error_base_axes(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) d with R_est = Exp(d) R_true: the error about base x, y, z."""
    from plsgraph.core.geometry import so3_log

    return so3_log(R_est @ R_true.T)
