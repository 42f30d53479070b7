"""Many recordings at once: each calibrated into its own folder, in parallel (local processes or any
``concurrent.futures`` executor, e.g. a Dask client's), one summary table."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from .errors import InputError, PlsgraphError
from .options import CalibrationOptions

log = logging.getLogger(__name__)

RECORDING_SUFFIXES = (".mcap", ".bag", ".db3")
#: Event-only files: they need their odometry from a second file (calibrate --odometry), which batch does not take.
EVENT_ONLY_SUFFIXES = (".raw", ".aedat4")


def is_bag_folder(p: Path) -> bool:
    """A ROS 2 bag folder (its metadata.yaml beside its .db3 or .mcap files): one recording, named after the folder,
    its NAME.options.yaml and NAME.truth.yaml beside the folder."""
    meta = p / "metadata.yaml"
    if not (p.is_dir() and meta.is_file()):
        return False
    try:  # a dataset's own metadata.yaml beside its recordings is not a bag's
        with open(meta, errors="replace") as f:
            return "rosbag2_bagfile_information" in f.read(65536)
    except OSError:
        return False


def recording_name(p: str | Path) -> str:
    """A recording's name in the batch (its result folder, its NAME.options.yaml and NAME.truth.yaml): a file's name
    without its suffix, a bag folder's whole name (``run.v2`` stays ``run.v2``)."""
    p = Path(p)
    return p.name if p.is_dir() else p.stem


def find_recordings(inputs: list[Path]) -> list[Path]:
    """The recordings named, or held by the folders named (a ROS 2 bag folder is one recording, whether named or
    held); two with one name are refused (their folders would collide)."""
    found: list[Path] = []
    for p in inputs:
        p = Path(p)
        if is_bag_folder(p):
            found.append(p)
        elif p.is_dir():
            found += sorted(q for q in p.iterdir()
                            if (q.suffix in RECORDING_SUFFIXES and q.is_file()) or is_bag_folder(q))
        elif p.is_file():
            if p.suffix in EVENT_ONLY_SUFFIXES:
                raise InputError(f"{p} holds events only: its odometry comes from a second file, which batch does not "
                                 f"take; calibrate it with 'plsgraph calibrate {p} --odometry ODOMETRY_FILE ...'")
            found.append(p)
        else:
            raise InputError(f"{p} does not exist")
    if not found:
        raise InputError(f"no recordings ({', '.join(RECORDING_SUFFIXES)} files or ROS 2 bag folders) in "
                         f"{', '.join(map(str, inputs))}")
    unique: dict[Path, Path] = {}
    for p in found:  # the same file given twice (overlapping globs, a folder and a file in it): calibrated once
        unique.setdefault(Path(os.path.normpath(p.absolute())), p)
    found = list(unique.values())
    names = [recording_name(p) for p in found]
    if len(set(names)) != len(names):
        same = sorted({n for n in names if names.count(n) > 1})
        paths = [str(p) for p in found if recording_name(p) in same]
        raise InputError(f"recordings share a name ({', '.join(same)}: {', '.join(paths)}); their output folders "
                         "would collide: rename or move one of them")
    return found


def _batch_item(item: tuple[str, str, CalibrationOptions, bool], seed: int = 0) -> dict:
    """Worker: calibrate one recording into its own folder; never raises for a user-level failure.

    The pipeline is deterministic, so the per-item ``seed`` that the executor layer hands out is not needed."""
    from .core.logs import warnings_once

    with warnings_once(Path(item[0]).name):  # a damaged file's reader warnings once, not once per pass over it
        return _calibrate_item(item)


