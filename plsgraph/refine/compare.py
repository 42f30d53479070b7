"""Closed-form solutions and the refinement side by side: each scored by its reprojection RMS on the same
detections and, with a truth, by its errors."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..core.camera import CameraModel
from ..core.geometry import inv_T, make_T, rotation_error_deg
from ..core.tracks import BaseTrack, CameraTrack
from ..errors import InputError, InsufficientDataError
from .graph import RefinementResult, seed_translation_and_board
from .residuals import residuals

log = logging.getLogger(__name__)


def solution_rms_px(
    camera_track: CameraTrack, base_track: BaseTrack, camera: CameraModel, T_base_cam: np.ndarray, td: float,
    translation_known: bool = True,
) -> float:
    """Reprojection RMS (px) of a calibration with the odometry ``base_track`` as given and the board fitted to it.

    When ``translation_known`` is False (a rotation-only closed form), the camera translation is fitted
    by least squares first, so that the number compares rotations and td, not a missing translation.
    """
    det = camera_track.detections
    if det is None:
        raise InputError("solution_rms_px needs camera_track.detections")
    T = np.asarray(T_base_cam, dtype=float)
    if T.shape == (3, 3):
        T, translation_known = make_T(T, np.zeros(3)), False
    t_C, B = seed_translation_and_board(camera_track, base_track, T[:3, :3], td, T[:3, 3])
    if translation_known:
        t_C = T[:3, 3]
        # Board refit with the given translation: average of the per-frame board positions.
        tau = camera_track.t + td
        ok = (tau >= base_track.t[0]) & (tau <= base_track.t[-1])
        Tw = base_track.poses_at(tau[ok]) @ make_T(T[:3, :3], t_C) @ inv_T(camera_track.T_board_cam[ok])
        B = make_T(B[:3, :3], np.median(Tw[:, :3, 3], axis=0))
    _, r = residuals(det, base_track, camera, make_T(T[:3, :3], t_C), td, B)
    e2 = np.sum(r**2, axis=-1)
    if not np.any(np.isfinite(e2)):  # no detection falls inside the odometry under this solution's td
        return float("nan")
    return float(np.sqrt(np.nanmean(e2)))


@dataclass(frozen=True)
class ComparisonTable:
    rows: tuple[dict, ...]
    markdown: str


def _as_solution(sol) -> tuple[np.ndarray, float | None, bool]:
    """(T or R, td or None, translation known) from a RotationResult, RefinementResult, array or dict."""
    if isinstance(sol, RefinementResult):
        return sol.T_base_cam, sol.td, True
    if isinstance(sol, Mapping):
        if "T_base_cam" in sol:
            return np.asarray(sol["T_base_cam"], float), sol.get("td"), True
        R = np.asarray(sol["R_base_cam"], float)
        t = sol.get("t_base_cam")
        return (make_T(R, t), sol.get("td"), True) if t is not None else (R, sol.get("td"), False)
    if hasattr(sol, "R_base_cam"):
        t = getattr(sol, "t_base_cam", None)
        R = np.asarray(sol.R_base_cam, float)
        return (make_T(R, t), getattr(sol, "td", None), True) if t is not None else (R, getattr(sol, "td", None), False)
    a = np.asarray(sol, float)
    return a, None, a.shape == (4, 4)


def _height_unobserved(refinement: RefinementResult) -> bool:
    """Whether the refinement left the camera height at its seed (planar motion, no height given)."""
    obs = getattr(refinement, "observability", None)
    return any(a.name == "z" and a.status != "observable" for a in (obs.axes if obs is not None else ()))


def compare_solutions(
    solutions: Mapping[str, object],
    refinement: RefinementResult,
    *,
    camera_track: CameraTrack | None = None,
    base_track: BaseTrack | None = None,
    camera: CameraModel | None = None,
    truth_T_base_cam: np.ndarray | None = None,
    truth_td: float | None = None,
) -> ComparisonTable:
    """One table comparing closed-form solutions with the refinement.

    ``solutions``: name -> closedform.RotationResult, a 3 x 3 rotation, a 4 x 4 transform or a dict with
    ``R_base_cam`` / ``T_base_cam`` (and optionally ``t_base_cam``, ``td``). A solution without td uses
    the refinement's seed td. With truth: rotation error (deg), translation and xy errors (m), td error
    (ms). Without: differences to the refinement. With the tracks and the camera: reprojection RMS (px), every
    solution under the odometry as the refinement's estimated speed and turn scales correct it (when it has them).
    """
    entries = dict(solutions)
    entries["refined"] = refinement
    rows = []
    have_tracks = camera_track is not None and base_track is not None and camera is not None
    odo = getattr(refinement, "odometry", None) or {}
    if have_tracks and odo.get("speed_scale") is not None and odo.get("turn_scale") is not None:
        # Every solution is scored under the odometry as the refinement corrected it (effective wheel radius and
        # track): taken as is, a skid-steer robot's track makes every answer's residuals large, the best one's too.
        from .graph import scaled_base_track

        base_track = scaled_base_track(base_track, float(odo["speed_scale"]), float(odo["turn_scale"]))
    for name, sol in entries.items():
        T, td, t_known = _as_solution(sol)
        td = refinement.seed_td if td is None else float(td)
        R = T[:3, :3]
        row: dict = {"method": name}
        ref_T = refinement.T_base_cam if truth_T_base_cam is None else np.asarray(truth_T_base_cam, float)
        z_unknown = t_known and T.shape == (4, 4) and not np.isfinite(T[2, 3])
        if name == "refined" and _height_unobserved(refinement):
            z_unknown = t_known and T.shape == (4, 4)  # its z is the seed's: no error to report (x, y are scored)
        if z_unknown:  # a planar closed form knows x, y only: borrow the reference height to score the rest
            T = T.copy()
            T[2, 3] = ref_T[2, 3]
        ref_td = refinement.td if truth_td is None else float(truth_td)
        key = "err" if truth_T_base_cam is not None else "diff"
        row[f"rot_{key}_deg"] = float(rotation_error_deg(R, ref_T[:3, :3]))
        if t_known and T.shape == (4, 4):
            dt = T[:3, 3] - ref_T[:3, 3]
            row[f"t_{key}_m"] = float("nan") if z_unknown else float(np.linalg.norm(dt))
            row[f"t_xy_{key}_m"] = float(np.linalg.norm(dt[:2]))
        else:
            row[f"t_{key}_m"] = float("nan")
            row[f"t_xy_{key}_m"] = float("nan")
        if truth_td is not None or name != "refined":
            row[f"td_{key}_ms"] = float(1e3 * (td - ref_td))
        else:
            row[f"td_{key}_ms"] = 0.0
        if have_tracks:
            try:
                row["rms_px"] = solution_rms_px(camera_track, base_track, camera, T, td, t_known)
            except (InputError, InsufficientDataError) as exc:
                log.warning("rms of %s: %s", name, exc)
                row["rms_px"] = float("nan")
        # The refinement's own RMS, over the frames it kept and with its per-frame board poses: every row has the key
        # (NaN but for the refined one), so that a script reads one set of columns.
        row["rms_px_graph"] = float(refinement.rms_px_final) if name == "refined" else float("nan")
        rows.append(row)
    cols = list(dict.fromkeys(k for r in rows for k in r))
    md = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = [r["method"]] + [("" if k not in r or (k == "rms_px_graph" and r["method"] != "refined")
                                  else f"{r[k]:.4g}" if np.isfinite(r[k]) else "-") for k in cols[1:]]
        md.append("| " + " | ".join(cells) + " |")
    if any(not np.isfinite(v) for r in rows for k, v in r.items() if k not in ("method", "rms_px_graph")):
        md.append("\n-: not determined (a solver that gives the rotation only has no translation; where the camera "
                  "height is unknown, t is not scored, t_xy is; rms_px where the solution could not be replayed)")
    if have_tracks:
        md.append("\nrms_px: every answer replayed the same way (the board's pose from the odometry through the answer "
                  "and td, one pose for the whole drive), so the rows compare; rms_px_graph: the refinement's own fit, "
                  "over the frames it kept, with the base's path estimated beside the extrinsic (the odometry a soft "
                  "constraint on it), so smaller")
    return ComparisonTable(tuple(rows), "\n".join(md))


