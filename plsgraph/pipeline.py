"""The calibration as steps over one :class:`Run`: read the recording, build the base and camera tracks, the
closed form, the refinement it seeds. Each step fills the run, so a failure late keeps what came before.

:mod:`plsgraph.api` wraps these into the public calls; nothing here prints or parses arguments.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .core.board import Board, load_board
from .core.camera import CameraModel
from .core.geometry import make_T
from .core.progress import ProgressFactory, no_progress
from .core.resources import read_yaml_mapping
from .core.tracks import BaseTrack, CameraTrack
from .errors import DegenerateMotionError, InputError, InsufficientDataError, PlsgraphError, RecordingError
from .options import CalibrationOptions

log = logging.getLogger(__name__)

MIN_CAMERA_FRAMES = 10  # fewer board detections than this: no calibration is attempted
#: Events spanning less than this (s, by the decoded events' times) are refused as too short when the front end finds
#: too little in them: no drive that short determines the extrinsic, and the search's own reasons (the board, the
#: surface kind) would not apply. (Not judged on a file's index: a .db3 lists its messages' times, which for events in
#: long packets fall short of the events' span.)
MIN_EVENT_SPAN_S = 2.0
#: The detection rate and the count surface's window length (s) the accuracy docs/validation.md quotes was measured
#: with. Lower rates and longer windows were measured worse (twentieth session): :func:`detection_rate_warnings`.
VALIDATED_RATE_HZ = 30.0
VALIDATED_WINDOW_S = 1.0 / 30.0


def detection_rate_warnings(kind: str, rate_hz: float, window_s: float) -> list[str]:
    """Warnings for a count-surface front end run at a lower detection rate or with longer windows than the
    defaults the accuracy was measured with: on the independent recordings 20 Hz (50 ms windows) passed three results
    beyond 3 sigma, and 20 Hz with 33 ms windows made the harsh ones less accurate (docs/validation.md, "Twentieth
    session"). Only the count surface was measured so (the decaying surfaces look back by their time constant, the
    polarity surfaces were not measured at other rates): for the others nothing is said."""
    if kind != "count":
        return []
    out = []
    slack = 1.0 + 1e-3  # a window typed as 0.0333 s is the default's
    if window_s > VALIDATED_WINDOW_S * slack:
        out.append(f"each detection window holds {1e3 * window_s:.0f} ms of events, longer than the "
                   f"{1e3 * VALIDATED_WINDOW_S:.0f} ms the accuracy was measured with: a fast-moving board blurs, and "
                   "on independent test recordings 50 ms windows gave results beyond their sigmas; use --window "
                   f"{VALIDATED_WINDOW_S:.4f}")
    if rate_hz * slack < VALIDATED_RATE_HZ:
        out.append(f"the board is detected at {rate_hz:g} Hz, below the {VALIDATED_RATE_HZ:g} Hz the accuracy was "
                   "measured with: fewer detections made the harder test recordings less accurate, some beyond their "
                   "sigmas")
    return out


SHORT_EVENTS_ADVICE = ("record longer: 20 s or more of driving forwards and backwards while turning (arcs, "
                       "S-curves), with the board in view, the event camera and the odometry recording all the while")


@dataclass
class Run:
    """What one run produced so far."""

    log_path: Path
    options: CalibrationOptions
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
    wheels: Any = None  # the cleaned wheel signals (odometry.wheel_order.WheelSignals), when joints were used
    clock_offset_s: float = 0.0  # camera track shifted by this onto the odometry clock (pairing.pair_tracks)
    # (mid, count image) of some detections' windows (ns on the events' clock), kept by the streaming front end for
    # the report's event frames (report.coverage.fig_event_frames); None: they are read from the recording
    event_frames: list | None = None
    input_problems: list[str] = field(default_factory=list)  # found before solving, e.g. wheels flagged as wrong
    # per frame of camera_track: taken while the base stood still, and left out of the refinement (_moving_frames);
    # None: every frame went to the refinement
    still_frames: np.ndarray | None = None
    # the lens distortion checked against the board views (calib.lens.LensCheck; None: not checked or too few views)
    lens: Any = None

    def warn(self, *messages: str) -> None:
        """Add warnings once each: a message repeated by several steps (or by several read passes over a damaged
        file, with other counts in it) is kept once, as first said."""
        import re

        seen = {re.sub(r"\d+", "#", w) for w in self.warnings}
        for m in messages:
            key = re.sub(r"\d+", "#", m)
            if key not in seen:
                seen.add(key)
                self.warnings.append(m)


class _Timer:
    def __init__(self, run: Run, name: str):
        self.run, self.name = run, name

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self.run.timing_s[self.name] = round(time.perf_counter() - self.t0, 4)


def load_truth(truth: Path | None) -> dict | None:
    """A truth YAML (from ``plsgraph simulate``), or a recording's path whose ``<name>.truth.yaml`` is beside it."""
    if truth is None:
        return None
    from .io.writer import read_truth

    p = Path(truth)
    try:
        t = read_yaml_mapping(p, "truth file") if p.is_file() else read_truth(p)
    except InputError as exc:
        raise InputError(f"{exc}; a truth file is a mapping with a 4 x 4 T_base_cam (and td)") from exc
    if not isinstance(t, dict) or np.asarray(t.get("T_base_cam", []), dtype=float).shape != (4, 4):
        raise InputError(f"truth file {p} must be a mapping with a 4 x 4 T_base_cam (and td)")
    return t