def _calibrate_item(item: tuple[str, str, CalibrationOptions, bool]) -> dict:
    from .api import calibrate_to_dir

    log_path, out_dir, opts, force = item
    t0 = time.perf_counter()
    try:
        # The recordings already share the processors: the figures are drawn in this process.
        res = calibrate_to_dir(log_path, out_dir, opts, force=force, figure_worker=False)
        rep = res["report"]
        c = rep["calibration"] or {}  # None when the motion only allowed a diagnosis
        row = _row(log_path, out_dir, "ok" if res["ok"] else "flagged", c, rep["problems"], rep.get("warnings", []))
        if "truth_errors" in rep:
            row["truth_errors"] = rep["truth_errors"]
        if rep.get("previous_calibration"):
            row["previous_calibration"] = str((Path(out_dir) / rep["previous_calibration"]).absolute())
    except PlsgraphError as exc:
        row = _failed_row(log_path, out_dir, f"{type(exc).__name__}: {exc}")
        _replace_with_failure(log_path, out_dir, force, row["error"])
        row["previous_calibration"] = _kept_calibration(out_dir)
    except OSError as exc:  # a full disk, a folder that cannot be written: the recording's, said plainly
        from .report.files import disk_message

        row = _failed_row(log_path, out_dir, disk_message(exc, out_dir))
        log.warning("%s: %s", Path(log_path).name, row["error"])
        # The folder keeps what it held, as the message says: not replaced by a failure's report (which, once the
        # failed run's stage has freed its room, might fit, and would take the earlier calibration's place).
        row["previous_calibration"] = _kept_calibration(out_dir)
    except Exception as exc:  # a bug must not stop the other recordings; it is reported in the summary
        from .core.processes import reraise_interrupt

        reraise_interrupt(exc)  # an interrupt inside an import stops the batch, as any interrupt does
        if type(exc).__name__ == "BrokenProcessPool":  # its front end's worker killed: no bug of ours
            error = ("a worker process of its front end was killed (out of memory, or a signal: see the system log, "
                     "e.g. dmesg)")
            log.warning("%s: %s", Path(log_path).name, error)
        else:
            log.exception("unexpected failure on %s", log_path)
            error = f"internal error {type(exc).__name__}: {exc}"
        row = _failed_row(log_path, out_dir, error)
        _replace_with_failure(log_path, out_dir, force, row["error"])
        row["previous_calibration"] = _kept_calibration(out_dir)
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def _kept_calibration(out_dir: str) -> str | None:
    """The earlier calibration a failed recording's folder kept (its report.json names it), as an absolute path."""
    import json

    try:
        kept = json.loads((Path(out_dir) / "report.json").read_text()).get("previous_calibration")
    except (OSError, ValueError, AttributeError):
        return None
    return str((Path(out_dir) / kept).absolute()) if kept else None


def _row(log_path: str, out_dir: str, status: str, c: dict, problems: list, warnings: list,
         error: str | None = None) -> dict:
    """A summary row, with the same keys whatever the outcome (None where there is no value): the recording (its
    absolute path), its result folder, the status (ok, flagged, failed), the extrinsic and its sigmas (``sigma``:
    the observability list's, name -> value in its unit, deg, m or ms, roll, pitch and yaw there being rotations
    about the base axes; ``rpy_sigma_deg``: the sigmas of ``rpy_deg``'s Euler angles), the problems (a failure's
    error among them) and the warnings."""
    obs = c.get("observability") or []
    return {"recording": str(Path(log_path).absolute()), "folder": str(Path(out_dir).absolute()), "status": status,
            "source": c.get("source"), "rpy_deg": c.get("rpy_deg"), "rpy_sigma_deg": c.get("rpy_sigma_deg"),
            "translation_m": c.get("translation_m"),
            "time_offset_s": c.get("time_offset_s"),
            "sigma": {o["name"]: o.get("sigma") for o in obs if isinstance(o, dict) and "name" in o} or None,
            "sigma_units": {o["name"]: o.get("unit") for o in obs if isinstance(o, dict) and "name" in o} or None,
            "translation_z_status": c.get("translation_z_status"), "problems": list(problems),
            "warnings": list(warnings), "error": error, "previous_calibration": None, "options_file": None}


def _failed_row(log_path: str, out_dir: str, error: str) -> dict:
    return _row(log_path, out_dir, "failed", {}, [error], [], error)


def _replace_with_failure(log_path: str, out_dir: str, force: bool, error: str) -> None:
    """A failed recording gets a folder with a report.json saying so: a new one, or with --force the earlier one
    replaced (an older ok calibration.yaml there must not pass for this run's; it is kept in previous_calibration/);
    without --force an existing folder was refused and stays as it was."""
    from .api import failure_to_dir
    from .report.files import CALIBRATION_SUBFOLDERS, foreign_entries

    if Path(out_dir).exists() and (not force or foreign_entries(Path(out_dir), subfolders=CALIBRATION_SUBFOLDERS)):
        return  # refused, or a folder of the user's own (--force replaces only an earlier result)
    try:
        failure_to_dir(log_path, out_dir, error)
    except Exception:  # another run holds the folder, or it cannot be written: the summary row still says failed
        log.exception("could not mark %s as failed", out_dir)


