"""Pinhole camera with plumb_bob (radial-tangential k1 k2 p1 p2 k3) distortion, as ROS CameraInfo has it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .resources import bundled_dir, read_yaml_mapping


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera. ``dist`` is (k1, k2, p1, p2, k3), OpenCV / ROS plumb_bob order."""

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float).reshape(3, 3)
        d = np.zeros(5)
        dist = np.asarray(self.dist, dtype=float).ravel()
        if dist.size > 5 or not np.all(np.isfinite(K)) or not np.all(np.isfinite(dist)):
            raise InputError("camera: K must be finite 3x3 and dist at most 5 finite plumb_bob coefficients")
        d[: dist.size] = dist
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"camera: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
        if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0.0, atol=1e-9):
            raise InputError(f"camera: K's last row must be [0, 0, 1], got {K[2].tolist()}")
        if not (0.0 < K[0, 2] < self.width and 0.0 < K[1, 2] < self.height):
            # (0, 0) or a point outside the image: a matrix written in another convention, or the wrong camera.
            raise InputError(f"camera: the principal point ({K[0, 2]:g}, {K[1, 2]:g}) must lie inside the "
                             f"{self.width} x {self.height} image")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def distort_normalized(self, xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalized coordinates (n, 2) and their Jacobian d(xd)/d(xn) (n, 2, 2)."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        drad = k1 + 2 * k2 * r2 + 3 * k3 * r2**2  # d radial / d r2
        J = np.empty((xn.shape[0], 2, 2))
        J[:, 0, 0] = radial + x * drad * 2 * x + 2 * p1 * y + p2 * 6 * x
        J[:, 0, 1] = x * drad * 2 * y + 2 * p1 * x + p2 * 2 * y
        J[:, 1, 0] = y * drad * 2 * x + p1 * 2 * x + 2 * p2 * y
        J[:, 1, 1] = radial + y * drad * 2 * y + p1 * 6 * y + 2 * p2 * x
        return np.stack([xd, yd], axis=-1), J

    def project(self, p_cam: np.ndarray, with_jacobian: bool = False):
        """Pixel coordinates (n, 2) of points (n, 3) in the camera frame.

        With ``with_jacobian`` also returns d(uv)/d(p_cam) (n, 2, 3). Points must have z > 0.
        """
        p = np.asarray(p_cam, dtype=float).reshape(-1, 3)
        z = p[:, 2]
        inv_z = 1.0 / z
        xn = p[:, :2] * inv_z[:, None]
        xd, Jd = self.distort_normalized(xn)
        uv = np.empty_like(xd)
        uv[:, 0] = self.fx * xd[:, 0] + self.K[0, 1] * xd[:, 1] + self.cx
        uv[:, 1] = self.fy * xd[:, 1] + self.cy
        if not with_jacobian:
            return uv
        Kp = self.K[:2, :2]
        Jn = np.zeros((p.shape[0], 2, 3))  # d xn / d p
        Jn[:, 0, 0] = inv_z
        Jn[:, 1, 1] = inv_z
        Jn[:, 0, 2] = -xn[:, 0] * inv_z
        Jn[:, 1, 2] = -xn[:, 1] * inv_z
        J = np.einsum("ij,njk,nkl->nil", Kp, Jd, Jn)
        return uv, J

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Normalized undistorted coordinates (n, 2) of pixels (n, 2)."""
        import cv2

        pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
        out = cv2.undistortPointsIter(pts, self.K, self.dist, None, None, crit)
        return out.reshape(-1, 2)

    def to_dict(self) -> dict:
        return {
            "width": int(self.width),
            "height": int(self.height),
            "K": self.K.tolist(),
            "distortion_model": "plumb_bob",
            "D": self.dist.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> CameraModel:
        try:
            K = d["K"] if "K" in d else d["camera_matrix"]["data"]
            D = d.get("D", d.get("dist", (d.get("distortion_coefficients") or {}).get("data", [])))
            model = d.get("distortion_model", "plumb_bob")
            if model not in ("plumb_bob", "rational_polynomial", "radtan") or len(D) > 5:
                raise InputError(f"camera: unsupported distortion model {model!r} with {len(D)} coefficients")
            w = d.get("width", d.get("image_width"))
            h = d.get("height", d.get("image_height"))
            return cls(int(w), int(h), np.asarray(K, dtype=float).reshape(3, 3), np.asarray(D, dtype=float))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                f"camera: bad or missing field ({exc}); expected width, height, K (9 numbers), D (plumb_bob)"
            ) from exc

    @classmethod
    def from_yaml(cls, path: str | Path) -> CameraModel:
        """Load from plsgraph's camera YAML or a ROS camera_calibration YAML (camera_matrix / ...); OpenCV and Kalibr
        files are read by :func:`plsgraph.io.camera_files.read_camera_file`."""
        return cls.from_dict(read_yaml_mapping(path, "camera file"))


def davis346_default() -> CameraModel:
    """Preset for a DAVIS346 (346 x 260, 18 um pixels) with a ~4.5 mm lens (data/cameras/davis346.yaml)."""
    return CameraModel.from_yaml(bundled_dir("cameras") / "davis346.yaml")
