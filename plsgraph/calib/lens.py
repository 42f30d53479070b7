"""The camera model's radial lens distortion checked against the board views.

A CameraInfo published without its calibration's distortion (or with another lens's) is invisible in the fit: the
poses absorb it and the reprojection RMS stays low, while the board's apparent size, and with it its distance and the
lever arm along the camera's axis, comes out wrong (an independent recording of a lens with k1 -0.06 calibrated with
all-zero coefficients gave x 20 cm off at 0.23 px RMS). The board views hold the distortion: the same grid seen at
many places in the image. :func:`distortion_from_views` fits k1 and k2 to them with the rest of the intrinsics held
(the focal length and the principal point are not resolved well enough by these views: docs/validation.md, "The
CameraInfo's focal length checked against the board views"), and compares the two models where it matters: the
radial displacement, in pixels, at the image radii the board was seen at. The refinement then measures what the
views' distortion would move (:func:`plsgraph.refine.graph.camera_sensitivity`), and the gate flags a result the
move would carry beyond its sigmas.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..core.camera import CameraModel

#: At most this many frames enter the fit (evenly spread over the recording), each with at least MIN_POINTS_FRACTION
#: of the board's points; fewer than MIN_FRAMES such frames: no check.
MAX_FRAMES = 80
MIN_FRAMES = 20
MIN_POINTS_FRACTION = 0.8
#: The jackknife's stretches of frames (the detections' errors are shared by neighbouring frames).
SEGMENTS = 10
#: The two models' displacement differs by more than this many jackknife sigmas and by more than MIN_SHIFT_PX at the
#: board's outer radii: the views disagree with the camera model (the refinement then measures what it moves).
SIGNIFICANCE = 3.0
MIN_SHIFT_PX = 0.3
#: A view whose reprojection RMS exceeds this many times the median (and OUTLIER_MIN_PX) is left out of the fit.
OUTLIER_FACTOR = 3.0
OUTLIER_MIN_PX = 1.0
#: The radius (percentile of the detections' distances from the principal point) the displacement is compared at.
RADIUS_PERCENTILE = 95.0


@dataclass(frozen=True)
class LensCheck:
    """The board views' radial distortion against the camera model's.

    ``given`` / ``views``: (k1, k2) of the camera model and as the views fit them (the rest of the intrinsics held);
    ``cov``: the views' jackknife covariance of (k1, k2); ``radius``: the normalised image radius compared at (the
    detections' 95th percentile); ``shift_px``: the views' model's radial displacement there less the given model's
    (pixels, positive outwards); ``shift_sigma_px``: its jackknife sigma; ``n_frames``: frames fitted;
    ``rms_px``: the fit's reprojection RMS with the views' distortion."""

    given: np.ndarray
    views: np.ndarray
    cov: np.ndarray
    radius: float
    shift_px: float
    shift_sigma_px: float
    n_frames: int
    rms_px: float

    @property
    def significant(self) -> bool:
        """Whether the views disagree with the camera model's distortion beyond their own scatter and by enough
        pixels to matter."""
        return bool(abs(self.shift_px) > max(SIGNIFICANCE * self.shift_sigma_px, MIN_SHIFT_PX))

    def camera(self, camera: CameraModel) -> CameraModel:
        """``camera`` with the views' k1 and k2."""
        dist = np.asarray(camera.dist, dtype=float).copy()
        dist[:2] = self.views
        return dataclasses.replace(camera, dist=dist)

    def to_dict(self) -> dict:
        return {"k1_k2_given": [float(x) for x in self.given], "k1_k2_views": [float(x) for x in self.views],
                "k1_k2_views_sigma": [float(x) for x in np.sqrt(np.clip(np.diag(self.cov), 0, None))],
                "radius_normalised": float(self.radius), "shift_px": float(self.shift_px),
                "shift_sigma_px": float(self.shift_sigma_px), "frames": int(self.n_frames),
                "rms_px": float(self.rms_px), "significant": self.significant}


def _radial_px(camera: CameraModel, k: np.ndarray, r: float) -> float:
    """The radial displacement (pixels) the coefficients ``k`` = (k1, k2) give a point at normalised radius ``r``."""
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    return float(f * r * (k[0] * r**2 + k[1] * r**4))