def _as_row(result: Any, item: tuple) -> dict:
    """refine_many's per-item outcome -> summary row (an exception it caught becomes a failed row)."""
    if result.ok and isinstance(result.value, dict):
        return result.value
    error = f"{result.error_type}: {result.error}"
    if result.error_type == "BrokenProcessPool":
        error = ("the worker process calibrating it was killed (out of memory, or a signal: see the system log, "
                 "e.g. dmesg); its folder keeps what it held")
    return {**_failed_row(item[0], item[1], error), "seconds": round(result.seconds, 2)}


def _stop_workers(executor: Any) -> None:
    """A batch interrupted: its pool's workers killed now (:func:`plsgraph.refine.batch.stop_workers`); a folder caught
    mid-swap is put back by the next run on it."""
    from .refine.batch import stop_workers

    stop_workers(executor)


def skipped_in_folders(inputs: list[Path]) -> list[str]:
    """What the folders given hold that a batch does not calibrate, said so that nothing is skipped silently:
    event-only files (they need --odometry) and recordings in sub-folders (folders are not searched down)."""
    notes = []
    for p in map(Path, inputs):
        if not p.is_dir():
            continue
        events = sorted(q.name for q in p.iterdir() if q.suffix in EVENT_ONLY_SUFFIXES and q.is_file())
        nested = sorted(str(q.relative_to(p)) for q in p.glob("*/*")
                        if q.suffix in RECORDING_SUFFIXES and q.is_file() and not is_bag_folder(q.parent))
        if events:
            notes.append(f"not calibrated: {', '.join(events)} in {p} (events only: calibrate each with --odometry)")
        if nested:
            notes.append(f"not calibrated: {', '.join(nested[:5])}{' ...' if len(nested) > 5 else ''} in "
                         f"sub-folders of {p} (name the sub-folders to include them)")
    return notes


def _check_shared_inputs(options: CalibrationOptions) -> None:
    """What every recording of the batch uses (the board, an intrinsics file) checked once, before any work: a wrong
    one is the user's error, not a failure of each recording."""
    from .core.board import load_board
    from .io.camera_files import split_camera_choice

    load_board(options.board)
    if options.inputs.camera_info is not None:
        # Only that it is there: which camera of a camchain is used depends on each recording's events topic.
        path, _ = split_camera_choice(options.inputs.camera_info)
        if not path.is_file():
            raise InputError(f"camera file {path} does not exist")
    odo = options.inputs.odometry_file
    if odo is not None and not Path(odo).exists():
        raise InputError(f"odometry file {odo} does not exist")


def run_batch(
    inputs: list[Path],
    out_dir: str | Path,
    options: CalibrationOptions,
    force: bool = False,
    jobs: int | None = None,
    executor: Executor | None = None,
    prune: bool = False,
    progress: Callable[[int, int], None] | None = None,
    resume: bool = False,
) -> dict:
    """Calibrate every recording in ``inputs`` into ``out_dir/<name>/``; a ``<name>.truth.yaml`` beside a
    recording is used as its truth. Returns ``{ok, text, rows}`` and writes summary.json / summary.md.

    With ``force`` into a folder of an earlier batch, the results of its recordings that this batch does not calibrate
    again stay, and so do their rows in the summary (``earlier_run``: true), so that one recording can be calibrated
    again alone; ``prune`` removes them instead. ``ok`` is about this batch's recordings."""
    from .report.files import OutputLock, prepare_output_dir

    if jobs is not None and jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {jobs}")
    logs = find_recordings(inputs)
    _check_shared_inputs(options)
    for p in logs:  # every recording's own settings checked before any work: a wrong one is the user's to fix
        recording_options(p, options)
    # Written into; each recording's folder replaced. --resume goes on in a folder that holds results.
    out = prepare_output_dir(out_dir, force=force or resume, whole=False)
    if out.is_symlink():  # one lock per folder, however it is named (a link to it too)
        out = out.resolve()
    # One batch at a time in a folder (a second one fails at once; before, two marked each other's recordings failed).
    with OutputLock(out):
        done: list[Path] = []
        if resume:  # the recordings with a result already: listed from their folders, not calibrated again
            # A failure's folder (no calibration, no diagnosis: a broken file, a full disk) is tried again.
            done = [p for p in logs if (out / recording_name(p) / "report.json").is_file()
                    and _row_from_folder({"recording": str(p)}, out / recording_name(p))["status"] != "failed"]
            logs = [p for p in logs if p not in done]
        return _run_batch_in(inputs, out, logs, options, force or resume, jobs, executor, prune, progress, done)


