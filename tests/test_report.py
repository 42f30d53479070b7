import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from plsgraph.core.geometry import make_T, so3_exp
from plsgraph.errors import InputError
from plsgraph.report.files import (
    calibration_dict,
    html_report,
    html_table,
    prepare_output_dir,
    ros_static_transform,
    write_json,
    write_yaml,
)


def _T():
    return make_T(so3_exp([0.1, -0.2, 0.3]), [0.15, 0.02, 0.25])


def test_calibration_dict_round_trips_through_yaml_and_json(tmp_path):
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1.0, 1e-6])
    obs = [{"direction": "translation z (camera height)", "status": "unobservable", "sigma": 1.0, "note": "prior"}]
    d = calibration_dict(_T(), 0.031, cov, obs)
    write_yaml(tmp_path / "c.yaml", d)
    write_json(tmp_path / "c.json", d)
    y = yaml.safe_load((tmp_path / "c.yaml").read_text())
    j = json.loads((tmp_path / "c.json").read_text())
    for loaded in (y, j):
        T = np.array(loaded["T_base_cam"])
        assert np.allclose(T, _T())
        q = np.array(loaded["quaternion_xyzw"])
        assert np.isclose(np.linalg.norm(q), 1.0)
        assert loaded["time_offset_s"] == pytest.approx(0.031)
        assert np.allclose(loaded["covariance"]["matrix"], cov)
        assert loaded["covariance"]["order"][-1] == "td"
        assert loaded["observability"][0]["status"] == "unobservable"


def test_nan_becomes_null_not_invalid_json(tmp_path):
    write_json(tmp_path / "r.json", {"a": float("nan"), "b": np.array([1.0, np.inf])})
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": None, "b": [1.0, None]}


def test_static_transform_line_encodes_the_pose():
    line = ros_static_transform(_T())
    tok = line.split()
    vals = dict(zip(tok[4::2], tok[5::2], strict=True))
    assert float(vals["--x"]) == pytest.approx(0.15) and float(vals["--z"]) == pytest.approx(0.25)
    q = np.array([float(vals[k]) for k in ("--qx", "--qy", "--qz", "--qw")])
    assert np.isclose(np.linalg.norm(q), 1.0, atol=1e-8)


def test_output_dir_refuses_to_overwrite(tmp_path):
    out = prepare_output_dir(tmp_path / "o")
    (out / "calibration.yaml").write_text("old")
    with pytest.raises(InputError, match="--force"):
        prepare_output_dir(out)
    assert prepare_output_dir(out, force=True) == out
    assert (out / "calibration.yaml").read_text() == "old"


def test_html_escapes_text():
    page = html_report("<t>", [("s", html_table([{"status": "weak", "x": "<b>"}], ["status", "x"]))], [])
    assert "&lt;b&gt;" in page and "<b>" not in page.split("<h2>s</h2>")[1]


def test_log_axes_of_the_figures_are_labelled_in_plain_numbers(tmp_path):
    from PIL import Image

    from plsgraph.report.figures import DPI, _plain_ticks, _plt, _save

    plt = _plt()
    fig, ax = plt.subplots(figsize=(3.0, 2.0), dpi=DPI)
    ax.bar([0, 1, 2], [0.002, 0.3, 40.0])
    ax.set_yscale("log")
    _plain_ticks(ax.yaxis)
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.yaxis.get_ticklabels() if t.get_text()]
    assert labels and not any("$" in s for s in labels)  # no typeset maths: the dearest text to draw
    assert {"0.01", "1", "10"} <= set(labels)
    assert not any(t.get_text() for t in ax.yaxis.get_ticklabels(minor=True))
    name = _save(plt, fig, tmp_path, "log.png")
    with Image.open(tmp_path / name) as im:  # made at the resolution it is saved at: the size the layout measured
        assert im.size == (round(3.0 * DPI), round(2.0 * DPI))