def read_inputs(run: Run) -> Any:
    """Read the recording (all but the events, which are streamed later); fill camera and board."""
    from .io.recording import read_recording

    opts = run.options
    run.board = load_board(opts.board)
    if not Path(run.log_path).exists():
        raise InputError(f"recording {run.log_path} does not exist")
    topics = {k: v for k, v in opts.inputs.topics.items() if k != "events"} or None
    with _Timer(run, "read"):
        if opts.inputs.odometry_file is None:
            rec = read_recording(run.log_path, topics=topics, with_events=False,
                                 events_topic=opts.inputs.topics.get("events"))
        else:  # events from the first file, the robot from the second
            from .pairing import merge_odometry_file, read_events_file

            rec = merge_odometry_file(run, read_events_file(run.log_path, None, opts.inputs.topics.get("events")))
    run.warn(*rec.warnings)
    if rec.lost:
        run.discarded["lost_while_reading"] = dict(rec.lost)
    run.recording_info.update({"used_topics": dict(rec.used_topics)})
    _require_streams(run, rec)
    if opts.inputs.camera_info is not None:
        from .io.camera_files import read_camera_file

        cam_file = read_camera_file(opts.inputs.camera_info, events_topic=_events_topic(rec, opts))
        run.camera = cam_file.camera
        run.warn(*cam_file.warnings)
        if rec.camera is not None:
            run.warn(*camera_disagreement(rec.camera, cam_file.camera, str(opts.inputs.camera_info)))
    elif rec.camera is not None:
        run.camera = rec.camera
    else:
        _no_camera(run, rec, opts)
    run.warn(*no_distortion_warning(run.camera))
    return rec


def no_distortion_warning(camera: Any) -> list[str]:
    """A warning when the intrinsics carry no lens distortion at all: right for rectified events, but a camera info
    published without its calibration's distortion looks the same, and the fit does not show it. (The board views
    check it once the front end has run: :func:`lens_check`; the warning is dropped when they agree.)"""
    if camera is None or np.any(np.asarray(camera.dist, dtype=float) != 0.0):
        return []
    return ["the camera intrinsics have no lens distortion (all plumb_bob coefficients 0): right if the events are "
            "rectified, but if the camera info was published without its calibration's distortion, the board's "
            "distance and with it the lever arm along the camera's axis come out wrong while the fit looks good (an "
            "independent recording of a lens with k1 -0.06 gave x 20 cm off at a reprojection RMS of 0.23 px); a "
            "3-6 mm lens on a DAVIS346-class sensor has k1 of about -0.1 to -0.4: pass the calibrated intrinsics with "
            "--camera-info"]


def _no_camera(run: Run, rec: Any, opts: Any) -> None:
    """The error of a recording without intrinsics (none given either)."""
    from .io.messages import CAMERA_INFO_TYPE

    info_topics = [t for t, i in rec.topics.items() if i.msgtype == CAMERA_INFO_TYPE]
    said = [w for w in rec.warnings if any(t in w for t in info_topics)]
    # The reader's warnings start with their topic, which the message below names already.
    said = [next((w[len(t) + 2:] for t in info_topics if w.startswith(f"{t}: ")), w) for w in said]
    why = ("no sensor_msgs/CameraInfo topic" if not info_topics else
           f"no usable sensor_msgs/CameraInfo ({', '.join(info_topics)}: "
           + ("; ".join(said) if said else "none of its messages makes a camera") + ")")
    also = (f" (nor does the odometry file {opts.inputs.odometry_file} give one)"
            if opts.inputs.odometry_file is not None and not info_topics else "")
    raise InputError(
        f"{run.log_path} has {why}{also}; pass the intrinsics with --camera-info FILE "
        "(a plsgraph, ROS camera_calibration or OpenCV YAML, or a Kalibr camchain as FILE[:camN])"
    )