def _run_batch_in(inputs: list[Path], out: Path, logs: list[Path], options: CalibrationOptions, force: bool,
                  jobs: int | None, executor: Executor | None, prune: bool,
                  progress: Callable[[int, int], None] | None = None, done: list[Path] | None = None) -> dict:
    from dataclasses import replace

    from .refine.batch import default_executor, refine_many, rerun_broken
    from .report.files import markdown_table, write_json, write_text

    earlier = _earlier_batch_rows(out)  # read before this batch's summary replaces the earlier one
    if (out / "summary.json").is_file():
        # Set aside, not deleted: if this batch is interrupted, the next one still finds which folders an earlier
        # batch made (to list them, or to --prune them). Removed once this batch's summary is written.
        (out / "summary.json").replace(out / EARLIER_SUMMARY)
    # From now on the folders are this batch's: an earlier summary would describe folders being replaced (and, if
    # this batch is interrupted, a mix of the two runs). This batch's summary is written when it completes.
    (out / "summary.md").unlink(missing_ok=True)
    items = []
    for p in logs:
        truth = p.with_name(recording_name(p) + ".truth.yaml")
        own = recording_options(p, options)
        if own.truth is None or own is options:  # a truth its options file names stands; else NAME.truth.yaml
            own = replace(own, truth=truth if truth.exists() else None)
        items.append((str(p), str(out / recording_name(p)), own, force))
    own = executor is None
    if own:
        executor = default_executor(len(items), jobs, ignore_interrupt=True)  # stopped below on an interrupt
    started = time.time()
    try:
        results = refine_many(items, _batch_item, executor=executor, progress=progress)
        broken = [k for k, r in enumerate(results) if not r.ok and r.error_type == "BrokenProcessPool"]
        if broken and own:
            # A worker process died (killed: out of memory, or a signal), which breaks the pool and fails every
            # recording it had not finished, not only its own: each is calibrated again, alone in a fresh process.
            executor.shutdown(wait=False, cancel_futures=True)
            log.warning("a worker process of the batch ended abruptly (killed: out of memory, or a signal); the %d "
                        "recording(s) it left unfinished are calibrated again, one at a time", len(broken))
            results = rerun_broken(items, results, _batch_item)
    except KeyboardInterrupt:
        if own:  # no recording starts or finishes after the interrupt: the folders said below are all there is
            _stop_workers(executor)
            from .report.files import clear_after_killed_run

            for item in items:  # the killed workers' staging folders and locks
                clear_after_killed_run(item[1])
        done = [Path(item[1]).name for item in items if _written_since(Path(item[1]), started)]
        log.warning("batch interrupted: %s (the recordings being calibrated were stopped; their folders keep what they "
                    "held); no summary is written (run the batch again with --resume to calibrate the rest and write "
                    "one)",
                    f"so far the folders of {', '.join(done)} are this run's" if done else
                    "no recording had finished yet")
        raise
    finally:
        if own:
            executor.shutdown(wait=True, cancel_futures=True)  # after an interrupt: the rest never start
    rows = [_as_row(r, item) for r, item in zip(results, items, strict=True)]
    for row, item in zip(rows, items, strict=True):
        own = Path(item[0]).with_name(recording_name(item[0]) + OPTIONS_SUFFIX)
        row["options_file"] = str(own.absolute()) if own.is_file() else None
    notes = []
    if done:  # --resume: the recordings that had a result, as their folders hold it
        for p in done:
            base = earlier.get(recording_name(p)) or _row(str(p), str(out / recording_name(p)), "ok", {}, [], [])
            rows.append({**_row_from_folder({**base, "recording": str(p.absolute())}, out / recording_name(p)),
                         "earlier_run": True})
        notes.append(f"--resume: {len(done)} recording(s) already had a result and were not calibrated again "
                     f"(listed as earlier runs): {', '.join(recording_name(p) for p in done)}")
        rows.sort(key=lambda r: Path(str(r["recording"])).name)
    ok = all(r["status"] == "ok" for r in rows)  # the recordings given, those --resume found done among them
    given = {Path(item[1]).name for item in items} | {recording_name(p) for p in done or []}
    others = {name: row for name, row in earlier.items() if name not in given}
    if force and prune:
        stale = _remove_stale_results(out, set(others))
        if stale:
            notes.append(f"removed the earlier results of recordings not in this batch (--prune): {', '.join(stale)}")
    elif others:
        kept = [name for name in sorted(others) if (out / name / "report.json").is_file()]
        rows += [{**_row_from_folder(others[name], out / name), "earlier_run": True} for name in kept]
        if kept:
            notes.append(f"kept the earlier results of recordings not in this batch (listed as earlier runs; --prune "
                         f"removes them): {', '.join(kept)}")
    for r in rows:
        if r.get("previous_calibration") and not r.get("earlier_run"):
            notes.append(f"kept the calibration {Path(r['folder']).name}'s folder held before in "
                         f"{r['previous_calibration']} (this run's result is {r['status']})")
    write_json(out / "summary.json", {"recordings": rows})
    (out / EARLIER_SUMMARY).unlink(missing_ok=True)
    table = markdown_table(
        [{"recording": Path(r["recording"]).name,
          "status": r["status"] + (" (earlier run)" if r.get("earlier_run") else ""), "seconds": r.get("seconds"),
          "roll": (r.get("rpy_deg") or [None] * 3)[0], "pitch": (r.get("rpy_deg") or [None] * 3)[1],
          "yaw": (r.get("rpy_deg") or [None] * 3)[2], "td_ms": None if r.get("time_offset_s") is None
          else 1e3 * r["time_offset_s"], "warnings": len(r.get("warnings") or []),
          "error": r.get("error") or "; ".join(r.get("problems") or [])} for r in rows],
        ["recording", "status", "roll", "pitch", "yaw", "td_ms", "seconds", "warnings", "error"],
    )
    write_text(out / "summary.md", table + "\n")
    text = table + f"\n\nwritten: {out / 'summary.json'}, {out / 'summary.md'}"
    for note in [*skipped_in_folders(inputs), *notes]:
        text += "\n" + note
    return {"ok": ok, "text": text, "rows": rows}


