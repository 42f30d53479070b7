"""Between reading and solving: make the camera track and the base track comparable.

Three things can stand between the two tracks of a real set-up:

* the odometry lives in another file (``--odometry``): an AEDAT4 or ``.raw`` event recording beside a ROS bag.
  :func:`merge_odometry_file` takes joints / odometry (and CameraInfo, when the event file has none) from it;
* the clocks differ by seconds to hours: :func:`pair_tracks` finds the difference coarsely
  (:mod:`plsgraph.calib.clock`) and shifts the camera track onto the odometry clock, so the fine time-offset
  search and the refinement see a small residual offset. The reported ``time_offset_s`` is the shift plus that
  residual (``Run.clock_offset_s`` holds the shift);
* the wheels are swapped or one is reversed (:mod:`plsgraph.odometry.wheel_order`): corrected (``fix``, the
  default) or flagged.

When the coarse step runs (``--clock-align auto``): whenever ``--odometry`` names a second file, or when the
camera's time span overlaps the odometry's by less than half its length (one file, but a sensor on another
clock). Otherwise the clocks are taken as the same, as before, and the fine search covers ±``td_range``.
``--clock-offset S`` replaces the coarse search by the user's number.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np

from .core.tracks import CameraTrack
from .errors import ClockAlignmentError, InputError, RecordingError

log = logging.getLogger(__name__)

#: Below this share of the camera span inside the odometry span, one file's two streams are on different clocks.
MIN_SPAN_OVERLAP = 0.5


def read_events_file(path: Path, topics: dict[str, str] | None, events_topic: str | None = None) -> Any:
    """The first file's robot topics when it has any; an events-only file (AEDAT4, .raw) gives an empty record."""
    from .io.messages import CAMERA_INFO_TYPE, IMU_TYPE, JOINT_STATE_TYPE, ODOMETRY_TYPE
    from .io.recording import Recording, read_recording
    from .io.source import open_source

    src = open_source(path)
    all_topics = src.topics()
    robot = (JOINT_STATE_TYPE, ODOMETRY_TYPE, IMU_TYPE, CAMERA_INFO_TYPE)
    if not topics and not any(i.msgtype in robot for i in all_topics.values()):
        return Recording(Path(path), all_topics)
    return read_recording(src, topics=topics, with_events=False, events_topic=events_topic)


def _kinds(topics: dict) -> tuple[bool, bool]:
    """Whether ``topics`` (name -> TopicInfo) hold events, and whether they hold wheel odometry."""
    from .io.messages import EVENT_FILE_TYPES

    names = [(i.msgtype or "").split("/")[-1] for i in topics.values()]
    events = any(n in ("EventArray", "EventPacket") for n in names) or any(
        i.msgtype in EVENT_FILE_TYPES for i in topics.values())
    return events, any(n in ("JointState", "Odometry") for n in names)


def _refuse_swapped_files(run: Any, rec: Any, path: Path, there: dict) -> None:
    """An InputError when the recording and the --odometry file (``path``, its topics ``there``) are given the wrong
    way round: the events are in the odometry file, the recording has none (and the odometry file no wheel
    odometry)."""
    events_here, _ = _kinds(rec.topics or {})
    events_there, wheels_there = _kinds(there)
    if events_there and not events_here and not wheels_there:
        _, wheels_here = _kinds(rec.topics or {})
        raise InputError(
            f"the two files are given the wrong way round: the events are in {path.name} (given with --odometry) and "
            f"{Path(run.log_path).name} has none{' but has the wheel odometry' if wheels_here else ''}; swap them: "
            f"plsgraph calibrate {path} --odometry {run.log_path} ...")