#: Relative difference of focal length or principal point (of the image size) between the recording's CameraInfo and
#: --camera-info above which the run says they disagree (a 5 % focal length moved the lever arm by 10 cm).
CAMERA_DISAGREE_REL = 0.01


def camera_disagreement(recorded: Any, given: Any, source: str) -> list[str]:
    """A warning when the intrinsics given (``--camera-info``), which are used, differ from the recording's own."""
    if (recorded.width, recorded.height) != (given.width, given.height):
        return [f"the intrinsics of {source} are for a {given.width} x {given.height} image, the recording's "
                f"CameraInfo for {recorded.width} x {recorded.height}; {source} is used: check it is this camera's"]
    scale = np.array([given.fx, given.fy, given.width, given.height], dtype=float)
    diff = np.abs(np.array([recorded.fx - given.fx, recorded.fy - given.fy, recorded.cx - given.cx,
                            recorded.cy - given.cy])) / scale
    if np.max(diff) <= CAMERA_DISAGREE_REL:
        return []
    return [f"the intrinsics of {source} (fx {given.fx:.1f}, fy {given.fy:.1f}, cx {given.cx:.1f}, cy {given.cy:.1f}) "
            f"differ from the recording's CameraInfo (fx {recorded.fx:.1f}, fy {recorded.fy:.1f}, "
            f"cx {recorded.cx:.1f}, cy {recorded.cy:.1f}) by up to {100 * np.max(diff):.0f} %; {source} is used: "
            "a focal length a few percent off moves the lever arm by centimetres, so make sure it is this camera's "
            "calibration"]


def _require_streams(run: Run, rec: Any) -> None:
    """The two streams a calibration needs, named before anything else is asked for (e.g. intrinsics)."""
    from .io.messages import EVENT_TYPES

    cands = [t for t, i in rec.topics.items() if i.msgtype in EVENT_TYPES and i.messages != 0]
    has_events = bool(run.options.inputs.topics.get("events")) or bool(cands)
    if has_events and not run.options.inputs.topics.get("events") and rec.camera is None:
        # Message counts are unknown in some files (no summary): with no CameraInfo either, look at the stream
        # itself before asking for intrinsics the user may not need to find.
        has_events = _any_event(run.log_path, cands)
    has_odometry = (rec.joints is not None and len(rec.joints) > 1) or (
        rec.odometry is not None and len(rec.odometry.t) > 1)
    missing = [w for w, ok in (("no events (an event camera topic)", has_events),
                               ("no odometry (sensor_msgs/JointState or nav_msgs/Odometry)", has_odometry)) if not ok]
    if missing:
        # A topic named like events whose type plsgraph does not read (a driver's own message): named, so that the
        # advice to pass it with --events-topic is not followed into a second refusal.
        unread = sorted(f"{t} ({i.msgtype})" for t, i in rec.topics.items()
                        if "event" in t.lower() and i.msgtype not in EVENT_TYPES and "camera_info" not in t.lower())
        also = (f"; {', '.join(unread)} {'is' if len(unread) == 1 else 'are'} named like events but of a type "
                "plsgraph does not read (it reads event_camera_msgs/EventPacket, event_array_msgs/EventArray, "
                "dvs_msgs/EventArray, AEDAT4 and Metavision .raw): convert the events to one of those"
                if not has_events and unread else "")
        apart = ("; with the events and the odometry in two files, give the events' file first and the other with "
                 "--odometry FILE" if len(missing) == 1 and run.options.inputs.odometry_file is None else "")
        raise RecordingError(
            f"{run.log_path} has {' and '.join(missing)}; a calibration needs both, recorded together "
            "(name a topic with --events-topic/--joints-topic/--odom-topic if plsgraph did not recognise it)" + apart
            + also
        )


def _any_event(log_path: Path, topics: list[str]) -> bool:
    from .io.events_reader import iter_event_chunks
    from .io.source import open_source

    try:
        src = open_source(log_path)
        return any(any(len(ch) for ch in iter_event_chunks(src, t)) for t in topics)
    except PlsgraphError:
        return True  # unreadable here: let the front end say what is wrong


