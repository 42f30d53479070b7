"""What the reprojection factors need of a camera: any object with these members (plsgraph's CameraModel is one)."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Camera(Protocol):
    K: np.ndarray  # 3 x 3 intrinsic matrix

    def distort_normalized(self, xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalized coordinates (n, 2) and their Jacobians (n, 2, 2) w.r.t. the undistorted ones."""
        ...

    def project(self, p: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of camera-frame points (n, 3)."""
        ...