def test_force_never_replaces_a_folder_holding_files_plsgraph_did_not_write(tmp_path):
    """Before: --out set to the recording's own folder with --force replaced it, recording and notes included."""
    out = tmp_path / "sand"
    out.mkdir()
    (out / "rec.mcap").write_bytes(b"recording")
    (out / "notes.txt").write_text("precious")
    (out / "report.json").write_text("{}")
    for force in (False, True):
        with pytest.raises(InputError, match=r"did not write \(notes.txt, rec.mcap\).*new or empty --out") as exc:
            prepare_output_dir(out, force=force, create=False)
        assert ("earlier plsgraph result" in str(exc.value)) is force
    assert (out / "rec.mcap").read_bytes() == b"recording" and (out / "notes.txt").read_text() == "precious"
    (out / "rec.mcap").unlink()
    (out / "notes.txt").unlink()
    with pytest.raises(InputError, match="already holds a plsgraph result; .*--force"):
        prepare_output_dir(out, create=False)
    assert prepare_output_dir(out, force=True, create=False) == out  # an earlier result alone: replaced
    batch = tmp_path / "batch"
    (batch / "a").mkdir(parents=True)
    (batch / "a" / "calibration.yaml").write_text("ok: true")
    (batch / "summary.json").write_text("{}")
    # A batch's folder of results is not a calibration's to replace (nor another calibration's folder in it) ...
    with pytest.raises(InputError, match=r"did not write \(a/\)"):
        prepare_output_dir(batch, force=True, create=False)
    # ... but a batch writes into it (each recording's folder is replaced, and checked, on its own).
    assert prepare_output_dir(batch, force=True, create=False, whole=False) == batch
    from plsgraph.report.files import foreign_entries

    assert foreign_entries(batch) == []  # as a batch sees it: results only
    (batch / "a" / "photo.jpg").write_bytes(b"")
    assert foreign_entries(batch) == ["a/"]


def test_the_working_folder_is_never_an_output_folder(tmp_path, monkeypatch):
    """Before: --out . --force calibrated for the whole run and then failed to move the folder it ran in."""
    here = tmp_path / "work" / "sub"
    here.mkdir(parents=True)
    monkeypatch.chdir(here)
    for out in (".", "..", str(here)):
        with pytest.raises(InputError, match="folder you are working in"):
            prepare_output_dir(out, force=True, create=False)
    assert prepare_output_dir("calib", create=False) == Path("calib")


def test_an_output_lock_is_removed_when_its_run_ends_and_still_excludes_a_second_run(tmp_path, monkeypatch):
    import os

    from plsgraph.report import files
    from plsgraph.report.files import OutputLock

    out = tmp_path / "out"
    with OutputLock(out) as a:
        assert a.path.exists()
        with pytest.raises(InputError, match="another plsgraph run"):
            OutputLock(out).__enter__()
    assert not a.path.exists() and list(tmp_path.iterdir()) == []  # nothing left beside the folder
    # A run that opens the lock file just before the run holding it removes it must not take the removed file's lock.
    first = OutputLock(out).__enter__()
    real_open = os.open

    def open_then_first_ends(*args, **kw):
        fd = real_open(*args, **kw)
        if first.fd is not None:
            first.__exit__(None, None, None)
        return fd

    monkeypatch.setattr(files.os, "open", open_then_first_ends)
    with OutputLock(out) as second:
        assert os.stat(second.path).st_ino == os.fstat(second.fd).st_ino
        monkeypatch.setattr(files.os, "open", real_open)
        with pytest.raises(InputError, match="another plsgraph run"):
            OutputLock(out).__enter__()
    assert not second.path.exists()


def test_frame_names_make_valid_robot_files():
    """Before: --child-frame robot1/event-camera.0 gave the launch file a node name ROS 2 refuses, --parent-frame
    /base_link (which tf2 refuses) was written as given, and the URDF said 't_odom = t_cam + -0.09 s'."""
    import ast
    import re

    from plsgraph.options import CalibrationOptions
    from plsgraph.report.robot_files import launch_text, node_name, urdf_text

    for child, node in (("robot1/event-camera.0", "robot1_event_camera_0_static_tf"), ("3cam", "_3cam_static_tf"),
                        ("event_camera", "event_camera_static_tf")):
        assert node_name(child) == node and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", node)
        CalibrationOptions.build(board="b", child_frame=child)
        text = launch_text(_T(), "base_link", child)
        ast.parse(text)
        assert f'name="{node}"' in text and f'"--child-frame-id", "{child}"' in text
    for bad in ("/base_link", "base_link/", "a//b", "my camera", "cam<1>"):
        with pytest.raises(InputError, match="frame name of letters"):
            CalibrationOptions.build(board="b", parent_frame=bad)
    assert "t_odom = t_cam - 0.091165188 s" in urdf_text(_T(), "base_link", "cam", time_offset_s=-0.091165188)
    assert "t_odom = t_cam + 0.030000000 s" in urdf_text(_T(), "base_link", "cam", time_offset_s=0.03)