def _events_topic(rec: Any, opts: CalibrationOptions) -> str | None:
    """The events topic a Kalibr camchain's camera is matched against: the one asked for, else the busiest."""
    from .io.messages import EVENT_TYPES

    if opts.inputs.topics.get("events"):
        return opts.inputs.topics["events"]
    cands = [(-(i.messages or 0), t) for t, i in rec.topics.items() if i.msgtype in EVENT_TYPES]
    return min(cands)[1] if cands else None


def build_base_track(run: Run, rec: Any) -> BaseTrack:
    """The robot's motion from the wheel joints (preferred) or the odometry messages."""
    from .odometry.joints import wheel_track_from_joints
    from .odometry.wheels import base_track_from_odometry

    opts = run.options
    odo = opts.odometry
    have_odom = rec.odometry is not None and len(rec.odometry.t) > 1
    use_joints = rec.joints is not None and len(rec.joints) > 1 and "odometry" not in opts.inputs.topics
    if use_joints and have_odom and odo.left_joint is None and not any("wheel" in j.lower() for j in rec.joints.names):
        use_joints = False  # joints without a wheel among them (an arm, a gripper): the odometry is the base
        run.warn(f"no wheel among the joints {', '.join(rec.joints.names)}; used nav_msgs/Odometry")
    scrambled = (rec.joints if use_joints else rec.odometry if have_odom else None)
    ratio = getattr(scrambled, "stamps_rougher", None)
    if ratio is not None:
        source, values = ("joint states'", "joint angles") if use_joints else ("odometry messages'", "positions")
        run.input_problems.append(
            f"the {source} header stamps go backwards, and put in their order the {values} move back and forth "
            f"{ratio:.1f}x more than in the order the messages were recorded: the stamps are likely wrong (not the "
            "order), and the robot's motion is timed by them; fix the driver's stamps")
    if use_joints:
        track, cleaning = wheel_track_from_joints(rec.joints, odo.wheel_radius, odo.track_width,
                                                  odo.left_joint, odo.right_joint, quiet=True)
        run.recording_info["wheel_joints"] = cleaning.wheel_joints
        run.recording_info["base_source"] = f"wheel joint states ({cleaning.kind})"
        run.discarded.update(cleaning.discarded)
        run.warn(*cleaning.warnings)
        run.wheels = cleaning.signals
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
    run.warn(*track.info.get("warnings", []))
    return track


def _load_the_rest() -> None:
    """Import what the calibration needs after the front end (GTSAM and the refinement above all, 0.1 s): called while
    the front end's workers finish its last spans, when this process only waits, instead of on the critical path after
    them."""
    import importlib

    for name in ("plsgraph.pairing", "plsgraph.calib.closed_form", "plsgraph.refine.graph", "plsgraph.report.figures",
                 "plsgraph.report.robot_files"):
        importlib.import_module(name)


