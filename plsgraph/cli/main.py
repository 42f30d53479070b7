"""The ``plsgraph`` command. Library code raises typed errors; only this module prints.

Exit codes: 0 success, 1 the job ran but its result is flagged (degenerate / not converged / failed
items in a batch), 2 user error (bad flags, unreadable input, refused overwrite), 3 internal error (or a worker
process killed), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 (SIGHUP).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import NoReturn

from .. import __version__
from ..errors import PlsgraphError

EPILOG = """\
typical session:
  plsgraph inspect run.mcap                       what is in the recording
  plsgraph diagnose run.mcap --board acircles_4x11_a2  is the motion good enough?
  plsgraph calibrate run.mcap --board acircles_4x11_a2 --out calib/
  plsgraph compare run.mcap --board acircles_4x11_a2 --truth run.truth.yaml

BOARD is a YAML file or the name of a bundled board (acircles_4x11, acircles_4x11_a2, aprilgrid_6x6, ...).
Conventions: T_base_cam maps camera points into the robot base frame; t_odom = t_cam + time_offset_s.
"""


class _Parser(argparse.ArgumentParser):
    """argparse that exits with code 2 and a one-line hint instead of a usage dump on errors."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        print(f"{self.prog}: error: {message}\n(see '{self.prog} --help')", file=sys.stderr)
        sys.exit(2)


def _bundled_boards() -> list[str]:
    """The bundled boards' names (plsgraph/data/boards), for the help."""
    from ..core.resources import bundled_names

    return bundled_names("boards")


def _add_recording_options(p: argparse.ArgumentParser, need_out: bool) -> None:
    p.add_argument("log", type=Path, help="recording: .mcap, ROS 2 .db3 folder/file, ROS 1 .bag, or an events-only "
                   ".aedat4 / Prophesee .raw (then with --odometry)")
    p.add_argument(
        "--board", required=True,
        help=f"the target: a board YAML or a bundled name ({', '.join(_bundled_boards())}); its size must match the "
        "print, or every distance is scaled",
    )
    p.add_argument(
        "--camera-info",
        type=Path,
        metavar="FILE[:camN]",
        help="camera intrinsics: plsgraph / ROS camera_calibration / OpenCV FileStorage YAML, or a Kalibr camchain "
        "(FILE:cam1 picks a camera; default: the one whose rostopic matches the events topic, or the only one). "
        "Default: CameraInfo in the recording",
    )
    p.add_argument("--wheel-radius", type=float, default=0.098, help="wheel radius r in m (default: %(default)s)")
    p.add_argument("--track-width", type=float, default=0.37, help="wheel separation b in m (default: %(default)s)")
    p.add_argument("--events-topic", help="event topic (default: detected by message type)")
    p.add_argument("--joints-topic", help="sensor_msgs/JointState topic (default: detected)")
    p.add_argument("--odom-topic",
                   help="nav_msgs/Odometry topic; naming it makes the odometry, not the wheel joints, the base motion")
    p.add_argument("--left-joint", help="name of the left wheel joint (default: picked by name)")
    p.add_argument("--right-joint", help="name of the right wheel joint (default: picked by name)")
    p.add_argument(
        "--surface",
        default="count",
        choices=["count", "polarity", "classic", "leaky"],
        help="event representation for detection: count (event count frame, default: it found the board most "
        "often in simulated robot recordings, see docs/frontend.md), polarity (the paper's polarity-aware "
        "surface), classic (exponential time surface), leaky (leaky polarity integrator)",
    )
    p.add_argument("--rate", type=float, default=30.0, help="detection rate in Hz (default: %(default)s)")
    p.add_argument("--window", type=float, default=None, metavar="SECONDS",
                   help="each detection window's look-back in s (default: one period of --rate; 5 tau for the "
                   "decaying surfaces)")
    p.add_argument("--tau", type=float, default=None, metavar="SECONDS",
                   help="time constant of the decaying surfaces (--surface classic or leaky) in s (default: 0.03 "
                   "classic, 0.05 leaky); a slow, hand-held board may need 0.3 with --window 0.9")
    p.add_argument(
        "--td-range", type=float, default=0.5,
        help="search the time offset in +-this many seconds, at most 10 (default: 0.5; clocks further apart: "
        "--odometry or --clock-offset)"
    )
    p.add_argument(
        "--method",
        default="pls",
        choices=["pls", "cca", "procrustes"],
        help="closed form that seeds the refinement (default: %(default)s)",
    )
    p.add_argument("--truth", type=Path, help="truth YAML (from 'plsgraph simulate') to report errors against")
    p.add_argument("--camera-height", type=float,
                   help="camera height above the base frame origin in m, if measured: planar motion cannot observe it")
    p.add_argument("--board-height", type=float,
                   help="height of the board's origin above the floor in m, if measured: makes the camera height "
                   "observable through the board")
    p.add_argument("--focal-sigma", type=float, default=0.005, metavar="REL",
                   help="how well the camera info's focal length is known, relative (default %(default)s = 0.5 %%): "
                   "the lever arm along the camera's axis moves with it, and the sigmas hold it; 0 takes it as exact")
    _add_ecosystem_options(p)
    if need_out:
        p.add_argument("--out", type=Path, required=True,
                       help="output folder: new, empty, or an earlier plsgraph result (replaced with --force)")
        p.add_argument("--force", action="store_true",
                       help="replace an earlier plsgraph result in the output folder (a result that is flagged, or no "
                       "calibration at all, keeps the earlier calibration in previous_calibration/)")


