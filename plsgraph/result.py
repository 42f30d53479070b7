"""Typed results of the library calls: :class:`CalibrationResult`, :class:`Diagnosis`, :class:`Comparison`.

Each is a frozen value with ``to_dict()`` (what report.json holds); people read them through
:mod:`plsgraph.report.text`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .core.geometry import make_T, rotation_error_deg
from .gate import problems_of_run
from .pipeline import Run
from .report.files import COVARIANCE_ORDER, calibration_dict, to_jsonable

HEIGHT_FROM_USER = "--camera-height prior"
HEIGHT_FROM_BOARD = "--board-height prior (through the board)"
HEIGHT_UNMEASURED = "not observable from planar motion: unknown, written as 0; measure it (--camera-height)"


def height_source(run: Run) -> str | None:
    """Where the camera height comes from (None: nowhere - it is unknown)."""
    if run.options.refine.camera_height is not None:
        return HEIGHT_FROM_USER
    ref = run.refinement
    if run.options.refine.board_height is not None and ref is not None and ref.converged:
        return HEIGHT_FROM_BOARD
    return None


def odometry_section(run: Run) -> dict | None:
    """calibration.yaml's ``odometry``: the effective wheel radius and track width the refinement estimated."""
    ref = run.refinement
    o = None if ref is None or not ref.converged else getattr(ref, "odometry", None)
    if o and "wheel_radius_m" not in o and "speed_scale" in o:
        # nav_msgs/Odometry: no wheel radius or track to name, the scales the data put on its distances and turns.
        return {
            "wheel_radius_m": None, "track_width_m": None, "wheel_radius_sigma_m": None, "track_width_sigma_m": None,
            "speed_scale": o["speed_scale"], "speed_scale_sigma": o.get("speed_scale_sigma"),
            "turn_rate_scale": o["turn_scale"], "turn_rate_scale_sigma": o.get("turn_scale_sigma"),
            "status": {{"wheel_radius": "speed_scale", "track_width": "turn_rate_scale"}.get(k, k): v
                       for k, v in dict(o.get("status", {})).items()},
            "note": "the odometry messages' speeds and turn rates times these scales are what the camera sees (the "
                    "messages carry no wheel radius or track width: correct the odometry source's own parameters "
                    "by them, e.g. a turn_rate_scale of 0.67 is a track width 1.5 x the one it uses)",
        }
    if not o or "wheel_radius_m" not in o:
        return None
    floor = o.get("wheel_radius_model_sigma_rel") or 0.0
    return {
        "wheel_radius_m": o["wheel_radius_m"],
        "track_width_m": o["track_width_m"],
        "wheel_radius_sigma_m": o.get("wheel_radius_sigma_m"),
        "track_width_sigma_m": o.get("track_width_sigma_m"),
        "wheel_radius_nominal_m": o.get("wheel_radius_nominal_m"),
        "track_width_nominal_m": o.get("track_width_nominal_m"),
        "status": dict(o.get("status", {})),
        "note": "effective values that explain the wheel odometry (a skid-steer robot's track is wider than its "
                "geometric one); in the board's length unit and the camera's scale (a misprinted board, or camera "
                "intrinsics whose focal length is off, scales the radius alike; their error is not in the sigmas). "
                "The sigmas hold the extrinsic's uncertainty they are correlated with"
                + (f", and the radius's {100 * floor:.2g} % for the event detector's sense of the board's size"
                   if floor else ""),
    }


@dataclass(frozen=True)
class CalibrationResult:
    """One calibration: the extrinsic, the time offset, how sure, and whether it is fit to use.

    ``covariance`` (7 x 7, or None when the refinement did not run or converge) is in base axes, parameter order
    ``covariance_order`` (roll, pitch, yaw [rad], x, y, z [m], td [s]). ``closed_form`` holds every closed-form
    solver's answer by name; ``refinement`` the optimizer's statistics. ``ok`` is False when the result is flagged:
    ``problems`` says why.
    """

    recording: str
    ok: bool
    problems: tuple[str, ...]
    source: str
    T_base_cam: np.ndarray
    time_offset_s: float
    covariance: np.ndarray | None
    covariance_order: tuple[str, ...]
    observability: tuple[dict, ...]
    closed_form: dict[str, dict]
    refinement: dict | None
    warnings: tuple[str, ...]
    truth_errors: dict | None
    report: dict = field(repr=False)
    run: Run | None = field(default=None, repr=False, compare=False)

    @property
    def R_base_cam(self) -> np.ndarray:
        return self.T_base_cam[:3, :3]

    @property
    def sigmas(self) -> dict[str, float] | None:
        """One-sigma per parameter (rad, m, s) in ``covariance_order``, or None."""
        if self.covariance is None:
            return None
        return dict(zip(self.covariance_order, np.sqrt(np.diag(self.covariance)).tolist(), strict=True))

    def to_dict(self) -> dict:
        """Everything, JSON-ready (the content of report.json)."""
        return to_jsonable(dict(self.report))


