"""Orchestration behind the command: recording -> tracks -> closed form -> refinement -> result files.

Each public function here is what one ``plsgraph`` subcommand does, callable from scripts too. They
raise typed errors for user mistakes and return plain dicts (``text`` for people, ``json`` for scripts).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .board import Board, load_board
from .camera import CameraModel
from .errors import (
    ConvergenceError,
    DegenerateMotionError,
    InputError,
    InsufficientDataError,
    PlsgraphError,
    RecordingError,
)
from .events import EventStream
from .geometry import make_T, rotation_error_deg
from .report import calibration_dict, markdown_table, prepare_output_dir, to_jsonable, write_json, write_yaml
from .tracks import BaseTrack, CameraTrack

log = logging.getLogger(__name__)

ProgressFactory = Callable[[str], Any]  # label -> context manager that is also a progress(done, total) callable


class _NoProgress:
    def __call__(self, done: int, total: int) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def _no_progress(label: str) -> _NoProgress:
    return _NoProgress()


def terminal_progress(label: str):
    from .progress import ProgressBar

    return ProgressBar(label)


@dataclass(frozen=True)
class PipelineOptions:
    """Everything a user can set about one calibration run (the CLI flags, as a value)."""

    board: str = "acircles_4x11"
    camera_info: Path | None = None
    wheel_radius: float = 0.098
    track_width: float = 0.37
    topics: dict[str, str] = field(default_factory=dict)
    left_joint: str | None = None
    right_joint: str | None = None
    surface: str = "count"
    rate_hz: float = 30.0
    td_range: float = 0.5
    method: str = "pls"
    truth: Path | None = None
    camera_height: float | None = None

    def __post_init__(self) -> None:
        for name in ("wheel_radius", "track_width", "rate_hz", "td_range"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                flag = {"rate_hz": "rate"}.get(name, name).replace("_", "-")
                raise InputError(f"--{flag} must be a positive number, got {v!r}")
        if self.camera_height is not None and not math.isfinite(self.camera_height):
            raise InputError(f"--camera-height must be a finite number of metres, got {self.camera_height!r}")

    @classmethod
    def from_namespace(cls, args) -> PipelineOptions:
        topics = {
            role: getattr(args, attr)
            for role, attr in (("events", "events_topic"), ("joints", "joints_topic"), ("odometry", "odom_topic"))
            if getattr(args, attr, None)
        }
        return cls(
            board=args.board,
            camera_info=getattr(args, "camera_info", None),
            wheel_radius=args.wheel_radius,
            track_width=args.track_width,
            topics=topics,
            left_joint=getattr(args, "left_joint", None),
            right_joint=getattr(args, "right_joint", None),
            surface=getattr(args, "surface", "count"),
            rate_hz=getattr(args, "rate", 30.0),
            td_range=getattr(args, "td_range", 0.5),
            method=getattr(args, "method", "pls"),
            truth=getattr(args, "truth", None),
            camera_height=getattr(args, "camera_height", None),
        )


@dataclass
class PipelineRun:
    """What one run produced; filled step by step so a failure late keeps what came before."""

    log_path: Path
    options: PipelineOptions
    board: Board | None = None
    camera: CameraModel | None = None
    camera_track: CameraTrack | None = None
    base_track: BaseTrack | None = None
    closed_form: Any = None
    refinement: Any = None
    truth: dict | None = None
    warnings: list[str] = field(default_factory=list)
    discarded: dict[str, Any] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    recording_info: dict[str, Any] = field(default_factory=dict)


class _Timer:
    def __init__(self, run: PipelineRun, name: str):
        self.run, self.name = run, name

    def __enter__(self):
        self.t0 = time.perf_counter()

    def __exit__(self, *exc) -> None:
        self.run.timing_s[self.name] = round(time.perf_counter() - self.t0, 4)


# ------------------------------------------------------------------------------------------------ steps


def _load_truth(opts: PipelineOptions, log_path: Path) -> dict | None:
    if opts.truth is None:
        return None
    import yaml

    from .io.writer import read_truth

    p = Path(opts.truth)
    if p.is_file():
        try:
            t = yaml.safe_load(p.read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise InputError(f"truth file {p} is not valid YAML: {exc}") from exc
    else:
        t = read_truth(p)  # a recording's path: its <name>.truth.yaml sidecar
    if not isinstance(t, dict) or np.asarray(t.get("T_base_cam", []), dtype=float).shape != (4, 4):
        raise InputError(f"truth file {p} must be a mapping with a 4 x 4 T_base_cam (and td)")
    return t


def read_inputs(run: PipelineRun, progress: ProgressFactory) -> Any:
    """Read the recording; fill camera and board; return the Recording."""
    from .io.recording import read_recording

    opts = run.options
    run.board = load_board(opts.board)
    if not Path(run.log_path).exists():
        raise InputError(f"recording {run.log_path} does not exist")
    with _Timer(run, "read"):
        # Everything but the events: those are streamed through the front end later, in bounded memory.
        rec = read_recording(run.log_path, topics={k: v for k, v in opts.topics.items() if k != "events"} or None,
                             with_events=False)
    run.warnings += list(rec.warnings)
    if rec.lost:
        run.discarded["lost_while_reading"] = dict(rec.lost)
    run.recording_info = {"used_topics": dict(rec.used_topics)}
    if opts.camera_info is not None:
        run.camera = CameraModel.from_yaml(opts.camera_info)
    elif rec.camera is not None:
        run.camera = rec.camera
    else:
        raise InputError(
            f"{run.log_path} has no sensor_msgs/CameraInfo topic; pass the intrinsics with --camera-info FILE "
            "(a plsgraph or ROS camera_calibration YAML)"
        )
    return rec


def build_base_track(run: PipelineRun, rec: Any) -> BaseTrack:
    from .odometry import base_track_from_odometry

    opts = run.options
    have_odom = rec.odometry is not None and len(rec.odometry.t) > 1
    use_joints = rec.joints is not None and len(rec.joints) > 1 and "odometry" not in opts.topics
    if use_joints and have_odom and opts.left_joint is None and not any("wheel" in j.lower() for j in rec.joints.names):
        use_joints = False  # joints without a wheel among them (an arm, a gripper): the odometry is the base
        run.warnings.append(f"no wheel among the joints {', '.join(rec.joints.names)}; used nav_msgs/Odometry")
    if use_joints:
        track = _wheel_track(run, rec.joints)
    elif have_odom:
        o = rec.odometry
        track = base_track_from_odometry(
            o.t.astype(np.float64) * 1e-9, o.position, o.orientation, linear=o.linear, angular=o.angular
        )
        run.recording_info["base_source"] = "nav_msgs/Odometry"
    else:
        raise RecordingError(
            f"{run.log_path} has neither wheel joint states nor odometry messages; "
            "record sensor_msgs/JointState or nav_msgs/Odometry, or name the topic with --joints-topic/--odom-topic"
        )
    run.warnings += list(track.info.get("warnings", []))
    return track


def _wheel_track(run: PipelineRun, joints: Any) -> BaseTrack:
    """BaseTrack from wheel joint states: angles unwrapped, repeated stamps dropped, rates if angles are missing."""
    from .odometry import base_track_from_wheels

    opts = run.options
    try:
        lc, rc = joints.wheel_columns(opts.left_joint, opts.right_joint)
    except InputError as exc:
        raise InputError(f"{exc}; name them with --left-joint/--right-joint") from exc
    run.recording_info["wheel_joints"] = {"left": [joints.names[i] for i in lc], "right": [joints.names[i] for i in rc]}
    t = joints.t.astype(np.float64) * 1e-9
    # Per joint, before the sides are averaged: unwrap angles that a driver reports in [-pi, pi) (a wrap of one
    # wheel of a pair would move the average by only ~pi, below what unwrapping catches), and fill each joint
    # onto every stamp, as drivers that publish each wheel in its own message leave the others NaN.
    pos = np.column_stack([_fill_unwrapped(t, joints.position[:, c], unwrap=True) for c in lc + rc])
    vel = np.column_stack([_fill_unwrapped(t, joints.velocity[:, c], unwrap=False) for c in lc + rc])
    nl = len(lc)
    left, right = pos[:, :nl].mean(axis=1), pos[:, nl:].mean(axis=1)
    left_rate, right_rate = vel[:, :nl].mean(axis=1), vel[:, nl:].mean(axis=1)
    keep = np.r_[True, np.diff(joints.t) > 0]  # a driver that republishes a state repeats its stamp
    if not np.all(keep):
        run.discarded["joint_states_repeated_stamp"] = int(np.count_nonzero(~keep))
    kind = "position"
    a, b = left, right
    if np.count_nonzero(np.isfinite(left) & np.isfinite(right)) < 2 and np.any(np.isfinite(left_rate)):
        kind, a, b = "velocity", left_rate, right_rate  # some drivers publish only wheel rates
        run.warnings.append("the joint states carry no wheel angles; integrated the wheel rates instead")
    ok = keep & np.isfinite(a) & np.isfinite(b)
    if np.count_nonzero(keep & ~ok):
        run.discarded["joint_states_without_wheel_values"] = int(np.count_nonzero(keep & ~ok))
    a, b = a[ok], b[ok]
    track = base_track_from_wheels(t[ok], a, b, wheel_radius=opts.wheel_radius, track_width=opts.track_width,
                                   kind=kind)
    n_jumps = len(track.info.get("jumps", []))
    if kind == "position" and n_jumps > 0.5 * max(1, ok.sum() - 1):
        raise InputError(
            f"{n_jumps} of {ok.sum() - 1} wheel steps are implausibly large: the joint positions do not look like "
            "wheel angles in radians (encoder ticks?); convert them or check --wheel-radius"
        )
    run.recording_info["base_source"] = f"wheel joint states ({kind})"
    return track


def _fill_unwrapped(t: np.ndarray, x: np.ndarray, unwrap: bool) -> np.ndarray:
    """One joint's values on every stamp: its finite samples (unwrapped if asked), linearly interpolated in
    between; NaN outside its own first and last sample."""
    m = np.isfinite(x)
    out = np.full(t.size, np.nan)
    if np.count_nonzero(m) < 2:
        out[m] = x[m]
        return out
    xs = np.unwrap(x[m]) if unwrap else x[m]
    inside = (t >= t[m][0]) & (t <= t[m][-1])
    out[inside] = np.interp(t[inside], t[m], xs)
    return out


def build_camera_track(run: PipelineRun, progress: ProgressFactory) -> CameraTrack:
    """The event front end, streaming the events through in spans of a few seconds (bounded memory)."""
    from .frontend import camera_track_from_event_chunks
    from .io.events_reader import EVENT_TYPES, iter_event_chunks, pick_topic
    from .io.source import open_source

    opts = run.options
    src = open_source(run.log_path)
    topic = pick_topic(src, EVENT_TYPES, opts.topics.get("events"), "event")
    info = src.topics()[topic]
    counts = {"events": 0, "on": 0, "first": None, "last": None}

    def checked(chunks):
        for ch in chunks:
            if counts["first"] is None and (ch.width, ch.height) != (run.camera.width, run.camera.height):
                raise InputError(
                    f"the event sensor is {ch.width} x {ch.height} but the camera intrinsics are for "
                    f"{run.camera.width} x {run.camera.height}; pass the right --camera-info"
                )
            if len(ch):
                counts["events"] += len(ch)
                counts["on"] += ch.n_on
                counts["first"] = ch.t_first if counts["first"] is None else counts["first"]
                counts["last"] = ch.t_last
            yield ch

    span = None if info.t_first_ns is None or info.t_last_ns is None else (info.t_first_ns, info.t_last_ns)
    with progress("detecting board") as bar:
        try:
            track = camera_track_from_event_chunks(
                checked(iter_event_chunks(src, topic)), run.camera, run.board, rate_hz=opts.rate_hz,
                kind=opts.surface, expected_span_ns=span, progress=bar,
            )
        finally:
            run.warnings += [w for w in src.log.warnings if w not in run.warnings]
    run.recording_info.update({
        "event_topic": topic,
        "event_type": info.msgtype,
        "events": counts["events"],
        "events_on": counts["on"],
        "duration_s": 0.0 if counts["first"] is None else (counts["last"] - counts["first"]) * 1e-9,
    })
    info = track.info
    for k in ("windows", "detected", "skipped"):
        if k in info:
            run.discarded[f"frontend_{k}"] = to_jsonable(info[k])
    if len(track) < 10:
        raise InsufficientDataError(
            f"the board was found in only {len(track)} of the event windows; check the board definition "
            f"(--board), the intrinsics and that the board is in view while the robot moves"
        )
    return track


def run_closed_form(run: PipelineRun) -> Any:
    from .pipeline import calibrate_closed_form

    td = run.options.td_range
    cf = calibrate_closed_form(run.camera_track, run.base_track, method=run.options.method, td_range=(-td, td))
    run.warnings += list(cf.warnings)
    run.discarded.update({f"closed_form_{k}": v for k, v in cf.discarded.items()})
    return cf


def run_refinement(run: PipelineRun, progress: ProgressFactory) -> Any:
    from .graph import RefinementOptions, refine

    cf = run.closed_form  # its rotation exists: _solve and diagnose check before they refine
    t = cf.t_base_cam if cf.t_base_cam is not None else np.zeros(3)
    t = np.where(np.isfinite(t), t, 0.0)
    seed = make_T(cf.R_base_cam, t)
    with progress("refining (GTSAM)") as bar:
        opts = RefinementOptions(camera_height=run.options.camera_height)
        res = refine(run.camera_track, run.base_track, run.camera, seed, cf.td, opts, progress=bar)
    run.warnings += list(res.warnings)
    run.discarded["refinement_frames_rejected"] = int(res.n_frames_rejected)
    run.discarded["refinement_frames_dropped"] = int(res.n_frames_dropped)
    return res


def run_from_tracks(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    camera: CameraModel,
    options: PipelineOptions,
    refine: bool = True,
    truth: dict | None = None,
    label: str = "<tracks>",
    progress: ProgressFactory = _no_progress,
) -> PipelineRun:
    """The calibration tail (closed form, refinement) on tracks the caller already has."""
    run = PipelineRun(Path(label), options, board=load_board(options.board), camera=camera,
                      camera_track=camera_track, base_track=base_track, truth=truth)
    return _solve(run, refine, progress)


def _solve(run: PipelineRun, refine: bool, progress: ProgressFactory) -> PipelineRun:
    """Closed form, then (optionally) the refinement it seeds, on a run whose tracks are set."""
    with _Timer(run, "closed_form"):
        run.closed_form = run_closed_form(run)
    if run.closed_form.R_base_cam is None:
        cf = run.closed_form
        raise DegenerateMotionError(
            "the closed form could not determine the rotation (" + "; ".join(cf.degenerate_reasons)
            + "); drive forwards and backwards while turning in front of the board"
        )
    if refine:
        with _Timer(run, "refinement"):
            run.refinement = run_refinement(run, progress)
    return run


def run_pipeline(
    log_path: str | Path,
    options: PipelineOptions,
    refine: bool = True,
    progress: ProgressFactory = _no_progress,
) -> PipelineRun:
    """The whole calibration of one recording. Raises typed errors on user mistakes."""
    run = PipelineRun(Path(log_path), options)
    run.truth = _load_truth(options, run.log_path)
    rec = read_inputs(run, progress)
    with _Timer(run, "odometry"):
        run.base_track = build_base_track(run, rec)
    with _Timer(run, "frontend"):
        run.camera_track = build_camera_track(run, progress)
    del rec
    return _solve(run, refine, progress)


# ------------------------------------------------------------------------------------------------ results


def _method_rows(run: PipelineRun) -> dict[str, dict]:
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


def _observability_rows(run: PipelineRun) -> list[dict]:
    ref = run.refinement
    if ref is None or ref.observability is None:
        return []
    return [
        {"direction": a.description or a.name, "name": a.name, "status": a.status, "sigma": a.sigma,
         "unit": a.unit, "note": a.message}
        for a in ref.observability.axes
    ]


def truth_errors(run: PipelineRun) -> dict | None:
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
        out["closed_form.td_err_ms"] = 1e3 * (cf.td - td_gt)
    ref = run.refinement
    if ref is not None:
        out["refined.rot_err_deg"] = float(rotation_error_deg(ref.R_base_cam, T_gt[:3, :3]))
        out["refined.t_xy_err_m"] = float(np.linalg.norm(ref.T_base_cam[:2, 3] - T_gt[:2, 3]))
        out["refined.t_z_err_m"] = float(ref.T_base_cam[2, 3] - T_gt[2, 3])
        out["refined.td_err_ms"] = 1e3 * (ref.td - td_gt)
    return out


def final_estimate(run: PipelineRun) -> tuple[np.ndarray, float, np.ndarray | None, str]:
    """(T_base_cam, td, covariance or None, source) of the best result the run has."""
    ref = run.refinement
    if ref is not None and ref.converged:
        return ref.T_base_cam, ref.td, ref.cov_base_axes, "refined"
    cf = run.closed_form
    t = np.asarray(cf.t_base_cam if cf.t_base_cam is not None else np.full(3, np.nan), dtype=float).copy()
    # Planar motion never gives the height: report the user's --camera-height (or 0) rather than a NaN that
    # would poison the transform; the observability list and the warnings say it is not measured.
    h = run.options.camera_height
    t[2] = h if h is not None else 0.0
    if not np.all(np.isfinite(t[:2])):
        t[:2] = 0.0
        run.warnings.append("the closed form did not determine the camera position; translation_m is not measured")
    run.warnings.append("translation z (camera height) is not measured by the closed form: "
                        + ("it is --camera-height" if h is not None else "it is set to 0; give --camera-height"))
    return make_T(cf.R_base_cam, t), cf.td, None, f"closed_form.{cf.method}"


SPEED_SCALE_LIMIT = 0.2  # |odometry speed scale - 1| beyond which the distances disagree too much to trust


def result_ok(run: PipelineRun) -> tuple[bool, list[str]]:
    problems: list[str] = []
    cf = run.closed_form
    if cf is not None and cf.degenerate:
        problems += [f"closed form: {r}" for r in cf.degenerate_reasons]
    speed = (getattr(cf, "odometry_scale", None) or {}).get("speed") if cf is not None else None
    if speed is not None and abs(speed - 1.0) > SPEED_SCALE_LIMIT:
        # Rotations do not care about scale, distances do: a board printed at another size than its YAML says,
        # or a wrong wheel radius, shows up as the camera and the wheels disagreeing on how far the robot went.
        problems.append(
            f"the camera sees the robot travel {1 / speed:.2f} x as far as the wheel odometry says: the board "
            "definition's size (square_size) or --wheel-radius is probably wrong, and the translation and time "
            "offset cannot be trusted"
        )
    ref = run.refinement
    if ref is not None and not ref.converged:
        problems.append("refinement did not converge; the covariance is withheld and the closed form is reported")
    return not problems, problems


def build_report(run: PipelineRun) -> dict:
    from . import __version__

    T, td, cov, source = final_estimate(run)
    if T[2, 1] > 0.5:  # the camera's "down" axis (optical y) points up in the base frame
        run.warnings.append(
            "the camera comes out upside down (its image 'down' axis points up in the base frame); if it is not "
            "mounted that way, the wheels are probably swapped (check --left-joint/--right-joint), which mirrors "
            "the whole solution"
        )
    ok, problems = result_ok(run)
    height = ("--camera-height prior" if run.options.camera_height is not None
              else "not observable from planar motion: seed value, not a measurement")
    calib = calibration_dict(T, td, cov, _observability_rows(run),
                             extra={"source": source, "translation_z_source": height})
    cf = run.closed_form
    report: dict[str, Any] = {
        "plsgraph_version": __version__,
        "recording": str(run.log_path),
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "ok": ok,
        "problems": problems,
        "calibration": calib,
        "closed_form": _method_rows(run),
        "closed_form_summary": {
            "method": cf.method,
            "R_base_cam": None if cf.R_base_cam is None else np.asarray(cf.R_base_cam).tolist(),
            "t_xy": None if cf.t_xy is None else np.asarray(cf.t_xy).tolist(),
            "td": cf.td,
            "observable": dict(cf.observable),
            "excitation": dict(cf.excitation),
            "n_pairs": cf.n_pairs,
            "degenerate": cf.degenerate,
            "degenerate_reasons": list(cf.degenerate_reasons),
        },
        "time_offset": None
        if cf.time_offset is None
        else {
            "td_s": cf.time_offset.td,
            "score": cf.time_offset.score,
            "sharpness": cf.time_offset.sharpness,
            "second_peak_ratio": cf.time_offset.second_peak_ratio,
            "method": cf.time_offset.method,
            "ok": cf.time_offset.ok,
        },
        "refinement": None if run.refinement is None else run.refinement.to_dict(),
        "options": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(run.options).items()},
        "recording_info": run.recording_info,
        "counts": {
            "camera_frames": len(run.camera_track) if run.camera_track is not None else 0,
            "odometry_samples": len(run.base_track) if run.base_track is not None else 0,
        },
        "discarded": run.discarded,
        "warnings": run.warnings,
        "timing_s": run.timing_s,
    }
    errs = truth_errors(run)
    if errs is not None:
        report["truth_errors"] = errs
    return to_jsonable(report)


def _num(v: Any, width: int, digits: int) -> str:
    return f"{v:{width}.{digits}f}" if isinstance(v, int | float) else "n/a".rjust(width)


def summary_text(report: dict) -> str:
    c = report["calibration"]
    lines = [
        f"recording      {report['recording']}",
        f"result from    {c['source']}",
        "T_base_cam     " + "\n               ".join(" ".join(_num(v, 9, 5) for v in row) for row in c["T_base_cam"]),
        f"rpy (deg)      {' '.join(_num(v, 8, 3) for v in c['rpy_deg'])}",
        f"translation m  {' '.join(_num(v, 8, 4) for v in c['translation_m'])}"
        + _height_note(report),
        f"time offset    {1e3 * c['time_offset_s']:.2f} ms (t_odom = t_cam + offset)",
    ]
    ref = report.get("refinement")
    if ref:
        lines.append(
            f"refinement     converged={ref['converged']} iterations={ref['iterations']} "
            f"reprojection RMS {ref['rms_px_initial']:.3f} -> {ref['rms_px_final']:.3f} px"
        )
    if c["observability"]:
        lines.append("observability:")
        for o in c["observability"]:
            sig = "-" if o["sigma"] is None else f"{o['sigma']:.3g} {o.get('unit', '')}"
            lines.append(f"  {o['status']:<13} {o['direction']:<40} sigma {sig}")
    if "truth_errors" in report:
        lines.append("errors against truth:")
        lines += [f"  {k:<36} {v:.4g}" for k, v in report["truth_errors"].items() if v is not None]
    if report["problems"]:
        lines.append("PROBLEMS:")
        lines += [f"  - {p}" for p in report["problems"]]
    if report["warnings"]:
        lines.append(f"warnings ({len(report['warnings'])}):")
        lines += [f"  - {w}" for w in report["warnings"][:12]]
    return "\n".join(lines)


def _write_diagnosis_only(out: Path, log_path: str | Path, exc: PlsgraphError) -> dict:
    from . import __version__

    out.mkdir(parents=True, exist_ok=True)
    stale = out / "calibration.yaml"
    if stale.exists():  # with --force into an old folder: an old result must not pass for this recording's
        stale.rename(out / "calibration.previous.yaml")
    for old in [out / "report.html", *out.glob("*.png")]:
        old.unlink(missing_ok=True)
    report = {
        "plsgraph_version": __version__,
        "recording": str(log_path),
        "ok": False,
        "calibration": None,
        "problems": [str(exc)],
        "advice": [
            "drive forwards and backwards while turning (arcs, S-curves) with the board in view; straight "
            "driving leaves the camera yaw and lever arm undetermined, turning in place the yaw",
        ],
    }
    write_json(out / "report.json", report)
    text = "\n".join([
        f"recording      {log_path}",
        "NO CALIBRATION: the recording does not determine the extrinsic.",
        f"  - {exc}",
        f"advice: {report['advice'][0]}",
        "",
        f"written: {out / 'report.json'} (diagnosis only)",
    ])
    return {"ok": False, "text": text, "report": report}


def _height_note(report: dict) -> str:
    obs = report["calibration"]["observability"]
    if not any(o.get("name") == "z" and o["status"] != "observable" for o in obs):
        return ""
    if report["options"].get("camera_height") is not None:
        return "   (z from --camera-height: the motion cannot observe it)"
    return "   (z is only the seed: the height is not observable; give --camera-height)"


def calibrate_to_dir(
    log_path: str | Path,
    out_dir: str | Path,
    options: PipelineOptions,
    refine: bool = True,
    force: bool = False,
    progress: ProgressFactory = terminal_progress,
) -> dict:
    """Run the pipeline and write calibration.yaml, report.json, report.html (+ PNGs) into ``out_dir``."""
    from .figures import write_html_report

    out = prepare_output_dir(out_dir, force=force, create=False)  # refuse before hours of work, not after
    try:
        run = run_pipeline(log_path, options, refine=refine, progress=progress)
    except (DegenerateMotionError, InsufficientDataError) as exc:
        # Too little motion or too little data: a diagnosis, not a number. No calibration.yaml is written.
        return _write_diagnosis_only(out, log_path, exc)
    report = build_report(run)
    out.mkdir(parents=True, exist_ok=True)
    write_html_report(out, run, report)  # first: a figure that fails adds its warning to the report
    write_yaml(out / "calibration.yaml", report["calibration"])
    write_json(out / "report.json", report)
    text = summary_text(report) + f"\n\nwritten: {out / 'calibration.yaml'}, {out / 'report.json'}, " \
        f"{out / 'report.html'}"
    return {"ok": report["ok"], "text": text, "report": report}


def diagnose(log_path: str | Path, options: PipelineOptions, progress: ProgressFactory = terminal_progress) -> dict:
    """Excitation and observability only: is this recording good enough, and what motion is missing?"""
    run = PipelineRun(Path(log_path), options)
    rec = read_inputs(run, progress)
    run.base_track = build_base_track(run, rec)
    run.camera_track = build_camera_track(run, progress)
    del rec
    try:
        run.closed_form = run_closed_form(run)
    except (DegenerateMotionError, InsufficientDataError) as exc:
        advice = ["drive forwards and backwards while turning (arcs, S-curves) with the board in view the whole "
                  "time; vary the speed"]
        text = "\n".join([f"recording {log_path}", "verdict: NOT good enough", f"problem: {exc}",
                          f"advice: {advice[0]}"])
        return {"ok": False, "text": text, "json": {"ok": False, "problems": [str(exc)], "advice": advice}}
    cf = run.closed_form
    verdicts = []
    if cf.R_base_cam is not None:
        try:
            run.refinement = run_refinement(run, progress)
        except (ConvergenceError, DegenerateMotionError, InsufficientDataError) as exc:
            verdicts.append(f"refinement failed: {exc}")
    ok, problems = result_ok(run)
    obs = _observability_rows(run)
    advice = motion_advice(cf, obs)
    good = ok and not any(o["status"] == "unobservable" and o["name"] not in ("z",) for o in obs)
    lines = [f"recording {log_path}", f"camera frames with the board: {len(run.camera_track)}",
             f"odometry samples: {len(run.base_track)}", "excitation (closed form):"]
    lines += [f"  {k:<28} {v:.4g}" for k, v in cf.excitation.items()]
    lines.append("observable from the closed form: "
                 + ", ".join(f"{k}={'yes' if v else 'NO'}" for k, v in cf.observable.items()))
    if obs:
        lines.append("observability after refinement:")
        lines += [f"  {o['status']:<13} {o['direction']:<40} {o['note']}" for o in obs]
    lines += [f"problem: {p}" for p in problems + verdicts]
    lines.append("verdict: " + ("good enough" if good else "NOT good enough"))
    lines += [f"advice: {a}" for a in advice]
    js = {"ok": good, "excitation": cf.excitation, "observable_closed_form": cf.observable, "observability": obs,
          "problems": problems + verdicts, "advice": advice, "degenerate_reasons": cf.degenerate_reasons}
    return {"ok": good, "text": "\n".join(lines), "json": to_jsonable(js)}


def motion_advice(cf: Any, obs: list[dict]) -> list[str]:
    """Plain-language advice on the motion a recording lacks."""
    adv: list[str] = []
    o = cf.observable
    if not o.get("yaw", True) or not o.get("x", True) or not o.get("y", True):
        adv.append("turn while driving (arcs, S-curves, figure eights): straight-line driving leaves the camera "
                   "yaw and the horizontal lever arm undetermined")
    if not o.get("roll", True) or not o.get("pitch", True):
        adv.append("turn the robot (both directions): the tilt of the camera relative to the floor comes from the "
                   "rotation axis, which only turning shows")
    if not o.get("td", True):
        adv.append("vary the speed and turn rate (accelerate, stop, reverse): a steady motion leaves the time "
                   "offset undetermined")
    if any(r["name"] == "z" and r["status"] != "observable" for r in obs):
        adv.append("the camera height cannot be observed from driving on a flat floor; measure it and pass it as a "
                   "prior if you need it")
    return adv


def compare(log_path: str | Path, options: PipelineOptions, progress: ProgressFactory = terminal_progress) -> dict:
    """Every closed-form solver and the refinement side by side (errors against --truth when given)."""
    from .graph import compare_solutions

    run = run_pipeline(log_path, options, refine=True, progress=progress)
    sols = {name: m for name, m in run.closed_form.methods.items() if m.R_base_cam is not None}
    truth_T = None if run.truth is None else np.asarray(run.truth["T_base_cam"], dtype=float)
    truth_td = None if run.truth is None else float(run.truth.get("td", float("nan")))
    table = compare_solutions(sols, run.refinement, camera_track=run.camera_track, base_track=run.base_track,
                              camera=run.camera, truth_T_base_cam=truth_T, truth_td=truth_td)
    failed = {n: m.error for n, m in run.closed_form.methods.items() if m.R_base_cam is None}
    text = table.markdown
    if failed:
        text += "\n\nno answer from: " + "; ".join(f"{n}: {e}" for n, e in failed.items())
    return {"ok": True, "text": text, "json": to_jsonable({"rows": list(table.rows), "failed": failed})}


# ------------------------------------------------------------------------------------------------ simulate

SIM_EPOCH_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z: simulated stamps look like a live ROS clock


def simulate_to_file(
    out: str | Path,
    motion: str = "rich",
    duration: float = 10.0,
    seed: int = 0,
    td: float = 0.03,
    event_format: str = "dvs",
    overwrite: bool = False,
    board: str = "acircles_4x11_a2",
    contrast: float = 0.25,
    progress: ProgressFactory = terminal_progress,
    realism: Any = "realistic",
) -> list[Path]:
    """Simulate a recording (events, wheel joint states, camera info) and write it as ROS 2 MCAP + truth.

    ``realism``: "realistic", "ideal" or a plsgraph.sim.realism.Realism (see docs/simulation.md)."""
    from .io.recording import JointStates
    from .io.writer import truth_path, write_recording, write_truth
    from .sim.events import EventSimParams
    from .sim.robot import simulate_robot

    out = Path(out)
    if out.suffix != ".mcap":
        raise InputError(f"--out must end in .mcap, got {out}")
    if not overwrite and (out.exists() or truth_path(out).exists()):
        raise InputError(f"{out} (or its truth file) exists; choose another path or pass --force")
    out.parent.mkdir(parents=True, exist_ok=True)
    sim = simulate_robot(motion=motion, duration=duration, seed=seed, td=td, board=load_board(board), realism=realism)
    with progress("simulating events") as bar:
        params = EventSimParams(contrast_on=contrast, contrast_off=contrast)
        events = sim.events(seed=seed, params=params, progress=bar)
    # Stamp both clocks from a realistic epoch, as a live robot would; the offset between them stays td.
    epoch_ns = SIM_EPOCH_NS
    events = EventStream(events.t + epoch_ns, events.x, events.y, events.p, events.width, events.height)
    n = sim.wheel_t.size
    names = ("front_left_wheel_joint", "front_right_wheel_joint")
    pos = np.stack([sim.wheel_left, sim.wheel_right], axis=1)
    vel = np.gradient(pos, sim.wheel_t, axis=0)
    joints = JointStates(np.round(sim.wheel_t * 1e9).astype(np.int64) + epoch_ns, names, pos, vel)
    truth = {
        "T_base_cam": sim.T_base_cam,
        "td": sim.td,
        "time_offset_convention": "t_odom = t_cam + td",
        "T_world_board": sim.T_world_board,
        "wheel_radius": sim.wheel_radius,
        "track_width": sim.track_width,
        "motion": motion,
        "clock_epoch_ns": epoch_ns,
        "duration_s": duration,
        "seed": seed,
        "board": sim.board.name,
        "camera": sim.camera.to_dict(),
        "odometry_samples": int(n),
        "events": len(events),
        "contrast_threshold": contrast,
    }
    truth.update(sim.truth_dict())  # nominal vs true odometry intrinsics, board scale, effects, visibility
    write_recording(out, events, joints, None, sim.camera, truth=None, event_format=event_format,
                    overwrite=overwrite)
    tp = write_truth(out, truth)
    return [out, tp]


# ------------------------------------------------------------------------------------------------ batch

RECORDING_SUFFIXES = (".mcap", ".bag", ".db3")


def find_recordings(inputs: list[Path]) -> list[Path]:
    found: list[Path] = []
    for p in inputs:
        p = Path(p)
        if p.is_dir():
            found += sorted(q for q in p.iterdir() if q.suffix in RECORDING_SUFFIXES and q.is_file())
        elif p.is_file():
            found.append(p)
        else:
            raise InputError(f"{p} does not exist")
    if not found:
        raise InputError(f"no recordings ({', '.join(RECORDING_SUFFIXES)}) in {', '.join(map(str, inputs))}")
    names = [p.stem for p in found]
    if len(set(names)) != len(names):
        raise InputError("two recordings share a name; their output folders would collide")
    return found


def _batch_item(item: tuple[str, str, dict, bool], seed: int = 0) -> dict:
    """Worker: calibrate one recording into its own folder; never raises for a user-level failure.

    The pipeline is deterministic, so the per-item ``seed`` that the batch API hands out is not needed."""
    log_path, out_dir, opts, force = item
    t0 = time.perf_counter()
    try:
        res = calibrate_to_dir(log_path, out_dir, PipelineOptions(**opts), force=force, progress=_no_progress)
        rep = res["report"]
        c = rep["calibration"] or {}  # None when the motion only allowed a diagnosis
        row = {"recording": log_path, "status": "ok" if res["ok"] else "flagged", "source": c.get("source"),
               "rpy_deg": c.get("rpy_deg"), "translation_m": c.get("translation_m"),
               "time_offset_s": c.get("time_offset_s"), "problems": rep["problems"]}
        if "truth_errors" in rep:
            row["truth_errors"] = rep["truth_errors"]
    except PlsgraphError as exc:
        row = {"recording": log_path, "status": "failed", "error": f"{type(exc).__name__}: {exc}"}
    except Exception as exc:  # a bug must not stop the other recordings; it is reported in the summary
        log.exception("unexpected failure on %s", log_path)
        row = {"recording": log_path, "status": "failed", "error": f"internal error {type(exc).__name__}: {exc}"}
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def run_batch(args) -> dict:
    """Calibrate many recordings in parallel (local processes, or a Dask cluster with --scheduler)."""
    from .batch import refine_many

    logs = find_recordings(args.inputs)
    out = prepare_output_dir(args.out, force=args.force)
    base = PipelineOptions(board=args.board, camera_info=args.camera_info, wheel_radius=args.wheel_radius,
                           track_width=args.track_width)
    opts = {k: v for k, v in vars(base).items()}
    items = []
    for p in logs:
        o = dict(opts)
        truth = p.with_name(p.stem + ".truth.yaml")
        o["truth"] = truth if truth.exists() else None
        items.append((str(p), str(out / p.stem), o, args.force))
    executor, client = None, None
    if args.scheduler:
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise InputError("--scheduler needs dask.distributed: pip install 'plsgraph[dask]'") from exc
        try:
            client = Client(args.scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {args.scheduler}: {exc}") from exc
        executor = client.get_executor()
    else:
        from .batch import default_executor

        executor = default_executor(len(items), args.jobs)
    try:
        results = refine_many(items, _batch_item, executor=executor)
    finally:
        executor.shutdown(wait=True) if client is None else client.close()
    rows = [_as_row(r, item) for r, item in zip(results, items, strict=True)]
    write_json(out / "summary.json", {"recordings": rows})
    table = markdown_table(
        [{"recording": Path(r["recording"]).name, "status": r["status"], "seconds": r.get("seconds"),
          "roll": (r.get("rpy_deg") or [None] * 3)[0], "pitch": (r.get("rpy_deg") or [None] * 3)[1],
          "yaw": (r.get("rpy_deg") or [None] * 3)[2], "td_ms": None if r.get("time_offset_s") is None
          else 1e3 * r["time_offset_s"], "error": r.get("error", "; ".join(r.get("problems", [])))} for r in rows],
        ["recording", "status", "roll", "pitch", "yaw", "td_ms", "seconds", "error"],
    )
    (out / "summary.md").write_text(table + "\n")
    ok = all(r["status"] == "ok" for r in rows)
    return {"ok": ok, "text": table + f"\n\nwritten: {out / 'summary.json'}, {out / 'summary.md'}", "rows": rows}


def _as_row(result: Any, item: tuple) -> dict:
    """refine_many's per-item outcome -> summary row (an exception it caught becomes a failed row)."""
    if result.ok and isinstance(result.value, dict):
        return result.value
    return {"recording": item[0], "status": "failed", "error": f"{result.error_type}: {result.error}",
            "seconds": round(result.seconds, 2)}