def _add_ecosystem_options(p: argparse.ArgumentParser) -> None:
    """Two files on two clocks, wheel order, camera mount, frame names (docs/cli.md, 'Two files, two clocks')."""
    p.add_argument("--odometry", type=Path, metavar="ODOM_FILE",
                   help="the wheel joints / odometry (and CameraInfo, if the events file has none) from this file "
                   "(any supported format); its clock may differ from the camera's by seconds to hours")
    p.add_argument("--clock-align", choices=["auto", "always", "never"], default="auto",
                   help="coarse clock alignment before the fine time-offset search: auto (default) when --odometry is "
                   "given or the camera and odometry time spans hardly overlap")
    p.add_argument("--clock-offset", type=float, metavar="SECONDS",
                   help="approximate clock difference (t_odom = t_cam + SECONDS) instead of the coarse search")
    p.add_argument("--wheel-order", choices=["fix", "flag", "off"], default="fix",
                   help="when the data show swapped wheels or a reversed wheel: fix (default: correct and say so), "
                   "flag (keep them, flag the result), off (do not check)")
    mount = p.add_mutually_exclusive_group()
    mount.add_argument("--upside-down-camera", action="store_true",
                       help="the camera is mounted upside down on purpose (else an upside-down result is a problem)")
    mount.add_argument("--upright-camera", action="store_true",
                       help="the camera is mounted upright (image 'down' towards the floor): said, a swapped pair of "
                       "wheel joints is corrected; unsaid, it is flagged, since an upside-down camera on wheels as "
                       "named looks the same")
    p.add_argument("--parent-frame", default="base_link",
                   help="robot frame in the URDF/launch/TF (default: %(default)s)")
    p.add_argument("--child-frame", default="event_camera",
                   help="camera frame in the URDF/launch/TF (default: %(default)s)")