def build_camera_track(run: Run, progress: ProgressFactory) -> CameraTrack:
    """The event front end, streaming the events through in spans of a few seconds (bounded memory)."""
    from .frontend.track import camera_track_from_event_chunks
    from .io.events_reader import EVENT_TYPES, iter_event_chunks, pick_topic
    from .io.source import open_source
    from .report.files import to_jsonable

    opts = run.options
    src = open_source(run.log_path)
    topic = pick_topic(src, EVENT_TYPES, opts.inputs.topics.get("events"), "event")
    info = src.topics()[topic]
    counts = {"events": 0, "on": 0, "first": None, "last": None}
    gaps: list[tuple[int, int]] = []

    def checked(chunks):
        from .gaps import event_gaps

        for ch in chunks:
            if counts["first"] is None and (ch.width, ch.height) != (run.camera.width, run.camera.height):
                raise InputError(
                    f"the event sensor is {ch.width} x {ch.height} but the camera intrinsics are for "
                    f"{run.camera.width} x {run.camera.height}; pass the right --camera-info"
                )
            if len(ch):
                gaps.extend(event_gaps(ch.t, counts["last"]))
                counts["events"] += len(ch)
                counts["on"] += ch.n_on
                counts["first"] = ch.t_first if counts["first"] is None else counts["first"]
                counts["last"] = ch.t_last
            yield ch

    span = None if info.t_first_ns is None or info.t_last_ns is None else (info.t_first_ns, info.t_last_ns)
    if span is None and hasattr(src, "approx_span"):  # an MCAP file: its chunk index gives the span for the bar
        span = src.approx_span(topic)

    def too_short(first: int, last: int) -> InsufficientDataError | None:
        if (last - first) * 1e-9 >= MIN_EVENT_SPAN_S:
            return None
        damaged = _damaged(run) or any("truncated or corrupt" in w or "cut short" in w or "is incomplete" in w
                                       for w in src.log.warnings)
        exc = InsufficientDataError(
            f"the events ({topic}) span only {(last - first) * 1e-9:.2f} s; a calibration needs the robot driving "
            f"and turning in front of the board for longer than that (at least {MIN_EVENT_SPAN_S:g} s; the accuracy "
            "docs/validation.md quotes is for 20 s drives)"
            + ("; the file is cut short or damaged (see the warnings)" if damaged else ""))
        if not damaged:
            exc.advice = SHORT_EVENTS_ADVICE  # neither the board's nor the intrinsics' fault: what the diagnosis says
        return exc

    with progress("detecting board") as bar:
        try:
            track = camera_track_from_event_chunks(
                checked(iter_event_chunks(src, topic)), run.camera, run.board, rate_hz=opts.frontend.rate_hz,
                kind=opts.frontend.surface, expected_span_ns=span, progress=bar,
                **({"window_s": opts.frontend.window_s} if opts.frontend.window_s is not None else {}),
                **({"surface_params": {"tau_s": opts.frontend.tau_s}} if opts.frontend.tau_s is not None else {}),
                workers=opts.frontend.frontend_workers or min(2, os.cpu_count() or 1),
                while_waiting=_load_the_rest,
            )
        except InsufficientDataError as exc:
            # A search that found (too) little in events too short to calibrate from: the shortness is the reason.
            short = None if counts["first"] is None else too_short(counts["first"], counts["last"])
            if short is None:
                raise
            short.frontend_info = getattr(exc, "frontend_info", None)
            raise short from exc
        finally:
            run.warn(*src.log.warnings)
    run.event_frames = track.info.pop("event_frames", None)
    run.recording_info.update({
        "event_topic": topic,
        "event_type": info.msgtype,
        "events": counts["events"],
        "events_on": counts["on"],
        "duration_s": 0.0 if counts["first"] is None else (counts["last"] - counts["first"]) * 1e-9,
    })
    if gaps:
        run.recording_info["event_gaps_ns"] = gaps
    if track.info.get("flicker_hz") is not None:  # the lighting, as the events show it
        run.recording_info.update({k: track.info[k] for k in ("flicker_hz", "flicker_pixels", "flicker_event_share")})
    run.warn(*track.info.get("warnings", []))
    run.warn(*detection_rate_warnings(str(track.info.get("kind", opts.frontend.surface)), opts.frontend.rate_hz,
                                      float(track.info.get("window_s", 1.0 / opts.frontend.rate_hz))))
    for k in ("windows", "detected", "skipped", "hot_pixels"):
        if k in track.info:
            run.discarded[f"frontend_{k}"] = to_jsonable(track.info[k])
    if len(track) < MIN_CAMERA_FRAMES:
        windows = int(track.info.get("windows") or 0)
        short = None if counts["first"] is None else too_short(counts["first"], counts["last"])
        if short is not None:
            short.frontend_info = track.info
            raise short
        if windows < MIN_CAMERA_FRAMES:  # the events are too short to hold that many windows
            why = (f"the events span only {windows} detection windows ({counts['events']:,} events), fewer than the "
                   f"{MIN_CAMERA_FRAMES} board detections a calibration needs"
                   + ("; the file is cut short or damaged (see the warnings)" if _damaged(run) else ""))
        else:
            why = (f"the board was found in only {len(track)} of the {windows} event windows (a calibration needs "
                   f"{MIN_CAMERA_FRAMES}); check the board definition (--board), the intrinsics and that the board is "
                   "in view while the robot moves")
        exc = InsufficientDataError(why)
        exc.frontend_info = track.info
        raise exc
    return track


def _damaged(run: Run) -> bool:
    """Whether reading the recording lost messages (a file cut short or damaged)."""
    return bool(run.discarded.get("lost_while_reading")) or any(
        "truncated or corrupt" in w or "cut short" in w or "is incomplete" in w for w in run.warnings)