def test_the_demos_folder_with_its_paper_tables_is_an_earlier_result(tmp_path):
    """scripts/demo.sh writes the paper's tables into a sub-folder of the calibration's folder; run again, its
    calibrate --force must replace that folder (before the guard knew those files, the second run was refused)."""
    out = tmp_path / "demo"
    (out / "paper_tables").mkdir(parents=True)
    for name in ("calibration.yaml", "report.json", "paper_tables/paper_tables.md", "paper_tables/paper_tables.json"):
        (out / name).write_text("x")
    assert prepare_output_dir(out, force=True, create=False) == out


def test_diagnosis_text_gives_each_directions_sigma_and_its_note_without_naming_it_twice():
    # Before: "unobservable  camera height (translation z)   camera height (translation z) is not observable ...",
    # and no sigma, which diagnose --json has.
    from plsgraph.report.text import diagnosis_text
    from plsgraph.result import Diagnosis

    rows = ({"direction": "camera position forward (translation x)", "name": "x", "status": "observable",
             "sigma": 0.0237, "unit": "m", "note": ""},
            {"direction": "camera height (translation z)", "name": "z", "status": "unobservable", "sigma": 1.0,
             "unit": "m", "note": "camera height (translation z) is not observable from this recording; give it."})
    text = diagnosis_text(Diagnosis("r.mcap", True, (), (), observability=rows))
    lines = text.splitlines()
    i = lines.index("observability after refinement:")
    assert lines[i + 1].split() == ["observable", "camera", "position", "forward", "(translation", "x)", "sigma",
                                    "0.0237", "m"]
    assert lines[i + 2].endswith("sigma 1 m")
    assert lines[i + 3].strip() == "is not observable from this recording; give it."
    assert text.count("camera height (translation z)") == 1


def test_the_euler_angles_sigmas_are_the_covariance_propagated_to_them_not_the_base_axes_sigmas():
    """Before: report.html and batch's summary put the sigmas of small rotations about the base x, y axes beside the
    Euler roll and pitch. With the camera turned about -87 deg in yaw (as mounted looking forwards), those are each
    other's: a base-y rotation moves the Euler roll."""
    from scipy.spatial.transform import Rotation

    from plsgraph.report.files import rpy_sigma_deg

    R = Rotation.from_euler("xyz", [-96.0, 1.0, -87.0], degrees=True)
    sig = np.radians([0.088, 0.132, 0.5])  # about base x, y, z
    cov = np.diag(sig ** 2)
    got = np.asarray(rpy_sigma_deg(R.as_matrix(), cov))
    # Monte Carlo: rotations drawn about the base axes, read as Euler angles.
    rng = np.random.default_rng(0)
    d = rng.standard_normal((20000, 3)) * sig
    e = (Rotation.from_rotvec(d) * R).as_euler("xyz", degrees=True)
    want = np.degrees(np.angle(np.exp(1j * np.radians(e - R.as_euler("xyz", degrees=True))))).std(axis=0)
    np.testing.assert_allclose(got, want, rtol=0.03)
    assert got[0] > 0.12 and got[1] < 0.1  # roll takes the base-y sigma, pitch the base-x one
    assert abs(got[2] - 0.5) < 0.02  # yaw is the rotation about the base z axis
    np.testing.assert_allclose(rpy_sigma_deg(np.eye(3), cov), np.degrees(sig), rtol=1e-6)  # no yaw: the same
    assert rpy_sigma_deg(R.as_matrix(), None) is None
    c = calibration_dict(make_T(R.as_matrix(), np.zeros(3)), 0.0, np.diag([*sig ** 2, 1e-4, 1e-4, 1.0, 1e-6]), [])
    np.testing.assert_allclose(c["rpy_sigma_deg"], got)


def test_a_camera_on_its_side_has_no_euler_sigmas_and_its_report_is_still_written():
    """A review: near pitch +-90 deg (a portrait-mounted camera) rpy_sigma_deg is NaN (null in the files), and
    report.html's table crashed on it, which dropped the whole calibration as an internal error."""
    from plsgraph.report.figures import _summary_table

    R = so3_exp([0.0, np.pi / 2, 0.0])  # pitch 90 deg
    c = calibration_dict(make_T(R, [0.1, 0.0, 0.2]), 0.01, np.diag([1e-6] * 6 + [1e-8]), [])
    assert c["rpy_sigma_deg"] == [None, None, None]  # NaN -> null
    html = _summary_table(c)
    assert html.count("<td>-</td>") >= 3 or html.count(">-<") >= 3