#: A recording's own settings: ``NAME.options.yaml`` beside ``NAME.mcap`` (a mapping of calibrate's settings by their
#: option names: wheel_radius, track_width, camera_height, camera_info, left_joint, topics, ...).
OPTIONS_SUFFIX = ".options.yaml"
#: Settings of an options file that name files: relative to that file's folder.
PATH_SETTINGS = ("camera_info", "truth", "odometry_file")


def recording_options(recording: Path, options: CalibrationOptions) -> CalibrationOptions:
    """``options`` with the settings of the recording's ``NAME.options.yaml`` (beside it) over them, if there is one:
    a fleet's robots differ in wheels, camera height and topics. A relative ``camera_info`` path there is relative to
    that file's folder. An unknown name or a bad value is an :class:`InputError` naming the file."""
    from .core.resources import read_yaml_mapping

    f = Path(recording).with_name(recording_name(recording) + OPTIONS_SUFFIX)
    if not f.is_file():
        return options
    settings = read_yaml_mapping(f, "recording options file")
    try:
        settings = CalibrationOptions._canonical_names(options, settings)  # the command line's names as well
    except InputError as exc:
        raise InputError(f"{f}: {exc}") from None
    if "board" in settings:
        raise InputError(f"{f}: the board is the batch's (--board), not a recording's")
    for key in PATH_SETTINGS:  # relative to the options file's folder, made absolute (a Dask worker's folder differs)
        if isinstance(settings.get(key), str):
            settings[key] = str((f.parent / settings[key]).absolute())
    topics = settings.get("topics")
    if topics is not None and not (isinstance(topics, dict) and all(isinstance(k, str) and isinstance(v, str)
                                                                     for k, v in topics.items())):
        raise InputError(f"{f}: topics must map roles (events, joints, odometry) to topic names, got {topics!r}")
    try:
        merged = CalibrationOptions.build(options, **settings)
        _check_shared_inputs(merged)  # an intrinsics file named there must exist too
    except (InputError, TypeError, ValueError) as exc:
        raise InputError(f"{f}: {exc}") from None
    return merged