def run_closed_form(run: Run) -> Any:
    from .calib.closed_form import calibrate_closed_form

    td = run.options.closed_form.td_range
    with _Timer(run, "closed_form"):
        cf = calibrate_closed_form(run.camera_track, run.base_track, method=run.options.closed_form.method,
                                   td_range=(-td, td))
    run.warn(*cf.warnings)
    run.discarded.update({f"closed_form_{k}": v for k, v in cf.discarded.items()})
    run.closed_form = cf
    return cf


def _moving_frames(run: Run, td: float) -> CameraTrack:
    """The camera track the refinement takes: without the frames taken while the wheel odometry says the base stood
    still (:mod:`plsgraph.odometry.still`; their times on the odometry clock from the closed form's ``td``), unless
    too few would be left. How many were left out goes to ``run.discarded`` (and a warning from WARN_FRAMES)."""
    from .gaps import _slice_camera
    from .odometry.still import MIN_FRAMES_LEFT, STILL_HALF_S, STILL_MARGIN_S, WARN_FRAMES, still_base

    cam = run.camera_track
    to = getattr(run.closed_form, "time_offset", None)
    trusted = to is not None and bool(to.ok) and not bool(to.at_range_edge) and np.isfinite(td)
    # A closed-form offset the refinement may replace (its search finds another peak) can be off by tenths of a
    # second: then only frames still over the whole search range either side count, so that none taken while the
    # base started or stopped is left out.
    margin = STILL_MARGIN_S if trusted else STILL_MARGIN_S + float(run.options.closed_form.td_range)
    still = still_base(cam.t + (td if np.isfinite(td) else 0.0), run.base_track, STILL_HALF_S + margin)
    n = int(still.sum())
    run.discarded["refinement_frames_base_still"] = 0
    run.still_frames = None
    if n == 0 or len(cam) - n < MIN_FRAMES_LEFT:
        return cam
    run.discarded["refinement_frames_base_still"] = n
    run.still_frames = still
    if n >= WARN_FRAMES:
        run.warn(f"{n} of {len(cam)} camera frames were taken while the wheel odometry says the base stood still, yet "
                 "the board made events (a chassis that rocks or hums while the robot idles, something moving in "
                 "view, a flickering lamp); they hold no motion to calibrate against and the refinement leaves them "
                 "out")
    return _slice_camera(cam, ~still)


def run_refinement(run: Run, progress: ProgressFactory,
                   solution_known: Callable[[Run, Any], None] | None = None) -> Any:
    """The refinement seeded by the run's closed form. ``solution_known(run, solution)``: see :func:`solve`."""
    from .refine.graph import RefinementOptions, refine

    cf = run.closed_form  # its rotation exists: solve and diagnose check before they refine
    t = cf.t_base_cam if cf.t_base_cam is not None else np.zeros(3)
    t = np.where(np.isfinite(t), t, 0.0)
    seed = make_T(cf.R_base_cam, t)
    user = run.options.refine
    camera_track = _moving_frames(run, cf.td)
    with _Timer(run, "refinement"), progress("refining (GTSAM)") as bar:
        run.lens = lens_check(run)
        opts = RefinementOptions(camera_height=user.camera_height, board_height=user.board_height,
                                 focal_sigma_rel=user.focal_sigma,
                                 lens_distortion_views=(tuple(float(x) for x in run.lens.views)
                                                        if run.lens is not None and run.lens.significant else None),
                                 workers=run.options.frontend.frontend_workers or min(2, os.cpu_count() or 1))
        scale = cf.odometry_scale or {}
        s0 = (scale.get("speed", 1.0), scale.get("turn_rate", 1.0))  # the closed form's odometry scales: the seed
        res = refine(camera_track, run.base_track, run.camera, seed, cf.td, opts, progress=bar,
                     seed_odometry_scale=s0 if all(0.2 < x < 5.0 for x in s0) else None,
                     on_solution=None if solution_known is None else lambda sol: solution_known(run, sol))
    run.warn(*res.warnings)
    run.warn(*lens_warnings(run.lens, res))
    drop_confirmed_no_distortion_warning(run)
    from .gate import path_warnings

    run.warn(*path_warnings(res, run.base_track))  # slip one radius and track do not describe (not a problem)
    run.discarded["refinement_frames_rejected"] = int(res.n_frames_rejected)
    run.discarded["refinement_frames_dropped"] = int(res.n_frames_dropped)
    run.discarded["refinement_frames_long_span"] = int(res.n_frames_long_span)
    run.refinement = res
    return res