@dataclass(frozen=True)
class Diagnosis:
    """Is a recording good enough, and which motion is missing?"""

    recording: str
    ok: bool
    problems: tuple[str, ...]
    advice: tuple[str, ...]
    excitation: dict[str, float] = field(default_factory=dict)
    observable_closed_form: dict[str, bool] = field(default_factory=dict)
    observability: tuple[dict, ...] = ()
    degenerate_reasons: tuple[str, ...] = ()
    camera_frames: int | None = 0  # None: the run stopped before the board was searched for
    odometry_samples: int = 0
    warnings: tuple[str, ...] = ()  # what the run said along the way (as calibrate's report.json "warnings")
    clock_alignment: dict = field(default_factory=dict)  # how the two clocks were put together (calibrate's too)

    def to_dict(self) -> dict:
        return to_jsonable({
            "recording": self.recording, "ok": self.ok, "problems": list(self.problems), "advice": list(self.advice),
            "excitation": self.excitation, "observable_closed_form": self.observable_closed_form,
            "observability": list(self.observability), "degenerate_reasons": list(self.degenerate_reasons),
            "camera_frames": self.camera_frames, "odometry_samples": self.odometry_samples,
            "warnings": list(self.warnings), "clock_alignment": self.clock_alignment,
        })


@dataclass(frozen=True)
class Comparison:
    """Every closed-form solver and the refinement side by side (errors against the truth when given)."""

    recording: str
    rows: tuple[dict, ...]
    failed: dict[str, str]
    markdown: str
    ok: bool = True
    problems: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()  # what the run said along the way (as calibrate's report.json "warnings")

    def to_dict(self) -> dict:
        return to_jsonable({"recording": self.recording, "ok": self.ok, "problems": list(self.problems),
                            "warnings": list(self.warnings), "rows": list(self.rows), "failed": self.failed})


# ------------------------------------------------------------------------------------------------ building


def method_rows(run: Run) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for name, m in run.closed_form.methods.items():
        out[name] = {
            "R_base_cam": None if m.R_base_cam is None else np.asarray(m.R_base_cam).tolist(),
            "t_base_cam": None if m.t_base_cam is None else np.asarray(m.t_base_cam).tolist(),
            "error": m.error,
            "warnings": list(m.warnings),
            "diagnostics": to_jsonable(m.diagnostics),
        }
    return out


def observability_rows(run: Run) -> list[dict]:
    ref = run.refinement
    if ref is None or ref.observability is None:
        return []
    return [
        {"direction": a.description or a.name, "name": a.name, "status": a.status, "sigma": a.sigma,
         "unit": a.unit, "note": a.message}
        for a in ref.observability.axes
    ]


def truth_errors(run: Run) -> dict | None:
    if run.truth is None:
        return None
    T_gt = np.asarray(run.truth["T_base_cam"], dtype=float)
    td_gt = float(run.truth.get("td", run.truth.get("time_offset_s", float("nan"))))
    out: dict[str, Any] = {}
    cf = run.closed_form
    if cf is not None:
        for name, m in cf.methods.items():
            if m.R_base_cam is not None:
                out[f"closed_form.{name}.rot_err_deg"] = float(rotation_error_deg(m.R_base_cam, T_gt[:3, :3]))
        if cf.t_xy is not None:
            out["closed_form.t_xy_err_m"] = float(np.linalg.norm(np.asarray(cf.t_xy) - T_gt[:2, 3]))
        out["closed_form.td_err_ms"] = 1e3 * (cf.td + run.clock_offset_s - td_gt)
    ref = run.refinement
    if ref is not None:
        out["refined.rot_err_deg"] = float(rotation_error_deg(ref.R_base_cam, T_gt[:3, :3]))
        out["refined.t_xy_err_m"] = float(np.linalg.norm(ref.T_base_cam[:2, 3] - T_gt[:2, 3]))
        rs = run.options.refine
        if rs.camera_height is not None or rs.board_height is not None:  # else z is not measured: written as 0
            out["refined.t_z_err_m"] = float(ref.T_base_cam[2, 3] - T_gt[2, 3])
        out["refined.td_err_ms"] = 1e3 * (ref.td + run.clock_offset_s - td_gt)
    return out


