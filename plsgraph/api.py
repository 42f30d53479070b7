"""The library's public calls: :func:`calibrate`, :func:`diagnose`, :func:`compare`, :func:`simulate`.

Each takes a recording and options (a :class:`plsgraph.options.CalibrationOptions`, or the same settings as
keyword arguments) and returns a typed result; nothing here parses arguments or prints. Typed errors
(:mod:`plsgraph.errors`) say what the user must change.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .core.camera import CameraModel
from .core.progress import ProgressFactory, no_progress
from .core.tracks import BaseTrack, CameraTrack
from .errors import ConvergenceError, DegenerateMotionError, InputError, InsufficientDataError
from .options import CalibrationOptions
from .pipeline import Run, build_tracks, run_closed_form, run_recording, run_refinement, run_tracks
from .result import CalibrationResult, Comparison, Diagnosis, calibration_result, observability_rows

log = logging.getLogger(__name__)


def _options(board: str | None, options: CalibrationOptions | None, kwargs: dict[str, Any]) -> CalibrationOptions:
    if board is not None:
        kwargs["board"] = board
    return CalibrationOptions.build(options, **kwargs)


def calibrate(
    recording: str | Path,
    board: str | None = None,
    *,
    options: CalibrationOptions | None = None,
    refine: bool = True,
    progress: ProgressFactory = no_progress,
    **settings: Any,
) -> CalibrationResult:
    """Calibrate one recording: ``T_base_cam``, the time offset, their covariance and observability.

    ``board`` is a bundled board name or a YAML path; ``settings`` are any field of the option sections
    (``wheel_radius``, ``track_width``, ``camera_info``, ``topics``, ``surface``, ``rate_hz``, ``method``,
    ``td_range``, ``camera_height``, ``board_height``, ``truth``, ...). ``refine=False`` stops at the closed form.
    Raises :class:`~plsgraph.errors.DegenerateMotionError` or :class:`~plsgraph.errors.InsufficientDataError`
    when the recording cannot determine the extrinsic (see :func:`diagnose` for why).
    """
    opts = _options(board, options, settings)
    return calibration_result(run_recording(recording, opts, refine=refine, progress=progress))


def calibrate_tracks(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    camera: CameraModel,
    board: str | None = None,
    *,
    options: CalibrationOptions | None = None,
    refine: bool = True,
    truth: dict | None = None,
    label: str = "<tracks>",
    progress: ProgressFactory = no_progress,
    **settings: Any,
) -> CalibrationResult:
    """:func:`calibrate` from tracks the caller already has (closed form, then refinement)."""
    opts = _options(board, options, settings)
    return calibration_result(run_tracks(camera_track, base_track, camera, opts, refine=refine, truth=truth,
                                         label=label, progress=progress))


MOTION_ADVICE_DEFAULT = ("drive forwards and backwards while turning (arcs, S-curves) with the board in view the "
                         "whole time; vary the speed")


def motion_advice(cf: Any, obs: list[dict], problems: list[str] | tuple[str, ...] = ()) -> list[str]:
    """Plain-language advice on what a recording lacks: each line names what the motion left undetermined (as the
    closed form's observability says), and for ``problems`` of the inputs' scale (board size, wheel radius, track
    width) what to check first."""
    adv: list[str] = []
    o = cf.observable
    turning = o.get("roll", True)  # turning fixes the base's up axis (roll); driving its forward axis (yaw)
    driving = o.get("yaw", True)
    if not turning and not driving:
        adv.append(MOTION_ADVICE_DEFAULT + ": the robot hardly moved, so nothing was determined")
    elif not driving:
        adv.append("drive forwards and backwards while turning: turning in place fixes only the camera's tilt, and "
                   "leaves its yaw and the horizontal lever arm undetermined")
    elif not turning:
        adv.append("turn while driving (arcs, S-curves, figure eights, both directions): driving straight leaves "
                   "the camera's roll about the driving direction and the horizontal lever arm undetermined")
    if not o.get("td", True):
        adv.append("vary the speed and turn rate (accelerate, stop, reverse): a steady motion leaves the time "
                   "offset undetermined")
    if any("disagree on distances" in p for p in problems):
        adv.append("check the board's size first (--board: the square_size of the board you printed, measured) and "
                   "--wheel-radius: the camera and the wheels disagree on distances, which no motion fixes")
    elif any("effective track width" in p for p in problems):
        adv.append("check --track-width (and, for a skid-steer robot, that its effective track is what the "
                   "odometry uses): no motion fixes it")
    if any(r["name"] == "z" and r["status"] != "observable" for r in obs):
        adv.append("the camera height cannot be observed from driving on a flat floor; measure it and pass it as a "
                   "prior if you need it (--camera-height, or the board's height with --board-height)")
    return adv


def diagnose(
    recording: str | Path,
    board: str | None = None,
    *,
    options: CalibrationOptions | None = None,
    progress: ProgressFactory = no_progress,
    **settings: Any,
) -> Diagnosis:
    """Excitation and observability only: is this recording good enough, and what motion is missing?"""
    from .gaps import cut_at_gaps
    from .gate import problems_of_run

    opts = _options(board, options, settings)
    run = Run(Path(recording), opts)
    try:
        build_tracks(run, progress)
    except (DegenerateMotionError, InsufficientDataError) as exc:  # as calibrate: a diagnosis (exit 1), not an error
        from .pipeline import _damaged
        from .report.output import DAMAGED_ADVICE, FRONTEND_ADVICE

        advice = (DAMAGED_ADVICE if _damaged(run) else getattr(exc, "advice", None) or
                  (FRONTEND_ADVICE if getattr(exc, "frontend_info", None) is not None else MOTION_ADVICE_DEFAULT))
        searched = run.camera_track is not None or getattr(exc, "frontend_info", None) is not None
        counts = {"camera_frames": (len(run.camera_track) if run.camera_track is not None else 0) if searched
                  else None,  # None: the run stopped before the board was searched for
                  "odometry_samples": len(run.base_track) if run.base_track is not None else 0}
        return Diagnosis(str(recording), False, (str(exc),), (advice,), **counts, warnings=tuple(run.warnings))
    counts = {"camera_frames": len(run.camera_track), "odometry_samples": len(run.base_track)}
    try:
        cut_at_gaps(run)  # the same data calibrate would use
        cf = run_closed_form(run)
    except (DegenerateMotionError, InsufficientDataError) as exc:
        return Diagnosis(str(recording), False, (str(exc),), (MOTION_ADVICE_DEFAULT,), **counts,
                         warnings=tuple(run.warnings))
    verdicts = []
    if cf.R_base_cam is not None:
        try:
            run_refinement(run, progress)
        except (ConvergenceError, DegenerateMotionError, InsufficientDataError) as exc:
            verdicts.append(f"refinement failed: {exc}")
    problems = problems_of_run(run) + verdicts  # the gate calibrate uses: both agree on one recording
    obs = observability_rows(run)
    good = not problems
    clock = run.recording_info.get("clock") or {}
    return Diagnosis(str(recording), good, tuple(problems), tuple(motion_advice(cf, obs, problems)),
                     dict(cf.excitation),
                     dict(cf.observable), tuple(obs), tuple(cf.degenerate_reasons), **counts,
                     warnings=tuple(run.warnings),
                     clock_alignment={k: clock[k] for k in ("coarse", "rule", "offset_s", "score",
                                                            "second_peak_ratio", "separation") if k in clock})


def compare(
    recording: str | Path,
    board: str | None = None,
    *,
    options: CalibrationOptions | None = None,
    progress: ProgressFactory = no_progress,
    **settings: Any,
) -> Comparison:
    """Every closed-form solver and the refinement side by side (errors against ``truth`` when given)."""
    from .refine.compare import compare_solutions

    opts = _options(board, options, settings)
    run = run_recording(recording, opts, refine=True, progress=progress)
    sols = {name: m for name, m in run.closed_form.methods.items() if m.R_base_cam is not None}
    truth_T = None if run.truth is None else np.asarray(run.truth["T_base_cam"], dtype=float)
    # The solvers see the camera track shifted onto the odometry clock; compare their td with the truth's likewise.
    truth_td = None if run.truth is None else float(run.truth.get("td", float("nan"))) - run.clock_offset_s
    track = run.camera_track
    if run.still_frames is not None:  # every solution scored on the frames the refinement took, not a still base's
        from .gaps import _slice_camera

        track = _slice_camera(track, ~run.still_frames)
    table = compare_solutions(sols, run.refinement, camera_track=track, base_track=run.base_track,
                              camera=run.camera, truth_T_base_cam=truth_T, truth_td=truth_td)
    failed = {n: m.error for n, m in run.closed_form.methods.items() if m.R_base_cam is None}
    from .gate import problems_of_run

    problems = tuple(problems_of_run(run))
    return Comparison(str(recording), tuple(table.rows), failed, table.markdown, ok=not problems, problems=problems,
                      warnings=tuple(run.warnings))


def calibrate_to_dir(
    recording: str | Path,
    out_dir: str | Path,
    options: CalibrationOptions,
    refine: bool = True,
    force: bool = False,
    progress: ProgressFactory = no_progress,
    figure_worker: bool | None = None,
) -> dict:
    """Calibrate and write calibration.yaml, report.json, report.html (+ PNGs) into ``out_dir``; a recording
    that cannot determine the extrinsic gets a diagnosis (report.json, no calibration). A run whose result is flagged or
    a diagnosis keeps a calibration the folder held before in ``previous_calibration/``
    (:func:`~plsgraph.report.output.keep_earlier_calibration`). Returns ``{ok, text, report}``.

    ``figure_worker``: True draws the figures in a second process that loads matplotlib while the calibration runs
    (:mod:`plsgraph.report.figure_worker`; the same figures, sooner), False in this process (e.g. when many
    recordings already share the processors); None (default) uses the second process when a processor is free for it
    (:func:`~plsgraph.report.figure_worker.processor_free`)."""
    from .report.figure_worker import FigureWorker, processor_free
    from .report.files import prepare_output_dir
    from .report.output import (
        DAMAGED_ADVICE,
        DIAGNOSIS_ADVICE,
        FRONTEND_ADVICE,
        PREVIOUS_CALIBRATION,
        write_calibration,
        write_diagnosis_only,
        write_result_folder,
    )
    from .report.text import calibration_text

    out = prepare_output_dir(out_dir, force=force, create=False)  # refuse before hours of work, not after

    def work(stage: Path) -> dict:
        use_worker = processor_free() if figure_worker is None else figure_worker
        with (FigureWorker.start() if use_worker else FigureWorker()) as figures:
            try:
                # The figure worker warms up once the front end (parallel, every processor) is done, and draws the
                # event frames (final tracks) while the rest of the calibration runs.
                def tracks_final(run: Any) -> None:
                    figures.warm()
                    figures.early(stage, run)

                # And the figures that need only the refined solution once the refinement's solve ends: they are
                # drawn while its second opinions are worked out, and kept if the result's solution is that one.
                def solution_known(run: Any, solution: Any) -> None:
                    figures.speculate(stage, run, solution)

                result = calibration_result(run_recording(recording, _options(None, options, {}), refine=refine,
                                                          progress=progress, tracks_final=tracks_final,
                                                          solution_known=solution_known))
            except (DegenerateMotionError, InsufficientDataError) as exc:
                # Too little motion or too little data: a diagnosis, not a number. No calibration.yaml is written.
                advice = (DAMAGED_ADVICE if getattr(exc, "damaged", False) else getattr(exc, "advice", None) or
                          (FRONTEND_ADVICE if getattr(exc, "frontend_info", None) is not None else DIAGNOSIS_ADVICE))
                return write_diagnosis_only(stage, recording, str(exc), advice, getattr(exc, "coverage", None),
                                            getattr(exc, "warnings", None), earlier=out,
                                            run_report=getattr(exc, "run_report", None))
            written = write_calibration(stage, result, figures, earlier=out)
        text = calibration_text(result.report) + "\n\nwritten: " + ", ".join(str(out / p.name) for p in written)
        if result.report.get("previous_calibration"):
            text += (f"\nkept: the calibration this folder held before, in {out / PREVIOUS_CALIBRATION} (this result "
                     "is flagged)")
        return {"ok": result.ok, "text": text, "report": result.report, "result": result}

    # The whole folder is written at once: under a lock (a second run on it fails at once), into a staging folder
    # that replaces it at the end (no file of an earlier run survives; an interrupt leaves the old one intact).
    # The figure worker has ended (drawn, or stopped) before the folder is moved into place or removed.
    return write_result_folder(out, work)


def failure_to_dir(recording: str | Path, out_dir: str | Path, error: str) -> None:
    """Replace ``out_dir`` with a report.json saying the recording failed (batch --force: an older result there
    must not pass for this recording's; its calibration is kept in ``previous_calibration/``)."""
    from .report.output import write_diagnosis_only, write_result_folder

    write_result_folder(Path(out_dir), lambda stage: write_diagnosis_only(stage, recording, error, advice="",
                                                                          earlier=Path(out_dir)))


#: The simulator holds a recording's events in memory: about this many bytes per simulated second at contrast 0.25
#: (0.3 GB at 10 s, 1.0 GB at 30 s, 3.9 GB at 120 s, measured peaks), more events (as 1 / contrast^2) below it.
SIM_BYTES_PER_S = 33e6


def _available_memory() -> float | None:
    """The memory the kernel says is available (bytes; Linux's MemAvailable), or None where it cannot tell."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def _check_simulation_memory(duration: float, contrast: float) -> None:
    """Refuse a simulation that would need more memory than the machine has available (before, an hour's recording
    was accepted and would have needed about 115 GB)."""
    per_s = SIM_BYTES_PER_S * max(0.25, (0.25 / float(contrast)) ** 2)  # contrast 0.45: 0.33 GB at 20 s, measured
    need = 0.3e9 + per_s * float(duration)
    have = _available_memory()
    if have is not None and need > have:
        most = max(1.0, (have - 0.3e9) / per_s)
        raise InputError(f"simulating {duration:g} s needs about {need / 1e9:.1f} GB of memory (the events are held "
                         f"in memory) and {have / 1e9:.1f} GB are available: simulate at most about {most:.0f} s "
                         "(or a higher --contrast, which makes fewer events)")


MAX_SIM_DURATION_S = 3600.0  # an hour of simulated events already takes hours and tens of GB
MAX_SIM_TD_S = 5.0  # a simulated clock offset beyond this is outside any td search range that makes sense
SIM_EPOCH_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z: simulated stamps look like a live ROS clock


@dataclass(frozen=True)
class SimulatedRecording:
    """A simulated recording before it is written: the truth (``sim``), the event stream and the wheel joint
    states, both stamped from ``epoch_ns`` as a live robot would, and the truth file's content."""

    sim: Any
    events: Any
    joints: Any
    truth: dict
    epoch_ns: int


def simulate_recording(
    motion: str = "rich",
    duration: float = 10.0,
    seed: int = 0,
    td: float = 0.03,
    board: str = "acircles_4x11_a2",
    contrast: float = 0.25,
    realism: Any = "realistic",
    progress: ProgressFactory = no_progress,
) -> SimulatedRecording:
    """Simulate a recording in memory (see :func:`simulate`, which also writes it)."""
    import math

    from .core.board import load_board
    from .core.events import EventStream
    from .io.recording import JointStates
    from .sim.events import EventSimParams
    from .sim.robot import simulate_robot

    if isinstance(duration, bool) or not (isinstance(duration, int | float) and math.isfinite(duration)
                                          and 1.0 < duration <= MAX_SIM_DURATION_S):
        raise InputError(f"--duration must be a number of seconds above 1 and at most {MAX_SIM_DURATION_S:g}, "
                         f"got {duration!r}")
    if isinstance(td, bool) or not (isinstance(td, int | float) and math.isfinite(td) and abs(td) <= MAX_SIM_TD_S):
        raise InputError(f"--td (the simulated clock offset) must be a number of seconds within +-{MAX_SIM_TD_S:g}, "
                         f"got {td!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"--seed must be a whole number >= 0, got {seed!r}")
    if not (isinstance(contrast, int | float) and math.isfinite(contrast) and contrast > 0):
        raise InputError(f"--contrast must be a positive number (log intensity), got {contrast!r}")
    _check_simulation_memory(duration, contrast)
    sim = simulate_robot(motion=motion, duration=duration, seed=seed, td=td, board=load_board(board),
                         realism=realism)
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
    return SimulatedRecording(sim, events, joints, truth, epoch_ns)


def simulate(
    out: str | Path,
    motion: str = "rich",
    duration: float = 10.0,
    seed: int = 0,
    td: float = 0.03,
    event_format: str = "dvs",
    overwrite: bool = False,
    board: str = "acircles_4x11_a2",
    contrast: float = 0.25,
    realism: Any = "realistic",
    progress: ProgressFactory = no_progress,
) -> list[Path]:
    """Simulate a recording (events, wheel joint states, camera info) and write it as ROS 2 MCAP + truth.

    ``realism``: "realistic", "ideal" or a :class:`plsgraph.sim.realism.Realism` (see docs/simulation.md)."""
    from .io.writer import truth_path, write_recording, write_truth

    out = Path(out)
    if out.suffix != ".mcap":
        raise InputError(f"--out must end in .mcap, got {out}")
    if not overwrite and (out.exists() or truth_path(out).exists()):
        raise InputError(f"{out} (or its truth file) exists; choose another path or pass --force")
    try:  # before the simulation, which takes a while: a folder nothing can be written into fails now
        import tempfile

        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out.parent):
            pass
    except OSError as exc:
        raise InputError(f"cannot write {out}: {exc.strerror or exc} in {out.parent}; choose an --out on a writable "
                         "disk") from None
    rec = simulate_recording(motion, duration, seed, td, board, contrast, realism, progress)
    write_recording(out, rec.events, rec.joints, None, rec.sim.camera, truth=None, event_format=event_format,
                    overwrite=overwrite)
    return [out, write_truth(out, rec.truth)]