def lens_check(run: Run) -> Any:
    """The camera model's radial distortion against the board views (:mod:`plsgraph.calib.lens`) on every frame the
    front end found the board in; None when there are too few such views or the check fails."""
    from .calib.lens import distortion_from_views

    det = run.camera_track.detections if run.camera_track is not None else None
    if det is None or run.camera is None:
        return None
    try:
        return distortion_from_views(det.uv, det.board_points, run.camera)
    except Exception as exc:  # noqa: BLE001 - a check beside the calibration must not cost it
        from .core.processes import reraise_interrupt

        reraise_interrupt(exc)
        log.warning("the lens distortion could not be checked against the board views: %s", exc)
        return None


def drop_confirmed_no_distortion_warning(run: Run) -> None:
    """The warning of intrinsics without distortion (:func:`no_distortion_warning`) is dropped when the board views
    were checked and agree with no distortion (rectified events, or a lens without any to speak of): the shift at the
    board's outer radius, with two of its sigmas, below the check's 0.3 px."""
    from .calib.lens import MIN_SHIFT_PX

    lens = run.lens
    if lens is None or run.camera is None or np.any(np.asarray(run.camera.dist) != 0.0):
        return
    if abs(lens.shift_px) + 2.0 * lens.shift_sigma_px >= MIN_SHIFT_PX:
        return  # not shown to agree: a check too noisy to tell keeps the warning
    said = no_distortion_warning(run.camera)
    run.warnings[:] = [w for w in run.warnings if w not in said]


def lens_warnings(lens: Any, refinement: Any) -> list[str]:
    """A warning when the board views want another radial distortion than the camera model's (the gate flags the
    result when what it moves is beyond the sigmas: :func:`plsgraph.gate.lens_problems`)."""
    if lens is None or not lens.significant:
        return []
    from .gate import lens_move_text

    moved = lens_move_text(refinement)
    z = abs(lens.shift_px) / max(lens.shift_sigma_px, 1e-12)
    return [f"the board views want another lens distortion than the camera intrinsics': k1 {lens.views[0]:+.3f}, k2 "
            f"{lens.views[1]:+.3f} against {lens.given[0]:+.3f}, {lens.given[1]:+.3f}, which moves a point at the "
            f"board's outer image radius by {lens.shift_px:+.2f} px ({z:.0f} times the views' scatter, "
            f"{lens.n_frames} views)" + (f"; with it the calibration would move by {moved}" if moved else "")
            + "; check the camera info's distortion coefficients (a camera info published without them, or another "
            "lens's; a focal length a few percent off shows partly as distortion too). calibrate writes the views' "
            "coefficients to camera_from_board_views.yaml in its output folder, for a second run with --camera-info "
            "into another folder"]


def solve(run: Run, refine: bool, progress: ProgressFactory = no_progress,
          tracks_final: Callable[[Run], None] | None = None,
          solution_known: Callable[[Run, Any], None] | None = None) -> Run:
    """Closed form, then (optionally) the refinement it seeds, on a run whose tracks are set. ``tracks_final(run)``
    is called once the tracks are final (cut at gaps), before the closed form; ``solution_known(run, solution)`` once
    the refinement's solve has ended, before its second opinions (see :func:`~plsgraph.refine.graph.refine`'s
    ``on_solution``). What they raise is logged, not raised (they are for work beside the calibration, e.g.
    figures)."""
    from .gaps import cut_at_gaps

    cut_at_gaps(run)  # never across a gap the robot moved across: the longest stretch without one, or an error
    if tracks_final is not None:
        try:
            tracks_final(run)
        except Exception as exc:  # noqa: BLE001 - work beside the calibration must not cost the calibration
            from .core.processes import reraise_interrupt

            reraise_interrupt(exc)
            log.warning("after the tracks: %s", exc)
    try:
        cf = run_closed_form(run)
    except InsufficientDataError as exc:
        if "kept_segment_s" not in run.discarded:
            raise
        a, b = run.discarded["kept_segment_s"]
        raise InsufficientDataError(
            f"after cutting the recording at odometry gaps the robot moved across (kept t={a:.2f}..{b:.2f} s): {exc}"
        ) from exc
    if cf.R_base_cam is None:
        from .api import motion_advice

        exc = DegenerateMotionError(
            "the closed form could not determine the rotation (" + "; ".join(cf.degenerate_reasons)
            + "); drive forwards and backwards while turning in front of the board"
        )
        said = [a for a in motion_advice(cf, []) if "camera height" not in a]
        if said:
            exc.advice = "; ".join(said)  # what this motion left undetermined, for the diagnosis
        raise exc
    if refine:
        run_refinement(run, progress, solution_known)
    return run


