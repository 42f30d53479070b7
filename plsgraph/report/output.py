"""Result folders: calibration.yaml, report.json, report.html and its pictures, or a diagnosis only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .files import write_json, write_yaml


def write_calibration(out: Path, result: Any) -> list[Path]:
    """Write a :class:`plsgraph.result.CalibrationResult` into the folder ``out`` (made if missing)."""
    from .figures import write_html_report

    report = result.report
    out.mkdir(parents=True, exist_ok=True)
    write_html_report(out, result.run, report)  # first: a figure that fails adds its warning to the report
    write_yaml(out / "calibration.yaml", report["calibration"])
    write_json(out / "report.json", report)
    from .robot_files import write_robot_files

    robot = write_robot_files(out, result)  # a flagged result gets comment-only files that say why
    return [out / "calibration.yaml", out / "report.json", out / "report.html", *robot]


DIAGNOSIS_ADVICE = (
    "drive forwards and backwards while turning (arcs, S-curves) with the board in view; straight "
    "driving leaves the camera yaw and lever arm undetermined, turning in place the yaw"
)


def write_diagnosis_only(out: Path, log_path: str | Path, reason: str) -> dict:
    """A run that could not calibrate: report.json with the reason and advice, no calibration.yaml."""
    from .. import __version__

    out.mkdir(parents=True, exist_ok=True)
    stale = out / "calibration.yaml"
    if stale.exists():  # with --force into an old folder: an old result must not pass for this recording's
        stale.rename(out / "calibration.previous.yaml")
    for old in [out / "report.html", *out.glob("*.png"), out / "base_to_camera.urdf", out / "static_tf.launch.py"]:
        old.unlink(missing_ok=True)
    report = {
        "plsgraph_version": __version__,
        "recording": str(log_path),
        "ok": False,
        "calibration": None,
        "problems": [reason],
        "advice": [DIAGNOSIS_ADVICE],
    }
    write_json(out / "report.json", report)
    text = "\n".join([
        f"recording      {log_path}",
        "NO CALIBRATION: the recording does not determine the extrinsic.",
        f"  - {reason}",
        f"advice: {DIAGNOSIS_ADVICE}",
        "",
        f"written: {out / 'report.json'} (diagnosis only)",
    ])
    return {"ok": False, "text": text, "report": report}