def merge_odometry_file(run: Any, rec: Any) -> Any:
    """The recording with joints, odometry and IMU from ``--odometry`` (and its CameraInfo if ``rec`` has none)."""
    from .io.recording import read_recording

    opts = run.options.inputs
    path = Path(opts.odometry_file)
    if not path.exists():
        raise InputError(f"odometry file {path} does not exist")
    if path.resolve() == Path(run.log_path).resolve():
        raise InputError(f"--odometry names the recording itself ({path}); leave --odometry out: a recording's own "
                         "odometry is read from it, on its own clock")
    from .io.source import open_source

    odo_src = open_source(path)  # opened once: its topics for the check below, then read
    _refuse_swapped_files(run, rec, path, odo_src.topics())
    own = rec.joints is not None or rec.odometry is not None
    if own:
        run.warn(f"{Path(run.log_path).name} has wheel odometry of its own; the odometry of {path.name} (--odometry) "
                 "is used instead")
    topics = {k: v for k, v in opts.topics.items() if k in ("joints", "odometry")} or None
    odo = read_recording(odo_src, topics=topics, with_events=False)
    run.warn(*(f"{path.name}: {w}" for w in odo.warnings))
    have = (odo.joints is not None and len(odo.joints) > 1) or (odo.odometry is not None and len(odo.odometry.t) > 1)
    if not have:
        listed = ", ".join(f"{t} ({i.msgtype})" for t, i in odo.topics.items()) or "nothing"
        wheel_topics = [t for t, i in odo.topics.items() if i.msgtype.split("/")[-1] in ("JointState", "Odometry")]
        if wheel_topics and (odo.lost or odo.warnings):
            # The topic is there; its messages were lost to damage (saying "holds neither" contradicted the listing).
            said = ([w for w in odo.warnings if any(t in w for t in wheel_topics)] or list(odo.warnings)
                    or ["messages lost"])
            raise RecordingError(f"odometry file {path} has {', '.join(wheel_topics)}, but fewer than two of their "
                                 f"messages could be read: the file is damaged ({said[0]}); use a complete copy")
        raise RecordingError(f"odometry file {path} holds neither sensor_msgs/JointState nor nav_msgs/Odometry "
                             f"messages (it has {listed}); name the topic with --joints-topic/--odom-topic")
    used = {k: v for k, v in rec.used_topics.items() if k not in ("joints", "odometry", "imu")}
    used.update({k: f"{path.name}:{v}" for k, v in odo.used_topics.items() if k in ("joints", "odometry", "imu")})
    camera = rec.camera
    if camera is None and odo.camera is not None:
        camera = odo.camera
        used["camera_info"] = f"{path.name}:{odo.used_topics.get('camera_info', '?')}"
    run.recording_info["odometry_file"] = str(path)
    return dataclasses.replace(rec, joints=odo.joints, odometry=odo.odometry, imu=odo.imu, camera=camera,
                               used_topics=used)


def shift_camera_track(track: CameraTrack, shift_s: float) -> CameraTrack:
    """The camera track with every time (poses and detections) moved by ``shift_s``."""
    det = track.detections
    if det is not None:
        det = dataclasses.replace(det, t=det.t + shift_s)
    return dataclasses.replace(track, t=track.t + shift_s, detections=det,
                               info=dict(track.info, clock_shift_s=float(shift_s)))


def span_overlap(camera_track: CameraTrack, base_t: np.ndarray) -> float:
    """Share of the camera track's span that lies inside the odometry's span (same clock assumed)."""
    a0, a1 = float(camera_track.t[0]), float(camera_track.t[-1])
    b0, b1 = float(base_t[0]), float(base_t[-1])
    return max(0.0, min(a1, b1) - max(a0, b0)) / max(a1 - a0, 1e-9)


def coarse_rule(run: Any) -> tuple[bool, str]:
    """Whether the coarse clock alignment runs, and why (see the module notes)."""
    opts = run.options.inputs
    if opts.clock_offset is not None:
        return False, f"clock difference given: {opts.clock_offset} s (--clock-offset)"
    if opts.clock_align == "never":
        return False, "the clocks are taken as the same (--clock-align never)"
    if opts.clock_align == "always":
        return True, "--clock-align always"
    if opts.odometry_file is not None:
        return True, "the odometry comes from another file (--odometry), so from another clock"
    share = span_overlap(run.camera_track, run.base_track.t)
    if share < MIN_SPAN_OVERLAP:
        return True, (f"only {100 * share:.0f} % of the camera's time span lies inside the odometry's: the two are on "
                      "different clocks")
    return False, "same clock (the camera's and the odometry's time spans overlap)"


def _require_overlap(cam: np.ndarray, odo: np.ndarray, centre: float, w: float, given: float | None) -> None:
    """The camera's span, shifted by ``centre`` (the clock difference given, or 0 for one clock), must meet the
    odometry's for some time offset within +-``w``; else the fine search has nothing to compare and the run would end
    in a diagnosis that blames the driving."""
    from .errors import InputError

    lo, hi = cam[0] + centre, cam[-1] + centre
    if not (hi + w < odo[0] or lo - w > odo[-1]):
        return
    spans = (f"the camera's span on the odometry clock is [{lo:.2f}, {hi:.2f}] s and the odometry's "
             f"[{odo[0]:.2f}, {odo[-1]:.2f}] s: they do not overlap for any time offset within +-{w:g} s")
    if given is not None:
        raise InputError(f"with --clock-offset {given:g} s {spans}. Check the offset and its sign (t_odom = t_cam + "
                         "offset), or leave --clock-offset out to have the clocks aligned from the motion")
    raise InputError(f"with --clock-align never the two clocks are taken as one, but {spans}. Let the clocks be "
                     "aligned from the motion (--clock-align auto or always), or give their difference with "
                     "--clock-offset SECONDS")


