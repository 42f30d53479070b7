"""Result folders: calibration.yaml, report.json, report.html and its pictures, or a diagnosis only.

:func:`write_result_folder` is how a run writes: under a lock on the folder, everything goes into a fresh staging
folder beside it that replaces the folder as a whole at the end (see :mod:`plsgraph.report.files`), so a folder
never holds files of two runs and an interrupted run leaves the previous result as it was.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from .coverage import DETECTED, NOT_SEARCHED
from .files import OutputLock, _atomic_write, staged_output, to_jsonable, write_json

log = logging.getLogger(__name__)


def _flagged_header(problems: list[str]) -> str:
    lines = ["# FLAGGED - DO NOT USE THIS CALIBRATION (ok: false). Problems:"]
    lines += [f"#   - {p}" for p in problems] or ["#   - (see report.json)"]
    lines.append("# There is deliberately no ready-to-paste transform line: fix the input and calibrate again.")
    return "\n".join(lines) + "\n"


def write_calibration_yaml(path: Path, calib: dict) -> None:
    """calibration.yaml; a flagged one starts with a comment block saying why not to use it."""
    text = yaml.safe_dump(to_jsonable(calib), sort_keys=False, default_flow_style=None, width=120)
    if calib.get("ok") is False:
        text = _flagged_header(list(calib.get("problems") or [])) + text
    _atomic_write(Path(path), text.encode())


def write_calibration(out: Path, result: Any, figures: Any = None, earlier: Path | None = None) -> list[Path]:
    """Write a :class:`plsgraph.result.CalibrationResult` into the folder ``out`` (made if missing). ``earlier``: the
    folder this one replaces; when the result is flagged, a calibration in it is kept in ``previous_calibration``
    (:func:`keep_earlier_calibration`).

    ``figures``: a started :class:`plsgraph.report.figure_worker.FigureWorker` draws the figures while the other
    files are written (else, or if it fails, they are drawn here). report.html and report.json come last: a figure
    that fails adds its warning to them. ``report["timing_s"]["figures"]`` is the time the figures held this
    process up (drawing them, or waiting for the worker)."""
    import time

    from .figures import write_html_report
    from .robot_files import write_lens_camera, write_robot_files

    report = result.report
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pending = figures is not None and figures.available
    if pending:
        figures.send(out, result.run)  # drawn in the worker while the files below are written
    elif figures is not None:
        figures.close()  # a worker that ended: nothing it wrote is kept
    waited = time.perf_counter() - t0
    write_calibration_yaml(out / "calibration.yaml", report["calibration"])
    robot = write_robot_files(out, result)  # a flagged result gets comment-only files that say why
    robot += write_lens_camera(out, result)  # the board views' distortion, for a second run
    if not report.get("ok", True) and keep_earlier_calibration(earlier, out) is not None:
        report["previous_calibration"] = PREVIOUS_CALIBRATION
    else:
        report.pop("previous_calibration", None)
    t1 = time.perf_counter()
    drawn = figures.result() if pending else None
    write_html_report(out, result.run, report, drawn)  # drawn here when the worker did not (drawn is None)
    report.setdefault("timing_s", {})["figures"] = round(waited + time.perf_counter() - t1, 4)
    write_json(out / "report.json", report)
    return [out / "calibration.yaml", out / "report.json", out / "report.html", *robot]


def coverage_line(cov: dict) -> str:
    """One line on the front end's coverage, for a summary."""
    moving = cov.get("found_fraction_robot_moving")
    also = "" if moving is None else f", {100 * moving:.0f} % of those in which the robot moved"
    if cov.get("clocks_not_aligned"):
        also = " (the odometry's clock was not aligned with the camera's, so its motion is not known there)"
    # The detector's reasons first; windows passed over while the board was lost (not searched) last.
    missed = [f"{k} {v}" for k, v in sorted(cov.get("by_outcome", {}).items(), key=lambda kv: kv[0] == NOT_SEARCHED)
              if k not in DETECTED][:4]
    why = f"; missed: {', '.join(missed)}" if missed else ""
    return f"board found in {cov['found']} of {cov['windows']} windows{also}{why}"


DIAGNOSIS_ADVICE = (
    "drive forwards and backwards while turning (arcs, S-curves) with the board in view; driving straight leaves the "
    "camera's roll about the driving direction and the lever arm undetermined, turning in place its yaw and the lever "
    "arm"
)
#: The advice when reading the recording lost messages (it is cut short or damaged) and too little was left.
DAMAGED_ADVICE = ("the recording is cut short or damaged (see the warnings): use a complete copy, or recover what is "
                  "readable (for MCAP: `mcap recover`) and record again if too little is left")
#: The advice when the front end found (almost) no board: the board or camera files come before the driving.
FRONTEND_ADVICE = (
    "check --board against the printed target (pattern, rows x columns, spacing) and --camera-info against the "
    "camera; keep the whole board in view, lit, while the robot moves"
)


#: Where a run that gives no calibration keeps the calibration it replaces (see :func:`keep_earlier_calibration`).
PREVIOUS_CALIBRATION = "previous_calibration"