def build_tracks(run: Run, progress: ProgressFactory = no_progress) -> Run:
    """Recording -> camera and base tracks (and camera, board)."""
    rec = read_inputs(run)
    with _Timer(run, "odometry"):
        run.base_track = build_base_track(run, rec)
    del rec
    with _Timer(run, "frontend"):
        run.camera_track = build_camera_track(run, progress)
    from .pairing import pair_tracks

    with _Timer(run, "pairing"):
        pair_tracks(run)  # wheel order, and the clocks when they differ
    say_wheel_track_warnings(run)
    return run


def say_wheel_track_warnings(run: Run) -> None:
    """Log the wheel track's warnings (gaps, jumps), built quietly, once the wheel order is decided: a wrong order's
    track has jumps of its own that are no fact about the recording (they stay out of the console and the report)."""
    if run.wheels is not None and run.base_track is not None:
        for msg in run.base_track.info.get("warnings", []):
            log.warning(msg)


def run_recording(
    log_path: str | Path, options: CalibrationOptions, refine: bool = True, progress: ProgressFactory = no_progress,
    tracks_final: Callable[[Run], None] | None = None,
    solution_known: Callable[[Run, Any], None] | None = None,
) -> Run:
    """The whole calibration of one recording. Raises typed errors on user mistakes. ``tracks_final(run)`` is called
    once the tracks are final (see :func:`solve`): the front end, which keeps every processor busy, is done;
    ``solution_known(run, solution)`` once the refinement's solve has ended (see :func:`solve`)."""
    run = Run(Path(log_path), options)
    run.truth = load_truth(options.truth)
    try:
        build_tracks(run, progress)
        return solve(run, refine, progress, tracks_final, solution_known)
    except (DegenerateMotionError, InsufficientDataError) as exc:
        exc.warnings = list(run.warnings)  # the diagnosis keeps them: a file cut short says so there
        exc.damaged = _damaged(run)
        exc.run_report = run_report_keys(run)  # and the keys every report.json has
        try:
            exc.coverage = diagnosis_coverage(run, exc)
        except Exception as cov_exc:  # noqa: BLE001 - the diagnosis matters, its coverage is extra
            log.warning("the diagnosis's coverage could not be computed: %s", cov_exc)
            exc.coverage = None
        raise


def run_report_keys(run: Run) -> dict:
    """What every report.json holds of a run besides its result (a diagnosis-only one too): the options, what was
    read, the camera intrinsics used, the counts, what was set aside and the stages' times."""
    from .report.files import to_jsonable

    return to_jsonable({
        "options": run.options.to_dict(),
        "recording_info": run.recording_info,
        # the intrinsics the run used (from the recording or --camera-info), so the result says what it rests on
        "camera": run.camera.to_dict() if run.camera is not None else None,
        "counts": {"camera_frames": len(run.camera_track) if run.camera_track is not None else 0,
                   "odometry_samples": len(run.base_track) if run.base_track is not None else 0},
        "discarded": run.discarded,
        "timing_s": run.timing_s,
    })


def diagnosis_coverage(run: Run, exc: Exception) -> dict | None:
    """The front end's coverage (report.json ``coverage``) of a run that ends in a diagnosis: what the detector saw
    is most of what a user needs when the board was found too rarely. None when the front end did not run."""
    from .report.coverage import coverage_summary

    info = getattr(exc, "frontend_info", None)
    if info is None and run.camera_track is not None:
        info = run.camera_track.info
    return None if not info else coverage_summary(info, run)


def run_tracks(
    camera_track: CameraTrack,
    base_track: BaseTrack,
    camera: CameraModel,
    options: CalibrationOptions,
    refine: bool = True,
    truth: dict | None = None,
    label: str = "<tracks>",
    progress: ProgressFactory = no_progress,
) -> Run:
    """The calibration tail (closed form, refinement) on tracks the caller already has."""
    run = Run(Path(label), options, board=load_board(options.board), camera=camera, camera_track=camera_track,
              base_track=base_track, truth=truth)
    return solve(run, refine, progress)