def robot_sections(run: Run) -> dict[str, Any]:
    """calibration.yaml's ``odometry`` section (the wheel geometry the data support), ``wheel_order``, ``focal_length``
    (what the focal length's accuracy is worth), ``lens_distortion`` (the board views' check of the camera info's) and
    ``clock``."""
    odo = run.options.odometry
    refined = odometry_section(run)
    scale = dict(getattr(run.closed_form, "odometry_scale", None) or {})
    sec: dict[str, Any] = {
        "nominal_wheel_radius_m": odo.wheel_radius,
        "nominal_track_width_m": odo.track_width,
        "effective_wheel_radius_m": scale.get("wheel_radius_m"),
        "effective_track_width_m": scale.get("track_width_m"),
        "speed_scale": scale.get("speed"),
        "turn_rate_scale": scale.get("turn_rate"),
        "source": ("closed form (odometry speed and turn-rate scales against the camera), without uncertainty"
                   + ("" if run.refinement is None else "; the refinement kept the nominal geometry"))
        if scale else "nominal (not estimated)",
        "base_source": run.recording_info.get("base_source"),
    }
    if refined is not None:  # estimated jointly with the extrinsic, with uncertainty: what the driver should take
        sec = {**refined, "source": "refinement (jointly with T_base_cam and td)",
               "closed_form_wheel_radius_m": sec["effective_wheel_radius_m"],
               "closed_form_track_width_m": sec["effective_track_width_m"], "base_source": sec["base_source"]}
    elif str(sec["base_source"] or "").startswith("nav_msgs"):  # no wheels: the nominal geometry is not its own
        sec = {"wheel_radius_m": None, "track_width_m": None, "wheel_radius_sigma_m": None,
               "track_width_sigma_m": None, **sec}
    else:
        sec = {"wheel_radius_m": sec["effective_wheel_radius_m"] or odo.wheel_radius,
               "track_width_m": sec["effective_track_width_m"] or odo.track_width,
               "wheel_radius_sigma_m": None, "track_width_sigma_m": None, **sec}
    out: dict[str, Any] = {"odometry": sec}
    wo = run.recording_info.get("wheel_order")
    if wo is not None:
        out["wheel_order"] = {k: wo[k] for k in ("hypothesis", "description", "decided", "corrected", "mount_unstated",
                                                     "message")
                              if k in wo}
    sens = None if run.refinement is None else (getattr(run.refinement, "inflation", None) or {}).get(
        "focal_length_sensitivity")
    if sens and sens.get("focal_change"):
        per = 0.01 / float(sens["focal_change"])
        out["focal_length"] = {
            "move_per_percent": {f"{a}_m" if a in ("x", "y") else ("td_s" if a == "td" else f"{a}_deg"):
                                 per * float(sens[a]) * (1.0 if a in ("x", "y", "td") else 180.0 / np.pi)
                                 for a in ("roll", "pitch", "yaw", "x", "y", "td")},
            "sigma_in_sigmas": float(sens.get("focal_sigma_in_sigmas") or 0.0),
            "note": "how far the calibration moves for a focal length 1 % longer than the camera info's (first order); "
                    "the sigmas hold a focal-length error of sigma_in_sigmas (relative, --focal-sigma; 0: none)",
        }
    lens = getattr(run, "lens", None)
    if lens is not None:
        sec = {**lens.to_dict(), "note": "the radial distortion the board views fit with the rest of the intrinsics "
               "held, against the camera info's; shift_px: the two models' difference at the board's outer image "
               "radius (radius_normalised), with its jackknife sigma; significant: beyond 3 sigma and 0.3 px"}
        move = None if run.refinement is None else (getattr(run.refinement, "inflation", None) or {}).get(
            "lens_distortion_move")
        if move:
            sec["calibration_move"] = {
                f"{a}_m" if a in ("x", "y") else ("td_s" if a == "td" else f"{a}_deg"):
                float(move[a]) * (1.0 if a in ("x", "y", "td") else 180.0 / np.pi)
                for a in ("roll", "pitch", "yaw", "x", "y", "td")}
            sec["note"] += "; calibration_move: how far the calibration moves with the views' k1, k2 (first order)"
        out["lens_distortion"] = sec
    clock = run.recording_info.get("clock")
    if clock is not None:
        out["clock_alignment"] = {k: clock[k] for k in ("coarse", "rule", "offset_s", "score", "second_peak_ratio",
                                                        "separation") if k in clock}
    return out


def final_estimate(run: Run) -> tuple[np.ndarray, float, np.ndarray | None, str]:
    """(T_base_cam, td, covariance or None, source) of the best result the run has."""
    ref = run.refinement
    if ref is not None and ref.converged:
        return ref.T_base_cam, ref.td, ref.cov_base_axes, "refined"
    cf = run.closed_form
    t = np.asarray(cf.t_base_cam if cf.t_base_cam is not None else np.full(3, np.nan), dtype=float).copy()
    # Planar motion never gives the height: report the user's --camera-height (or 0) rather than a NaN that
    # would poison the transform; the observability list and the warnings say it is not measured.
    h = run.options.refine.camera_height
    t[2] = h if h is not None else 0.0
    if not np.all(np.isfinite(t[:2])):
        t[:2] = 0.0
        run.warn("the closed form did not determine the camera position; translation_m is not measured")
    run.warn("translation z (camera height) is not measured by the closed form: "
             + ("it is --camera-height" if h is not None else "it is set to 0; give --camera-height"))
    return make_T(cf.R_base_cam, t), cf.td, None, f"closed_form.{cf.method}"