def test_matplotlib_keeps_its_cache_in_one_folder_when_home_is_read_only(tmp_path, monkeypatch):
    # A review: with a read-only HOME every run warned and left a fresh /tmp/matplotlib-* folder behind.
    import os
    import tempfile

    from plsgraph.report.figures import _matplotlib_config_dir

    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("MPLCONFIGDIR", "")  # recorded as it was, and so put back after the test
    monkeypatch.delenv("MPLCONFIGDIR")
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    _matplotlib_config_dir()
    assert "MPLCONFIGDIR" not in os.environ  # a HOME it can write: matplotlib's own folder
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, m: False if str(p).startswith(str(home)) else real_access(p, m))
    _matplotlib_config_dir()
    shared = tmp_path / "tmp" / f"plsgraph-matplotlib-{os.getuid()}"
    assert os.environ["MPLCONFIGDIR"] == str(shared) and shared.is_dir()
    _matplotlib_config_dir()  # set: left as it is
    assert os.environ["MPLCONFIGDIR"] == str(shared)
    # A cache folder it cannot write, the config one writable: the same (the font cache goes to the cache folder).
    monkeypatch.delenv("MPLCONFIGDIR")
    (home / ".cache").mkdir()
    monkeypatch.setattr(os, "access", lambda p, m: False if "cache" in str(p) else real_access(p, m))
    _matplotlib_config_dir()
    assert os.environ["MPLCONFIGDIR"] == str(shared)
    # A shared folder others may write (or another user's): not used.
    monkeypatch.delenv("MPLCONFIGDIR")
    shared.chmod(0o777)
    _matplotlib_config_dir()
    assert "MPLCONFIGDIR" not in os.environ
    shared.chmod(0o700)


def test_a_diagnosis_that_stopped_before_the_board_search_does_not_say_zero_frames():
    # A review: "camera frames with the board: 0" where the front end never ran (the events were too short).
    from plsgraph.report.text import diagnosis_text
    from plsgraph.result import Diagnosis

    stopped = diagnosis_text(Diagnosis("r.mcap", False, ("the events span only 1.00 s",), (), camera_frames=None,
                                       odometry_samples=3050))
    assert "camera frames with the board: not searched for" in stopped and "odometry samples: 3050" in stopped
    found_none = diagnosis_text(Diagnosis("r.mcap", False, ("no board",), (), camera_frames=0, odometry_samples=9))
    assert "camera frames with the board: 0" in found_none


def test_odometry_messages_get_their_scales_reported_not_the_nominal_wheels():
    # A review: with nav_msgs/Odometry the summary said "effective wheel radius 0.0980 m, track width 0.370 m" (the
    # nominal values) and calibration.yaml that the refinement kept them, while it had estimated a turn scale of 0.676.
    from types import SimpleNamespace

    from plsgraph.options import CalibrationOptions
    from plsgraph.report.text import calibration_text
    from plsgraph.result import robot_sections

    ref = SimpleNamespace(converged=True, inflation={}, odometry={
        "speed_scale": 0.998, "turn_scale": 0.676, "speed_scale_sigma": 0.004, "turn_scale_sigma": 0.031,
        "status": {"wheel_radius": "observable", "track_width": "observable"}})
    run = SimpleNamespace(options=CalibrationOptions(), refinement=ref, lens=None,
                          closed_form=SimpleNamespace(odometry_scale={"speed": 0.99, "turn_rate": 0.67}),
                          recording_info={"base_source": "nav_msgs/Odometry"}, clock_offset_s=0.0)
    odo = robot_sections(run)["odometry"]
    assert odo["wheel_radius_m"] is None and odo["track_width_m"] is None
    assert (odo["turn_rate_scale"], odo["turn_rate_scale_sigma"]) == (0.676, 0.031)
    assert odo["status"] == {"speed_scale": "observable", "turn_rate_scale": "observable"}
    assert "refinement" in odo["source"]
    c = {"source": "refinement", "T_base_cam": np.eye(4).tolist(), "rpy_deg": [0, 0, 0], "translation_m": [0, 0, 0],
         "time_offset_s": 0.0, "odometry": odo, "observability": []}
    text = calibration_text({"recording": "r.mcap", "calibration": c, "ok": True, "problems": [], "warnings": []})
    assert "x0.676 +- 0.031 its turn rate" in text and "wheel radius" not in text
