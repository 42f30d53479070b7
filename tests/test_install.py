"""A wheel built from the checkout, installed into a fresh virtual environment, calibrates the sample recording
from another folder with the board given by name: the boards and camera presets travel inside the package, and
the library call works without the command line."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import numpy as np
import pytest
import yaml
from realdata import REPO_ROOT, SAMPLE

from plsgraph.core.geometry import rotation_error_deg


@pytest.mark.slow
def test_wheel_in_fresh_venv_calibrates_sample_by_board_name(tmp_path):
    wheels = tmp_path / "wheels"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels), str(REPO_ROOT)],
                           capture_output=True, text=True)
    if build.returncode != 0:
        pytest.skip(f"cannot build a wheel here (no network for the build backend?): {build.stderr[-300:]}")
    (whl,) = wheels.glob("plsgraph-*.whl")
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "-q", str(whl)],
                   check=True, capture_output=True)
    # The dependencies (gtsam, OpenCV, ...) come from this environment's site-packages as a plain path entry: its
    # own .pth files (the editable install of the checkout among them) are not processed, so plsgraph can only
    # come from the wheel.
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    (Path(site) / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp_path / "elsewhere"
    work.mkdir()
    code = (
        "import json, sys, plsgraph\n"
        f"r = plsgraph.calibrate({str(SAMPLE)!r}, board='acircles_4x11_a2')\n"
        "print(json.dumps({'file': plsgraph.__file__, 'T': r.T_base_cam.tolist(), 'td': r.time_offset_s,"
        " 'order': list(r.covariance_order)}))\n"
    )
    run = subprocess.run([str(py), "-c", code], cwd=work, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["file"].startswith(str(env_dir))  # the wheel's copy, not the checkout
    assert out["order"][-1] == "td"
    truth = yaml.safe_load(SAMPLE.with_name("rich_sample.truth.yaml").read_text())
    assert rotation_error_deg(np.array(out["T"])[:3, :3], np.array(truth["T_base_cam"])[:3, :3]) < 1.0
    help_run = subprocess.run([str(env_dir / "bin" / "plsgraph"), "--help"], cwd=work, capture_output=True, text=True)
    assert help_run.returncode == 0 and "calibrate" in help_run.stdout