#: The problem of a swapped pair of wheel joints found with the camera's mount unsaid: under planar motion, swapped
#: wheels under an upright camera and the wheels as named under an upside-down camera are the same recording (the
#: mirror through the base's x-z plane is a rotation by 180 deg about the base x axis for planar motions), so the
#: correction rests on an assumption the data cannot check.
MOUNT_OR_SWAP_PROBLEM = (
    "the wheel joints as named and an upright camera do not fit the camera's motion, and two explanations fit it "
    "equally well: the left and right wheel joints are swapped (the camera upright; the result assumes this), or the "
    "camera is mounted upside down (the wheels as named; the result would be this one rolled by 180 deg). Driving on "
    "a floor cannot tell them apart: say how the camera is mounted, --upright-camera or --upside-down-camera")


#: The same for a reversed wheel: its magnitudes show that one wheel's joint counts backwards, but which one rests on
#: the mount (the left one under an upright camera is the right one under an upside-down camera, turned by 180 deg).
MOUNT_OR_REVERSED_PROBLEM = (
    "the wheel joints as named do not fit the camera's motion: one wheel's joint counts backwards, and which one "
    "depends on how the camera is mounted: the {named} wheel's with the camera upright (the result assumes this), or "
    "the {other} wheel's with the camera upside down (the result would be this one turned by 180 deg). Driving on a "
    "floor cannot tell them apart: say how the camera is mounted, --upright-camera or --upside-down-camera")


def mount_problem(hypothesis: str) -> str:
    """The problem of a wheel-order correction that rests on the camera's mount alone, the mount unsaid."""
    if hypothesis == "swapped":
        return MOUNT_OR_SWAP_PROBLEM
    named = "left" if hypothesis == "left_reversed" else "right"
    return MOUNT_OR_REVERSED_PROBLEM.format(named=named, other="right" if named == "left" else "left")


def pair_tracks(run: Any) -> None:
    """Check the wheel order and align the clocks; updates ``run.base_track``, ``run.camera_track`` (shifted onto
    the odometry clock), ``run.clock_offset_s`` and ``run.recording_info['clock' / 'wheel_order']``."""
    from .calib.clock import align_clocks
    from .odometry.wheel_order import check_wheel_order

    opts = run.options
    coarse, why = coarse_rule(run)
    w = opts.closed_form.td_range
    given = opts.inputs.clock_offset
    centre = given if given is not None else 0.0
    window = None if coarse else (centre - w, centre + w)
    if not coarse:
        _require_overlap(run.camera_track.t, run.base_track.t, centre, w, given)
    alignment = None
    wheels = getattr(run, "wheels", None)
    if wheels is not None and opts.odometry.wheel_order != "off":
        chk = check_wheel_order(run.camera_track, wheels, window, upside_down_camera=opts.mount.upside_down_camera)
        info = chk.to_dict()
        if chk.wrong and opts.odometry.wheel_order == "fix":
            # The wheels as named were a wrong hypothesis: their track's gaps and jumps give way to the corrected one's.
            named = set(run.base_track.info.get("warnings", [])) if run.base_track is not None else set()
            run.warnings = [w for w in run.warnings if w not in named]
            run.base_track = chk.base_track
            info["corrected"] = True
            run.warn(chk.message + "; corrected: the base motion was integrated with that wheel order "
                     "(--wheel-order flag keeps the wheels as named and flags the result)")
            run.warn(*chk.base_track.info.get("warnings", []))
            alignment = chk.alignment
            info["mount_unstated"] = not opts.mount.stated
            if not opts.mount.stated:
                run.input_problems.append(mount_problem(chk.hypothesis))
        elif chk.wrong:
            info["corrected"] = False
            run.input_problems.append(chk.message + "; not corrected (--wheel-order flag): fix the joint names "
                                      "(--left-joint/--right-joint) or the joint directions")
        else:
            info["corrected"] = False
            if not chk.decided:
                run.warn(chk.message)
            alignment = chk.alignment if chk.hypothesis == "as_given" else None
        run.recording_info["wheel_order"] = info
    clock: dict[str, Any] = {"coarse": coarse, "rule": why, "offset_s": 0.0 if given is None else float(given)}
    if coarse:
        if alignment is None or not alignment.ok:
            # The wheel check ran without demanding confidence; the coarse step does (raises when ambiguous).
            alignment = align_clocks(run.camera_track, run.base_track, window_s=None, strict=True)
        clock.update(alignment.to_dict())
        clock["rule"] = why
        clock["coarse"] = True
        if not alignment.ok:  # pragma: no cover - align_clocks(strict=True) raised already
            raise ClockAlignmentError(alignment.reason)
    shift = float(clock["offset_s"])
    if shift != 0.0:
        run.camera_track = shift_camera_track(run.camera_track, shift)
        run.clock_offset_s = shift
        log.info("camera track shifted by %.6f s onto the odometry clock", shift)
    run.recording_info["clock"] = clock