#: Below this share of the windows in which the robot moved with the board found, the result warns.
LOW_COVERAGE = 0.5


def _coverage(run: Run) -> dict | None:
    """The front end's window outcomes counted (report.json ``coverage``); a warning when the board was missed in
    most windows in which the robot moved."""
    from .report.coverage import coverage_summary

    track = run.camera_track
    cov = None if track is None else coverage_summary(track.info, run)
    if cov is not None and cov["found_fraction_robot_moving"] is not None \
            and cov["found_fraction_robot_moving"] < LOW_COVERAGE:
        run.warn(f"the board was found in only {100 * cov['found_fraction_robot_moving']:.0f} % of the windows in "
                 "which the robot moved (report.html 'Detection coverage' says why); the calibration rests on the "
                 "rest")
    return cov


def calibration_result(run: Run) -> CalibrationResult:
    """The typed result (and its report dict) of a solved run."""
    from . import __version__

    T, td, cov, source = final_estimate(run)
    td = td + run.clock_offset_s  # the camera track was shifted onto the odometry clock by that much
    problems = problems_of_run(run, T_base_cam=T)
    ok = not problems
    height = height_source(run)
    obs = observability_rows(run)
    if height is None:
        for row in obs:
            if row["name"] == "z":
                row["status"] = "unobservable"
                row["note"] = ("The camera height is not observable from driving on a flat floor; it is unknown and "
                               "written as 0. Measure it and pass --camera-height (or the board's --board-height).")
    mount = run.options.mount
    extra: dict[str, Any] = {"source": source, "translation_z_source": height or HEIGHT_UNMEASURED,
                             **robot_sections(run)}
    calib = calibration_dict(T, td, cov, obs, parent_frame=mount.parent_frame, child_frame=mount.child_frame,
                             extra=extra, ok=ok, problems=problems, z_known=height is not None)
    if height is None:
        T = T.copy()
        T[2, 3] = 0.0
    cf = run.closed_form
    methods = method_rows(run)
    errs = truth_errors(run)
    coverage = _coverage(run)
    report: dict[str, Any] = {
        "plsgraph_version": __version__,
        "recording": str(Path(run.log_path).absolute()),
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "ok": ok,
        "problems": problems,
        "calibration": calib,
        "closed_form": methods,
        "closed_form_summary": {
            "method": cf.method,
            "R_base_cam": None if cf.R_base_cam is None else np.asarray(cf.R_base_cam).tolist(),
            "t_xy": None if cf.t_xy is None else np.asarray(cf.t_xy).tolist(),
            "td": cf.td + run.clock_offset_s,
            "observable": dict(cf.observable),
            "excitation": dict(cf.excitation),
            "n_pairs": cf.n_pairs,
            "degenerate": cf.degenerate,
            "degenerate_reasons": list(cf.degenerate_reasons),
            "td_at_border": bool(getattr(cf, "td_at_border", False)),
        },
        "time_offset": None
        if cf.time_offset is None
        else {
            "td_s": cf.time_offset.td + run.clock_offset_s,
            "clock_shift_s": run.clock_offset_s,
            "score": cf.time_offset.score,
            "sharpness": cf.time_offset.sharpness,
            "second_peak_ratio": cf.time_offset.second_peak_ratio,
            "method": cf.time_offset.method,
            "ok": cf.time_offset.ok,
        },
        "refinement": None if run.refinement is None else run.refinement.to_dict(),
        "options": run.options.to_dict(),
        "recording_info": run.recording_info,
        "coverage": coverage,
        "counts": {
            "camera_frames": len(run.camera_track) if run.camera_track is not None else 0,
            "odometry_samples": len(run.base_track) if run.base_track is not None else 0,
        },
        "discarded": run.discarded,
        "warnings": run.warnings,
        "timing_s": run.timing_s,
    }
    if errs is not None:
        report["truth_errors"] = errs
    report = to_jsonable(report)
    ref_stats = None
    if run.refinement is not None:
        ref_stats = {k: v for k, v in report["refinement"].items() if not isinstance(v, list)}
    return CalibrationResult(
        recording=str(run.log_path), ok=ok, problems=tuple(problems), source=source,
        T_base_cam=np.asarray(T, dtype=float), time_offset_s=float(td),
        covariance=None if cov is None else np.asarray(cov, dtype=float), covariance_order=tuple(COVARIANCE_ORDER),
        observability=tuple(obs), closed_form=methods, refinement=ref_stats, warnings=tuple(run.warnings),
        truth_errors=errs, report=report, run=run,
    )