def _written_since(folder: Path, t0: float) -> bool:
    """Whether a recording's folder holds a report.json written since ``t0`` (this batch's)."""
    try:
        return (folder / "report.json").stat().st_mtime >= t0
    except OSError:
        return False


#: An earlier batch's summary.json while a batch runs (an interrupted batch leaves it for the next).
EARLIER_SUMMARY = ".summary-earlier.json"


def _row_from_folder(row: dict, folder: Path) -> dict:
    """An earlier batch's summary ``row`` as its ``folder`` holds it now: status, extrinsic, sigmas, problems and
    warnings read from the folder's report.json. The earlier summary may describe another result than the folder's
    (a batch interrupted after it replaced the folder, before it wrote its own summary); the folder is what a user
    would take. A report.json that cannot be read leaves the row as the summary had it, with a warning saying so."""
    import json

    try:
        rep = json.loads((folder / "report.json").read_text())
        if not isinstance(rep, dict):
            raise ValueError("not a mapping")
    except (OSError, ValueError) as exc:
        return {**row, "warnings": [*(row.get("warnings") or []),
                                    f"its folder's report.json could not be read ({exc}): this row is the earlier "
                                    "summary's, which may not describe the folder"]}
    c = rep.get("calibration") or {}
    problems = list(rep.get("problems") or [])
    if rep.get("ok"):
        status, error = "ok", None
    elif c or rep.get("advice"):  # a flagged calibration, or a diagnosis (too little motion, too little data)
        status, error = "flagged", None
    else:  # a failure's report: no calibration and no advice, the error among its problems
        status, error = "failed", (problems[0] if problems else row.get("error"))
    new = _row(row.get("recording") or str(folder), str(folder), status, c, problems, list(rep.get("warnings") or []),
               error)
    new["seconds"] = row.get("seconds")
    new["options_file"] = row.get("options_file")
    if "truth_errors" in rep:
        new["truth_errors"] = rep["truth_errors"]
    if rep.get("previous_calibration"):
        new["previous_calibration"] = str((folder / rep["previous_calibration"]).absolute())
    return new


def _earlier_batch_rows(out: Path) -> dict[str, dict]:
    """The rows of an earlier batch's summary.json in ``out`` (or of the one an interrupted batch set aside) by their
    recording's folder name, with every key a row has (None where an older version wrote none); empty when there is
    none, or it cannot be read. Only those folders are a batch's to keep listing, or to remove."""
    import json

    blank = {**dict.fromkeys(_failed_row("", "", "")), "problems": [], "warnings": []}
    for name in ("summary.json", EARLIER_SUMMARY):
        try:
            rows = json.loads((out / name).read_text()).get("recordings", [])
        except (OSError, ValueError, AttributeError, TypeError):
            continue
        try:
            return {recording_name(str(r["recording"])): {**blank, **r} for r in rows
                    if isinstance(r, dict) and r.get("recording")}
        except (TypeError, AttributeError):
            return {}
    return {}


def _remove_stale_results(out: Path, stale_names: set[str]) -> list[str]:
    """With --force the batch's folder holds this batch's results only: remove the folders of the earlier batch's
    recordings (``stale_names``: listed in its summary.json) that are not in this one, when they hold nothing but what
    plsgraph writes; anything else stays (a calibration's folder put there by hand is no batch's to remove)."""
    import shutil

    from .report.files import CALIBRATION_SUBFOLDERS, RESULT_FILES, foreign_entries

    stale = []
    for d in sorted(p for p in out.iterdir() if p.is_dir() and not p.is_symlink() and p.name in stale_names
                    and not p.name.startswith(".")):  # hidden: a staging folder of a run, not a recording's
        ours = not foreign_entries(d, subfolders=CALIBRATION_SUBFOLDERS)
        if ours and any(f.name in RESULT_FILES for f in d.iterdir()):
            shutil.rmtree(d)
            stale.append(d.name)
    return stale