class _Views:
    """The board views' reprojection as a function of each view's pose and the shared k1, k2 (the rest of the camera
    held), solved by Gauss-Newton with the poses eliminated view by view (each view's 6x6 block), which also gives each
    view's share of the reduced 2x2 system for the jackknife."""

    def __init__(self, camera: CameraModel, obj: list, img: list) -> None:
        import cv2

        self.K = camera.K.astype(np.float64)
        self.dist = np.asarray(camera.dist, dtype=np.float64).copy()
        self.obj, self.img = obj, img
        self.poses = []
        for o, u in zip(obj, img, strict=True):
            ok, rvec, tvec = cv2.solvePnP(o, u, self.K, self.dist, flags=cv2.SOLVEPNP_ITERATIVE)
            if not ok:
                raise ValueError("a board view's pose could not be solved")
            self.poses.append(np.r_[rvec.ravel(), tvec.ravel()])

    def _normal(self, k: np.ndarray) -> tuple[list, float]:
        """Per view: (S_i, g_i, Ainv_i, B_i, a_i) of the reduced system at ``k``; and the RMS (px)."""
        import cv2

        dist = self.dist.copy()
        dist[:2] = k
        out, sq, n = [], 0.0, 0
        for o, u, p in zip(self.obj, self.img, self.poses, strict=True):
            proj, J = cv2.projectPoints(o.astype(np.float64), p[:3], p[3:], self.K, dist)
            r = (proj.reshape(-1, 2) - u.reshape(-1, 2)).ravel()
            Jp, Jd = J[:, :6], J[:, 10:12]  # rvec, tvec | focal, principal point | k1, k2, ...
            A = Jp.T @ Jp
            B = Jp.T @ Jd
            Ainv = np.linalg.inv(A)
            a = Jp.T @ r
            out.append((Jd.T @ Jd - B.T @ Ainv @ B, Jd.T @ r - B.T @ Ainv @ a, Ainv, B, a))
            sq += float(r @ r)
            n += r.size // 2
        return out, float(np.sqrt(sq / max(n, 1)))

    def view_rms(self, k: np.ndarray) -> np.ndarray:
        """Each view's reprojection RMS (px) at ``k`` with its current pose."""
        import cv2

        dist = self.dist.copy()
        dist[:2] = k
        out = []
        for o, u, p in zip(self.obj, self.img, self.poses, strict=True):
            proj = cv2.projectPoints(o.astype(np.float64), p[:3], p[3:], self.K, dist)[0].reshape(-1, 2)
            out.append(float(np.sqrt(np.mean(np.sum((proj - u.reshape(-1, 2)) ** 2, axis=1)))))
        return np.array(out)

    def solve(self, k0: np.ndarray, iterations: int = 12) -> tuple[np.ndarray, list, float]:
        """k1, k2 at the least-squares fit (started at ``k0``), each view's (S_i, g_i) there, and the RMS (px)."""
        k = np.asarray(k0, dtype=float).copy()
        for _ in range(iterations):
            parts, _ = self._normal(k)
            S = sum(q[0] for q in parts)
            g = sum(q[1] for q in parts)
            dk = -np.linalg.solve(S, g)
            for i, (_, _, Ainv, B, a) in enumerate(parts):
                self.poses[i] = self.poses[i] - Ainv @ (a + B @ dk)
            k = k + dk
            if np.max(np.abs(dk)) < 1e-7:
                break
        parts, rms = self._normal(k)
        return k, [(q[0], q[1]) for q in parts], rms


def distortion_from_views(uv: np.ndarray, board_points: np.ndarray, camera: CameraModel,
                          max_frames: int = MAX_FRAMES, segments: int = SEGMENTS) -> LensCheck | None:
    """k1 and k2 as the board views ``uv`` (frames x points x 2, NaN where a point was not found) of the board's
    points ``board_points`` (points x 3, metres) fit them with the rest of ``camera`` held, with a jackknife over
    ``segments`` stretches of frames. None when too few frames hold enough of the board or a fit fails."""
    import cv2

    uv = np.asarray(uv, dtype=float)
    pts = np.asarray(board_points, dtype=float)
    if uv.ndim != 3 or uv.shape[1] != pts.shape[0] or uv.shape[0] == 0:
        return None
    found = np.all(np.isfinite(uv), axis=2)
    good = np.flatnonzero(found.sum(axis=1) >= max(6, int(np.ceil(MIN_POINTS_FRACTION * pts.shape[0]))))
    if good.size < max(MIN_FRAMES, segments):
        return None
    idx = good[np.unique(np.linspace(0, good.size - 1, min(max_frames, good.size)).round().astype(int))]
    obj = [pts[found[i]].astype(np.float32) for i in idx]
    img = [uv[i][found[i]].astype(np.float32) for i in idx]
    # The radius compared at: the detections' outer radii, in the given model's normalised coordinates.
    norm = camera.undistort_pixels(np.concatenate(img))
    radius = float(np.percentile(np.hypot(norm[:, 0], norm[:, 1]), RADIUS_PERCENTILE))
    given = np.asarray(camera.dist, dtype=float)[:2].copy()
    try:
        fit = _Views(camera, obj, img)
        views, parts, rms = fit.solve(given)
        # A view that fits far worse than the others (a mislabelled grid, a wrong PnP branch) is left out, once.
        per_view = fit.view_rms(views)
        keep = per_view <= max(OUTLIER_FACTOR * float(np.median(per_view)), OUTLIER_MIN_PX)
        if not keep.all() and keep.sum() >= max(MIN_FRAMES, segments):
            idx = idx[keep]
            obj = [o for o, k in zip(obj, keep, strict=True) if k]
            img = [u for u, k in zip(img, keep, strict=True) if k]
            views, parts, rms = _Views(camera, obj, img).solve(given)
        S_all = sum(q[0] for q in parts)
        g_all = sum(q[1] for q in parts)
        reps = []
        for part in np.array_split(np.arange(len(idx)), segments):
            # Each stretch left out in turn: one Gauss-Newton step from the whole fit on the views kept.
            S_d = sum(parts[i][0] for i in part)
            g_d = sum(parts[i][1] for i in part)
            reps.append(views - np.linalg.solve(S_all - S_d, g_all - g_d))
    except (cv2.error, ValueError, np.linalg.LinAlgError):
        return None
    reps = np.array(reps)
    if not (np.all(np.isfinite(views)) and np.all(np.isfinite(reps))):
        return None
    n = len(reps)
    dev = reps - reps.mean(axis=0)
    cov = (n - 1) / n * dev.T @ dev
    shift = _radial_px(camera, views, radius) - _radial_px(camera, given, radius)
    shifts = np.array([_radial_px(camera, k, radius) for k in reps])
    shift_sigma = float(np.sqrt((n - 1) / n * np.sum((shifts - shifts.mean()) ** 2)))
    return LensCheck(given=given, views=views, cov=cov, radius=radius, shift_px=float(shift),
                     shift_sigma_px=shift_sigma, n_frames=int(len(idx)), rms_px=rms)