def _build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="plsgraph",
        description="Calibrate an event camera against the wheel odometry of a ground robot: "
        "extrinsic T_base_cam, clock offset, and what the motion made observable.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"plsgraph {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    s = sub.add_parser("inspect", help="list topics, message counts, time spans and event statistics")
    s.add_argument("log", type=Path, help="recording: .mcap, ROS 2 .db3 folder/file, ROS 1 .bag, .aedat4 or "
                   "Prophesee .raw")
    s.add_argument("--json", action="store_true", help="print machine-readable JSON")
    s.add_argument("--quick", action="store_true", help="do not decode the events (several times faster on a big "
                   "recording): topics, message counts and time spans only (the event topic's from its messages' "
                   "stamps, not from its events' times)")
    s.set_defaults(func=_cmd_inspect)

    s = sub.add_parser("simulate", help="write a simulated recording (MCAP) with its truth beside it")
    s.add_argument("--motion", choices=["rich", "straight", "spin"], default="rich",
                   help="how the robot drives: rich (turns and curves, calibratable; default), straight or spin "
                   "(degenerate: for seeing the diagnosis)")
    s.add_argument("--duration", type=float, default=10.0, help="seconds (default: %(default)s)")
    s.add_argument("--seed", type=int, default=0, help="random seed, a whole number >= 0 (default: %(default)s)")
    s.add_argument("--td", type=float, default=0.03, help="true time offset in s (default: %(default)s)")
    s.add_argument("--event-format", choices=["dvs", "libcaer_cmp", "libcaer", "evt3", "mono"], default="dvs",
                   help="event message encoding (default: %(default)s, dvs_msgs/EventArray)")
    s.add_argument("--board", default="acircles_4x11_a2", help="board YAML or bundled name (default: %(default)s)")
    s.add_argument("--contrast", type=float, default=0.25,
                   help="event contrast threshold in log intensity (default: %(default)s; larger, fewer events)")
    s.add_argument("--ideal", action="store_true",
                   help="the clean simulator (default: realistic sensor, robot, scene and driving, docs/simulation.md)")
    s.add_argument("--out", type=Path, required=True, help="output .mcap path")
    s.add_argument("--force", action="store_true", help="overwrite an existing file")
    s.set_defaults(func=_cmd_simulate)

    s = sub.add_parser("calibrate", help="run the whole pipeline and write calibration.yaml, report.json/html")
    _add_recording_options(s, need_out=True)
    s.add_argument("--no-refine", action="store_true", help="stop after the closed form (no GTSAM refinement)")
    s.set_defaults(func=_cmd_calibrate)

    for name, help_text, func in (
        ("diagnose", "is the recording good enough? excitation and observability only", _cmd_diagnose),
        ("compare", "every closed-form solver and the refinement side by side", _cmd_compare),
    ):
        s = sub.add_parser(name, help=help_text)
        _add_recording_options(s, need_out=False)
        s.add_argument("--json", action="store_true", help="print machine-readable JSON")
        s.set_defaults(func=func)

    s = sub.add_parser("reproduce-paper", help="the paper's synthetic Tables I and II next to ours")
    s.add_argument("--out", type=Path, required=True, help="output folder")
    s.add_argument("--trials", type=int, default=200,
                   help="trials per cell, 2 to 10000 (default: %(default)s, the paper's)")
    s.add_argument("--quick", action="store_true", help="few trials, a few seconds")
    s.add_argument("--seed", type=int, default=0, help="random seed, a whole number >= 0 (default: %(default)s)")
    s.add_argument("--force", action="store_true", help="overwrite existing tables")
    s.set_defaults(func=_cmd_reproduce)

    s = sub.add_parser(
        "batch", help="calibrate many recordings in parallel; one summary table",
        description="Calibrate many recordings in parallel, each into OUT/NAME/, with summary.json and summary.md. "
        "Beside NAME.mcap, a NAME.truth.yaml is used as its --truth and a NAME.options.yaml holds its own settings "
        "over these flags (calibrate's option names: wheel_radius, track_width, camera_height, camera_info, "
        "left_joint, topics, ...; paths relative to that file).")
    s.add_argument("inputs", nargs="+", type=Path, help="recordings, or folders holding them")
    s.add_argument("--out", type=Path, required=True, help="output folder (one sub-folder per recording)")
    s.add_argument("--board", required=True, help=f"board YAML or bundled name ({', '.join(_bundled_boards())})")
    s.add_argument("--camera-info", type=Path, metavar="FILE[:camN]", help="camera intrinsics file, as for calibrate")
    s.add_argument("--wheel-radius", type=float, default=0.098, help="wheel radius r in m (default: %(default)s)")
    s.add_argument("--track-width", type=float, default=0.37, help="wheel separation b in m (default: %(default)s)")
    mount = s.add_mutually_exclusive_group()
    mount.add_argument("--upright-camera", action="store_true",
                       help="every robot's camera is mounted upright (see calibrate --help; a recording's "
                       "NAME.options.yaml may say otherwise: upside_down_camera: true)")
    mount.add_argument("--upside-down-camera", action="store_true", help="every robot's camera is mounted upside down")
    s.add_argument("--jobs", type=int, default=None, help="local worker processes (default: CPU count)")
    s.add_argument("--scheduler", help="Dask scheduler address (tcp://host:port) instead of local processes")
    s.add_argument("--force", action="store_true",
                   help="replace the earlier results of the recordings given (one whose result is now flagged or "
                   "fails keeps its earlier calibration in previous_calibration/); an earlier batch's results of "
                   "recordings not given stay, listed in the summary as earlier runs")
    s.add_argument("--prune", action="store_true",
                   help="with --force: remove the earlier batch's results of recordings not given this time")
    s.add_argument("--resume", action="store_true",
                   help="calibrate only the recordings whose folder in --out holds no result yet (the rest of an "
                   "interrupted batch); the others are listed in the summary from their folders")
    s.set_defaults(func=_cmd_batch)
    return p


def _emit(args: argparse.Namespace, text: str, code: int) -> int:
    """Print the command's output with its exit code decided first, so a reader that closes the pipe early
    (| head) does not change the code."""
    args.exit_code = code
    print(text)
    return code


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from ..sim.paper import reproduce_paper
    from .progress import ProgressBar

    trials = 20 if args.quick and args.trials == 200 else args.trials
    with ProgressBar("reproduce-paper") as bar:
        res = reproduce_paper(args.out, trials=trials, quick=args.quick, seed=args.seed, overwrite=args.force,
                              progress=bar)
    print(res["markdown"])
    print(f"\nwritten: {Path(args.out) / 'paper_tables.md'}, {Path(args.out) / 'paper_tables.json'}")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from ..io.inspect import format_inspection, inspect_recording
    from .progress import ProgressBar

    info = inspect_recording(args.log, progress=ProgressBar, count_events=not args.quick)
    if not info.get("topics"):
        why = "; ".join(info.get("warnings", [])) or "no messages"
        print(f"plsgraph: error: nothing readable in {args.log}: {why}", file=sys.stderr)
        _json_error(args, f"nothing readable in {args.log}: {why}", 2)
        return 2
    # The reader's warnings are in the listing (or the JSON) and were logged on stderr as they came: not again.
    print(json.dumps(info, indent=2) if args.json else format_inspection(info))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from ..api import simulate
    from .progress import ProgressBar

    paths = simulate(args.out, motion=args.motion, duration=args.duration, seed=args.seed, td=args.td,
                     event_format=args.event_format, overwrite=args.force, board=args.board,
                     contrast=args.contrast, realism="ideal" if args.ideal else "realistic", progress=ProgressBar)
    for p in paths:
        print(f"written: {p}")
    return 0


def _options(args: argparse.Namespace):
    """The calibration options from the flags (the only place that maps flags to settings)."""
    from ..options import CalibrationOptions

    topics = {
        role: getattr(args, attr)
        for role, attr in (("events", "events_topic"), ("joints", "joints_topic"), ("odometry", "odom_topic"))
        if getattr(args, attr, None)
    }
    settings = dict(board=args.board, camera_info=args.camera_info, wheel_radius=args.wheel_radius,
                    track_width=args.track_width, upright_camera=bool(getattr(args, "upright_camera", False)),
                    upside_down_camera=bool(getattr(args, "upside_down_camera", False)))
    if hasattr(args, "surface"):  # calibrate, diagnose, compare (batch takes the defaults)
        settings.update(topics=topics, left_joint=args.left_joint, right_joint=args.right_joint,
                        surface=args.surface, rate_hz=args.rate, window_s=args.window, tau_s=args.tau,
                        td_range=args.td_range, method=args.method,
                        truth=args.truth, camera_height=args.camera_height, board_height=args.board_height,
                        focal_sigma=args.focal_sigma,
                        odometry_file=args.odometry, clock_align=args.clock_align, clock_offset=args.clock_offset,
                        wheel_order=args.wheel_order,
                        parent_frame=args.parent_frame, child_frame=args.child_frame)
    return CalibrationOptions.build(**settings)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ..report.figure_worker import look_ahead

    look_ahead()  # whether a processor is free for the figures: looked at while the calibration's modules load
    from ..api import calibrate_to_dir
    from .progress import ProgressBar

    summary = calibrate_to_dir(args.log, args.out, _options(args), refine=not args.no_refine, force=args.force,
                               progress=ProgressBar)
    return _emit(args, summary["text"], 0 if summary["ok"] else 1)


def _cmd_diagnose(args: argparse.Namespace) -> int:
    from ..api import diagnose
    from ..report.text import diagnosis_text
    from .progress import ProgressBar

    res = diagnose(args.log, options=_options(args), progress=ProgressBar)
    return _emit(args, json.dumps(res.to_dict(), indent=2) if args.json else diagnosis_text(res), 0 if res.ok else 1)


def _cmd_compare(args: argparse.Namespace) -> int:
    from ..api import compare
    from ..errors import DegenerateMotionError, InsufficientDataError
    from ..report.text import comparison_text
    from .progress import ProgressBar

    try:
        res = compare(args.log, options=_options(args), progress=ProgressBar)
    except (DegenerateMotionError, InsufficientDataError) as exc:  # a result of the recording, not a user error
        print(f"plsgraph: no comparison: {exc}", file=sys.stderr)
        if args.json:  # a script reading stdout gets an answer it can parse, as diagnose --json gives
            print(json.dumps({"recording": str(args.log), "ok": False, "problems": [str(exc)], "warnings": [],
                              "rows": [], "failed": {}}, indent=2))
        return 1
    return _emit(args, json.dumps(res.to_dict(), indent=2) if args.json else comparison_text(res), 0 if res.ok else 1)


def _cmd_batch(args: argparse.Namespace) -> int:
    from ..batch import run_batch
    from ..errors import InputError
    from .progress import ProgressBar

    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    if args.prune and not args.force:
        raise InputError("--prune goes with --force (it removes earlier results, which only --force replaces)")
    if args.resume and (args.force or args.prune):
        raise InputError("--resume keeps the results there are and calibrates the rest; --force and --prune replace "
                         "or remove results: give one or the other")
    if not args.scheduler:
        with ProgressBar("calibrating recordings") as bar:
            res = run_batch(args.inputs, args.out, _options(args), force=args.force, jobs=args.jobs, prune=args.prune,
                            progress=bar, resume=args.resume)
        return _emit(args, res["text"], 0 if res["ok"] else 1)
    try:
        from dask.distributed import Client
    except ImportError as exc:
        raise InputError("--scheduler needs dask.distributed: pip install 'plsgraph[dask]'") from exc
    try:
        client = Client(args.scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {args.scheduler}: {exc}") from exc
    try:
        with ProgressBar("calibrating recordings") as bar:
            res = run_batch(args.inputs, args.out, _options(args), force=args.force, executor=client.get_executor(),
                            prune=args.prune, progress=bar, resume=args.resume)
    finally:
        client.close()
    return _emit(args, res["text"], 0 if res["ok"] else 1)


def main(argv: list[str] | None = None) -> int:
    from ..core.logs import warnings_once

    parser = _build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        if args.command in ("inspect", "calibrate", "diagnose", "compare") and any(Path(e).exists() for e in extra):
            parser.error(f"{args.command} takes one recording, and got more ({', '.join(extra)}); to calibrate "
                         "several, one after another or in parallel, use 'plsgraph batch'")
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")
    from .progress import end_bar_line

    with warnings_once():  # each warning once; taken off the handlers again when the command ends
        for handler in logging.getLogger().handlers:  # a warning starts on a line of its own, not after a bar:
            handler.removeFilter(end_bar_line)  # last, so that only a record the filters let through ends the line
            handler.addFilter(end_bar_line)
        return _run_command(args)


def _json_error(args: argparse.Namespace, message: str, code: int) -> None:
    """With --json, an error is also JSON on stdout (``ok`` false, ``error``, ``exit_code``): a script that parses
    the output gets an answer, not an empty string."""
    if getattr(args, "json", False):
        try:
            print(json.dumps({"ok": False, "error": message, "exit_code": code}))
        except (OSError, ValueError):  # stdout itself failed (a full disk, a closed pipe): stderr has the message
            pass


def _run_command(args: argparse.Namespace) -> int:
    SIGNALS_RECEIVED.clear()  # this command's own
    written = getattr(sys.modules.get("plsgraph.report.files"), "JUST_WRITTEN", None)
    if written:
        written.clear()
    try:
        return int(args.func(args) or 0)
    except PlsgraphError as exc:
        code = _ended_by_signal(exc, args)
        if code is not None:
            return code
        print(f"plsgraph: error: {exc}", file=sys.stderr)
        _json_error(args, str(exc), 2)
        return 2
    except BrokenPipeError:  # the reader of our output went away (| head): not an error of ours
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return getattr(args, "exit_code", 0)
    except OSError as exc:  # unwritable output folder, a file where a folder should be, a full disk
        from ..report.files import disk_message

        code = _ended_by_signal(exc, args)
        if code is not None:
            return code

        msg = disk_message(exc, getattr(args, "out", None))
        print(f"plsgraph: error: {msg}", file=sys.stderr)
        _json_error(args, msg, 2)
        return 2
    except Terminated as exc:  # SIGTERM (a job scheduler, systemd, kill) or SIGHUP (a closed terminal or ssh session)
        return _signal_exit(args, exc.signum)
    except KeyboardInterrupt:
        return _signal_exit(args, signal.SIGINT)
    except Exception as exc:  # a bug: say so plainly, keep the traceback for the report with --verbose
        code = _ended_by_signal(exc, args)
        if code is not None:
            return code
        if type(exc).__name__ == "BrokenProcessPool":  # a worker process killed, not a bug of ours
            msg = ("a worker process ended abruptly (killed: out of memory, or a signal; the system log, e.g. dmesg, "
                   "says which); nothing was written, an earlier result in --out is kept")
            print(f"plsgraph: error: {msg}", file=sys.stderr)
            _json_error(args, msg, 3)
            return 3
        if args.verbose:
            traceback.print_exc()
        print(f"plsgraph: internal error ({type(exc).__name__}: {exc}); please report it with the command line "
              "and, if possible, the recording (run with -v for the traceback)", file=sys.stderr)
        _json_error(args, f"internal error ({type(exc).__name__}: {exc})", 3)
        return 3


# Commands that work on one recording in this process and leave nothing running behind: when they are done,
# run() ends the process at once.
QUICK_EXIT_COMMANDS = frozenset({"inspect", "simulate", "calibrate", "diagnose", "compare"})


def single_threaded_blas() -> None:
    """Give numpy's BLAS one thread in this process and the ones it starts, unless the user chose otherwise; it must
    run before numpy loads. The command's matrices are small and its processors already busy (the front end's
    workers, the refinement's second process, the figures), and OpenBLAS's extra threads spin on after each call:
    with one thread, ``plsgraph calibrate`` of the 20 s benchmark recording took 4.64 s instead of 4.99 s (medians
    of 3, alternating runs), the same answer."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


#: The signals this command was sent (:func:`terminate_like_interrupt`), newest last.
SIGNALS_RECEIVED: list[int] = []


def _ended_by_signal(exc: Exception, args: argparse.Namespace) -> int | None:
    """The exit code of a run a signal ended although ``exc`` reached the top: an interrupt raised inside an import of
    a compiled module comes out as its ImportError, and a half-initialised module (gtsam) then fails again at its next
    import ("type ... is already registered"), which is the signal's doing, not a bug. None: no signal came."""
    from ..core.processes import interrupt_behind

    behind = interrupt_behind(exc)
    if behind is not None:
        signum = getattr(behind, "signum", signal.SIGINT)  # Terminated carries its signal; Ctrl-C's does not
    elif SIGNALS_RECEIVED:
        signum = SIGNALS_RECEIVED[-1]
    else:
        return None
    if args.verbose:  # what surfaced, for a reader who suspects a bug behind it
        traceback.print_exc()
    return _signal_exit(args, signum)


def _signal_exit(args: argparse.Namespace, signum: int) -> int:
    """Say that a signal ended the command (on stderr, and as JSON with --json) and give its exit code."""
    if signum == signal.SIGINT:
        msg, code = _interrupted_message(), 130
    else:
        msg, code = _terminated_message(signal.Signals(signum).name), 128 + int(signum)
    print(msg, file=sys.stderr)
    _json_error(args, msg.removeprefix("plsgraph: "), code)
    return code


def _just_written() -> object:
    """The --out whose result was put in place as the interrupt came (report.files.JUST_WRITTEN), or None."""
    written = getattr(sys.modules.get("plsgraph.report.files"), "JUST_WRITTEN", None)
    return written[-1] if written else None


def _interrupted_message() -> str:
    written = _just_written()
    if written is not None:
        return f"plsgraph: interrupted as the run ended; its result was written to {written}"
    return "plsgraph: interrupted"


def _terminated_message(name: str) -> str:
    written = _just_written()
    if written is not None:  # the signal came while the finished result was being put in place, and it was
        return f"plsgraph: terminated ({name}) as the run ended; its result was written to {written}"
    return (f"plsgraph: terminated ({name}); what the run had written in progress is removed, an earlier result in "
            "its --out is kept")


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the command's main thread like Ctrl-C's KeyboardInterrupt, so that the same
    clean-up runs (staging folder removed, worker processes stopped, an earlier result kept)."""

    def __init__(self, signum: int):
        import signal

        super().__init__(signum)
        self.signum = int(signum)
        self.name = signal.Signals(signum).name


def terminate_like_interrupt() -> None:
    """SIGTERM and SIGHUP end the command as Ctrl-C does (:class:`Terminated`), in this process only: a process
    forked from it (the refinement's second opinion, a figure) keeps the default, dying at once. Every signal this
    process takes, Ctrl-C's included, is kept in :data:`SIGNALS_RECEIVED` (see :func:`_ended_by_signal`)."""
    import signal

    me = os.getpid()

    def handler(signum, frame):
        if os.getpid() != me:  # a forked child: as Python's default would (Ctrl-C raises, the others kill)
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        SIGNALS_RECEIVED.append(int(signum))
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    for sig, default in ((signal.SIGTERM, (signal.SIG_DFL, None)), (signal.SIGHUP, (signal.SIG_DFL, None)),
                         (signal.SIGINT, (signal.default_int_handler,))):
        try:
            if signal.getsignal(sig) in default:
                signal.signal(sig, handler)
        except (ValueError, OSError):  # not the main thread, or a platform without the signal
            pass


def run() -> None:
    """The ``plsgraph`` command (the console script): :func:`main`, then, for :data:`QUICK_EXIT_COMMANDS`, the
    process ends at once (:func:`end_process`) instead of tearing the interpreter down, which takes a third of a
    second after a calibration (gtsam, OpenCV and scipy are loaded) for nothing the user sees."""
    argv = sys.argv[1:]
    single_threaded_blas()
    terminate_like_interrupt()
    code = main(argv)
    if next((a for a in argv if not a.startswith("-")), None) in QUICK_EXIT_COMMANDS:
        end_process(code)
    sys.exit(code)


def end_process(code: int) -> NoReturn:
    """End the process with ``code`` now: logging, stdout and stderr are flushed; the interpreter's teardown (freeing
    every module's objects) is skipped. Only for a process whose files are all written and closed, with no other
    process or thread of its own still at work."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (| head) or stream: nothing more can reach it
            pass
    os._exit(code)


if __name__ == "__main__":
    run()
