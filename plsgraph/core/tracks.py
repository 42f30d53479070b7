"""Trajectory containers shared by the front ends, the alignment, the closed form and the graph.

Both are frozen dataclasses of numpy arrays (struct of arrays). Times are float64 seconds, each in
its own sensor's clock: a camera sample at ``t`` belongs to odometry time ``t + td``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from .geometry import PoseInterpolator


def _check_times(name: str, t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    if t.ndim != 1:
        raise InputError(f"{name}: times must be a 1-D array")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{name}: times contain NaN or inf")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        raise InputError(f"{name}: times must be strictly increasing (sort the stream and drop duplicates)")
    return t


def _check_poses(name: str, T: np.ndarray, n: int) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (n, 4, 4):
        raise InputError(f"{name}: poses must have shape ({n}, 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{name}: poses contain NaN or inf")
    return T



def gap_indices(t: np.ndarray, gap_factor: float, min_gap_s: float = 0.0) -> np.ndarray:
    """Indices k of the steps t[k] -> t[k + 1] longer than ``gap_factor`` times the median step and than
    ``min_gap_s``: the one definition of a gap in a sampled stream."""
    d = np.diff(np.asarray(t, dtype=float))
    if d.size == 0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(d > max(gap_factor * float(np.median(d)), min_gap_s))


@dataclass(frozen=True)
class Detections:
    """Board detections, one row per image frame.

    ``uv`` (m, N, 2) pixel coordinates of the N board points (NaN where a point was not seen);
    ``t`` (m,) the camera time the centres correspond to; ``board_points`` (N, 3) in the board frame.
    """

    t: np.ndarray
    uv: np.ndarray
    board_points: np.ndarray

    def __post_init__(self) -> None:
        t = _check_times("detections", self.t)
        uv = np.asarray(self.uv, dtype=float)
        pts = np.asarray(self.board_points, dtype=float)
        if uv.ndim != 3 or uv.shape[0] != t.size or uv.shape[2] != 2 or uv.shape[1] != pts.shape[0]:
            raise InputError(f"detections: uv shape {uv.shape} does not match {t.size} frames x {pts.shape[0]} points")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "board_points", pts)

    def __len__(self) -> int:
        return int(self.t.size)

    def subset(self, mask: np.ndarray) -> Detections:
        return Detections(self.t[mask], self.uv[mask], self.board_points)


# A track's interpolator is made on its first poses_at and kept (tracks are not changed once made; the closed
# form's time-offset search interpolates one base track at some 80 shifts).
_INTERPOLATOR = "_pose_interpolator"


def _interpolator(track, T: np.ndarray) -> PoseInterpolator:
    f = track.__dict__.get(_INTERPOLATOR)
    if f is None:
        f = PoseInterpolator(track.t, T)
        object.__setattr__(track, _INTERPOLATOR, f)
    return f


def _without_interpolator(track) -> dict:
    """The track's state for pickling, without its interpolator (made again when needed)."""
    return {k: v for k, v in track.__dict__.items() if k != _INTERPOLATOR}


#: Lists of a camera track's ``info`` (the front end's bookkeeping) with one entry per detection, kept aligned with
#: the detections: which detector found each, the span of events it was found on (multiples of the window), and the
#: end of the window it was found in (s; the detection's own stamp is the mean time of its events, up to half a span
#: earlier).
PER_FRAME_INFO = ("detector", "span_windows", "window_t")


@dataclass(frozen=True)
class CameraTrack:
    """Camera poses relative to the board, ``T_board_cam`` (n, 4, 4), at camera times ``t`` (n,).

    ``cov`` (n, 6, 6) is the pose covariance in the tangent space of T_board_cam (rotation first,
    right perturbation, GTSAM convention); ``rms_px`` (n,) the per-frame reprojection RMS.
    ``detections`` keeps the pixel measurements the poses came from, for the reprojection factors.
    """

    t: np.ndarray
    T_board_cam: np.ndarray
    cov: np.ndarray | None = None
    rms_px: np.ndarray | None = None
    detections: Detections | None = None
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _check_times("camera track", self.t)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "T_board_cam", _check_poses("camera track", self.T_board_cam, t.size))

    def __len__(self) -> int:
        return int(self.t.size)

    def poses_at(self, t_query: np.ndarray) -> np.ndarray:
        """Poses at ``t_query`` (:func:`~plsgraph.core.geometry.interpolate_poses`)."""
        return _interpolator(self, self.T_board_cam)(t_query)

    def __getstate__(self) -> dict:
        return _without_interpolator(self)


@dataclass(frozen=True)
class BaseTrack:
    """Robot base poses ``T_world_base`` (n, 4, 4) at odometry times ``t`` (n,).

    ``v`` (n, 3) linear and ``omega`` (n, 3) angular velocity of the base expressed in the base
    frame (for a differential drive v = (v, 0, 0), omega = (0, 0, w)).
    """

    t: np.ndarray
    T_world_base: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _check_times("base track", self.t)
        n = t.size
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "T_world_base", _check_poses("base track", self.T_world_base, n))
        for name in ("v", "omega"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n, 3) or not np.all(np.isfinite(a)):
                raise InputError(f"base track: {name} must be finite with shape ({n}, 3), got {a.shape}")
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return int(self.t.size)

    def poses_at(self, t_query: np.ndarray) -> np.ndarray:
        """Poses at ``t_query`` (:func:`~plsgraph.core.geometry.interpolate_poses`)."""
        return _interpolator(self, self.T_world_base)(t_query)

    def __getstate__(self) -> dict:
        return _without_interpolator(self)