def keep_earlier_calibration(earlier: Path | None, stage: Path) -> Path | None:
    """A run that ends without a calibration (a diagnosis, a failure) into a folder that holds one (``--force``) keeps
    that calibration's files in ``stage / PREVIOUS_CALIBRATION``: the folder says what the latest run gave, and a good
    result is not lost to a bad recording. A folder without a calibration passes on the one it kept. Only result files
    are copied (one generation). Returns the subfolder, or None when there is no calibration to keep."""
    import shutil

    from .files import RESULT_FILES

    if earlier is None:
        return None
    # The calibration the folder holds, or the one an earlier run kept there; a good one before a flagged one.
    found = [d for d in (Path(earlier), Path(earlier) / PREVIOUS_CALIBRATION) if (d / "calibration.yaml").is_file()]
    if not found:
        return None
    src = next((d for d in found if _calibration_ok(d / "calibration.yaml")), found[0])
    keep = stage / PREVIOUS_CALIBRATION
    try:
        keep.mkdir(parents=True, exist_ok=True)
        for f in sorted(src.iterdir()):
            if f.is_file() and not f.is_symlink() and f.name in RESULT_FILES:
                try:
                    # A hard link: the stage is beside the folder, on its disk, and result files are only ever
                    # replaced, never written in place. It needs no room, so a nearly full disk keeps them too.
                    os.link(f, keep / f.name)
                except OSError:
                    shutil.copy2(f, keep / f.name)
    except OSError as exc:  # the new result matters more than the copy: written without it, and said so
        shutil.rmtree(keep, ignore_errors=True)
        log.warning("the earlier calibration in %s could not be kept (%s); it is replaced", earlier, exc)
        return None
    return keep


def _calibration_ok(path: Path) -> bool:
    """Whether a calibration.yaml says ``ok: true`` (False when it cannot be read)."""
    try:
        return bool((yaml.safe_load(path.read_text()) or {}).get("ok"))
    except (OSError, yaml.YAMLError, AttributeError):
        return False


def write_diagnosis_only(out: Path, log_path: str | Path, reason: str, advice: str = DIAGNOSIS_ADVICE,
                         coverage: dict | None = None, warnings: list[str] | None = None,
                         earlier: Path | None = None, run_report: dict | None = None) -> dict:
    """A run that could not calibrate: report.json with the reason and advice (and the front end's ``coverage``
    when it ran, and the run's ``warnings``: a file cut short says so), no calibration.yaml. ``earlier``: the folder
    this one replaces; a calibration in it is kept in the subfolder ``previous_calibration``
    (:func:`keep_earlier_calibration`). ``run_report``: the keys every report.json has of its run
    (:func:`plsgraph.pipeline.run_report_keys`: options, recording_info, counts, discarded, timing_s), when a run
    got that far; null otherwise, so that the keys are there whatever the outcome."""
    import time

    from .. import __version__

    out.mkdir(parents=True, exist_ok=True)
    kept = keep_earlier_calibration(earlier, out)
    report = {
        "plsgraph_version": __version__,
        "recording": str(Path(log_path).absolute()),
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "ok": False,
        "calibration": None,
        "problems": [reason],
        "advice": [advice] if advice else [],
        "warnings": list(warnings or []),
        **{k: (run_report or {}).get(k) for k in ("options", "recording_info", "counts", "discarded", "timing_s")},
    }
    report["coverage"] = coverage  # null when the front end did not run
    if kept is not None:
        report["previous_calibration"] = PREVIOUS_CALIBRATION
    write_json(out / "report.json", report)
    text = "\n".join([
        f"recording      {log_path}",
        "NO CALIBRATION: the recording does not determine the extrinsic.",
        f"  - {reason}",
        *([coverage_line(coverage)] if coverage is not None else []),
        *([f"advice: {advice}"] if advice else []),
        *([f"warnings ({len(warnings)}):", *[f"  - {w}" for w in warnings[:12]]] if warnings else []),
        "",
        *([f"kept: the calibration this folder held before, in {out / PREVIOUS_CALIBRATION} (this run gave none)"]
          if kept is not None else []),
        f"written: {out / 'report.json'} (diagnosis only)",
    ])
    return {"ok": False, "text": text, "report": report}


def write_result_folder(out: Path, work: Callable[[Path], dict], final: Path | None = None) -> dict:
    """Run ``work(stage)`` (which computes and writes into the staging folder it is given and returns the summary)
    under a lock on ``out``, then move the stage into place. Paths in the summary's text name ``out``."""
    out = Path(out)
    if out.is_symlink():  # a link to the folder to write: its target is replaced, not the link (a review)
        out = out.resolve()
    made = [p for p in out.absolute().parents if not p.exists()]  # folders this run creates above the result's
    try:
        with OutputLock(out), staged_output(out) as stage:
            summary = work(stage)
    except BaseException:
        for p in made:  # deepest first: an interrupted run into new/deep/cal leaves no empty folders behind
            try:
                p.rmdir()
            except OSError:
                break
        raise
    if "text" in summary:
        summary["text"] = summary["text"].replace(str(stage), str(out))
    return summary
