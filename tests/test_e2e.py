"""End to end through the command: simulate a recording to MCAP, calibrate it, batch it (local and Dask)."""

import json
import re

import numpy as np
import pytest
import yaml

from plsgraph.cli.main import main
from plsgraph.core.geometry import rotation_error_deg

# Tolerances for an 8 s "rich" simulated recording seen through the event front end (see docs/refinement.md
# for the spread over seeds): rotation, camera position in the floor plane, time offset.
ROT_TOL_DEG = 0.8
TXY_TOL_M = 0.03
TD_TOL_S = 0.008


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("rec")
    log = d / "rich.mcap"
    code = main(["simulate", "--ideal", "--motion", "rich", "--duration", "8", "--seed", "1", "--contrast", "0.45",
                 "--event-format", "evt3", "--out", str(log)])
    assert code == 0
    return log


@pytest.fixture(scope="module")
def calibrated(recording, tmp_path_factory):
    out = tmp_path_factory.mktemp("calib") / "out"
    truth = recording.with_name("rich.truth.yaml")
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--out", str(out), "--truth", str(truth)])
    return code, out, yaml.safe_load(truth.read_text())


def test_calibrate_recovers_truth(calibrated):
    code, out, truth = calibrated
    assert code == 0
    calib = yaml.safe_load((out / "calibration.yaml").read_text())
    T, T_gt = np.array(calib["T_base_cam"]), np.array(truth["T_base_cam"])
    assert rotation_error_deg(T[:3, :3], T_gt[:3, :3]) < ROT_TOL_DEG
    assert np.linalg.norm(T[:2, 3] - T_gt[:2, 3]) < TXY_TOL_M
    assert abs(calib["time_offset_s"] - truth["td"]) < TD_TOL_S
    status = {o["name"]: o["status"] for o in calib["observability"]}
    assert status["z"] == "unobservable"
    assert all(status[k] == "observable" for k in ("roll", "pitch", "x", "y", "td"))


def test_report_json_is_parseable_and_complete(calibrated):
    _, out, _ = calibrated
    rep = json.loads((out / "report.json").read_text())
    assert rep["ok"] is True
    assert {"pls", "cca", "procrustes"} <= set(rep["closed_form"])
    assert np.array(rep["closed_form"]["pls"]["R_base_cam"]).shape == (3, 3)
    assert rep["refinement"]["converged"] is True
    assert rep["counts"]["camera_frames"] > 100
    assert "frontend_windows" in rep["discarded"]
    assert rep["truth_errors"]["refined.rot_err_deg"] < ROT_TOL_DEG
    assert (out / "report.html").read_text().count("<img") >= 4


def test_calibrate_refuses_existing_output(recording, calibrated, capsys):
    _, out, _ = calibrated
    before = (out / "calibration.yaml").read_text()
    assert main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "calibration.yaml").read_text() == before


def test_diagnose_says_the_recording_is_good(recording, capsys):
    code = main(["diagnose", str(recording), "--board", "acircles_4x11_a2", "--json"])
    res = json.loads(capsys.readouterr().out)
    assert code == 0 and res["ok"] is True
    assert any("height" in a for a in res["advice"])


def test_batch_local_one_failure_does_not_stop_the_rest(recording, tmp_path):
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(recording.read_bytes()[:5000])  # truncated copy
    out = tmp_path / "batch"
    code = main(["batch", str(recording), str(bad), "--board", "acircles_4x11_a2", "--out", str(out), "--jobs", "2"])
    rows = {r["recording"].split("/")[-1]: r for r in json.loads((out / "summary.json").read_text())["recordings"]}
    assert code == 1
    assert rows["rich.mcap"]["status"] == "ok"
    assert rows["rich.mcap"]["truth_errors"]["refined.rot_err_deg"] < ROT_TOL_DEG
    assert rows["broken.mcap"]["status"] == "failed" and rows["broken.mcap"]["error"]
    assert (out / "rich" / "calibration.yaml").exists()


def test_diagnose_compare_and_batch_carry_calibrates_warnings(recording, tmp_path, capsys):
    # A wheel radius 5 % off is estimated and applied, with a warning in calibrate's report.json; diagnose, compare and
    # batch used to drop every warning (only problems reached them).
    flags = ["--board", "acircles_4x11_a2", "--wheel-radius", "0.103"]
    assert main(["calibrate", str(recording), *flags, "--out", str(tmp_path / "one")]) == 0
    capsys.readouterr()
    said = json.loads((tmp_path / "one" / "report.json").read_text())["warnings"]
    assert any("wheel radius" in w for w in said)
    assert main(["diagnose", str(recording), *flags, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == said
    assert main(["compare", str(recording), *flags, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == said
    assert main(["diagnose", str(recording), *flags]) == 0
    assert f"warning: {said[0]}" in capsys.readouterr().out
    assert main(["batch", str(recording), *flags, "--out", str(tmp_path / "batch")]) == 0
    (row,) = json.loads((tmp_path / "batch" / "summary.json").read_text())["recordings"]
    assert row["warnings"] == said
    assert "| warnings |" in (tmp_path / "batch" / "summary.md").read_text().replace("  ", " ")


def test_batch_on_a_dask_cluster(recording, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        out = tmp_path / "dask"
        code = main(["batch", str(recording), "--board", "acircles_4x11_a2", "--out", str(out),
                     "--scheduler", c.scheduler_address])
    rows = json.loads((out / "summary.json").read_text())["recordings"]
    assert code == 0 and rows[0]["status"] == "ok"


def test_compare_prints_every_solver_against_truth(recording, capsys):
    truth = recording.with_name("rich.truth.yaml")
    code = main(["compare", str(recording), "--board", "acircles_4x11_a2", "--truth", str(truth), "--json"])
    res = json.loads(capsys.readouterr().out)
    assert code == 0
    rows = {r["method"]: r for r in res["rows"]}
    assert {"pls", "cca", "procrustes", "refined"} <= set(rows)
    assert rows["refined"]["rot_err_deg"] < ROT_TOL_DEG
    assert all(np.isfinite(r["rot_err_deg"]) for r in rows.values())


def test_spinning_in_place_gives_a_diagnosis_not_a_number(tmp_path, capsys):
    log = tmp_path / "spin.mcap"
    assert main(["simulate", "--ideal", "--motion", "spin", "--duration", "6", "--seed", "2", "--contrast", "0.45",
                 "--event-format", "evt3", "--out", str(log)]) == 0
    out = tmp_path / "calib"
    code = main(["calibrate", str(log), "--board", "acircles_4x11_a2", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 1 and "NO CALIBRATION" in text
    assert not (out / "calibration.yaml").exists()
    rep = json.loads((out / "report.json").read_text())
    assert rep["ok"] is False and "yaw" in rep["problems"][0]
    cov = rep["coverage"]  # what the detector saw, also when there is no calibration
    assert 0 < cov["found"] <= cov["windows"] and sum(cov["by_outcome"].values()) == cov["windows"]
    assert cov["found"] == sum(cov["by_outcome"].get(k, 0) for k in ("rims", "blobs", "image"))
    assert f"board found in {cov['found']} of {cov['windows']} windows" in text
    code = main(["diagnose", str(log), "--board", "acircles_4x11_a2", "--json"])
    res = json.loads(capsys.readouterr().out)
    assert code == 1 and res["ok"] is False
    assert res["observable_closed_form"]["yaw"] is False
    assert any("turning in place" in a and "yaw" in a for a in res["advice"])
    assert main(["compare", str(log), "--board", "acircles_4x11_a2"]) == 1  # a verdict on the motion, not a user error
    code = main(["batch", str(log), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "b"), "--jobs", "1"])
    (row,) = json.loads((tmp_path / "b" / "summary.json").read_text())["recordings"]
    assert code == 1 and row["status"] == "flagged" and "yaw" in row["problems"][0]


def test_closed_form_only_result_has_no_nan_and_says_the_height_is_not_measured(recording, tmp_path):
    import shutil
    import stat

    truth = tmp_path / "my_truth.yaml"  # any file name is accepted for --truth
    shutil.copy(recording.with_name("rich.truth.yaml"), truth)
    out = tmp_path / "cf"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--no-refine", "--out", str(out),
                 "--truth", str(truth)])
    assert code == 0
    text = (out / "calibration.yaml").read_text()
    calib = yaml.safe_load(text)
    assert "nan" not in text.lower() and "null" not in text.split("covariance")[0].replace(
        "rpy_sigma_deg: null", "")
    assert calib["source"] == "closed_form.pls" and calib["rpy_sigma_deg"] is None  # the closed form has no sigma
    assert calib["translation_m"][2] == 0.0 and "not observable" in calib["translation_z_source"]
    T_gt = np.array(yaml.safe_load(truth.read_text())["T_base_cam"])
    assert rotation_error_deg(np.array(calib["T_base_cam"])[:3, :3], T_gt[:3, :3]) < 3.0
    assert stat.S_IMODE((out / "calibration.yaml").stat().st_mode) & 0o044  # readable by group/others


def test_detection_rate_warnings_name_the_lower_rate_and_the_longer_window():
    from plsgraph.pipeline import detection_rate_warnings

    assert detection_rate_warnings("count", 30.0, 1.0 / 30.0) == []
    assert detection_rate_warnings("count", 30.0, 0.0333) == []  # the default, typed
    assert detection_rate_warnings("count", 60.0, 1.0 / 60.0) == []  # faster and shorter: not what was measured worse
    slow = detection_rate_warnings("count", 20.0, 0.05)
    assert len(slow) == 2 and "50 ms" in slow[0] and "detected at 20 Hz" in slow[1]
    kept = detection_rate_warnings("count", 20.0, 0.0333)
    assert len(kept) == 1 and "detected at 20 Hz" in kept[0]
    assert len(detection_rate_warnings("count", 30.0, 0.1)) == 1  # a longer window alone
    assert detection_rate_warnings("time_surface", 10.0, 0.15) == []  # decaying surfaces: their own look-back


def test_a_flagged_result_at_a_lower_rate_says_first_to_calibrate_again_at_the_defaults(monkeypatch):
    # A review: at --rate 5 the first problem said the recording determines yaw poorly ("drive longer"); the rate's
    # warning came further down, after the advice to record again.
    from types import SimpleNamespace

    import plsgraph.gate as gate
    from plsgraph.options import CalibrationOptions, FrontendOptions

    monkeypatch.setattr(gate, "problems_of", lambda *a, **k: ["the recording determines yaw only to about 3.5 deg"])

    def run(rate, window=None):
        opts = CalibrationOptions(frontend=FrontendOptions(rate_hz=rate, window_s=window))
        track = SimpleNamespace(info={"kind": "count", "window_s": window or 1.0 / rate})
        return SimpleNamespace(options=opts, camera_track=track, closed_form=None, refinement=None, base_track=None,
                               input_problems=[])

    slow = gate.problems_of_run(run(5.0))
    assert len(slow) == 2 and "calibrate again with the default --rate" in slow[0] and "5 Hz" in slow[0]
    assert "yaw" in slow[1]
    assert "200 ms of events" in gate.problems_of_run(run(30.0, 0.2))[0]
    assert gate.problems_of_run(run(30.0)) == ["the recording determines yaw only to about 3.5 deg"]
    monkeypatch.setattr(gate, "problems_of", lambda *a, **k: [])
    assert gate.problems_of_run(run(5.0)) == []  # not flagged: the warnings say it


def test_a_lower_detection_rate_is_said_in_the_result(recording, calibrated, tmp_path):
    """--rate 20 (50 ms windows) was measured less accurate, with results beyond their sigmas on independent test
    recordings: the result says so; the default run does not."""
    out = tmp_path / "r20"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--no-refine", "--rate", "20", "--out",
                 str(out)])
    assert code == 0
    warnings = json.loads((out / "report.json").read_text())["warnings"]
    assert any("50 ms of events" in w for w in warnings) and any("detected at 20 Hz" in w for w in warnings)
    default = json.loads((calibrated[1] / "report.json").read_text())["warnings"]
    assert not any("the accuracy was measured with" in w for w in default)


def test_swapped_wheels_are_corrected_or_flagged(recording, tmp_path):
    swap = ["--left-joint", "front_right_wheel_joint", "--right-joint", "front_left_wheel_joint"]
    out = tmp_path / "swapped"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--out", str(out), "--no-refine", *swap,
                 "--upright-camera"])
    rep = json.loads((out / "report.json").read_text())
    assert code == 0 and rep["calibration"]["wheel_order"]["corrected"]  # fixed, and said so
    assert any("swapped" in w for w in rep["warnings"])
    assert np.asarray(rep["calibration"]["T_base_cam"])[2, 1] < -0.5  # the camera is upright again
    # Unsaid, the same correction is flagged: correct wheels under an upside-down camera look the same.
    out = tmp_path / "unsaid"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--out", str(out), "--no-refine", *swap])
    rep = json.loads((out / "report.json").read_text())
    assert code == 1 and rep["calibration"]["wheel_order"]["corrected"]
    assert rep["calibration"]["wheel_order"]["mount_unstated"]
    assert "mount_unstated: true" in (out / "calibration.yaml").read_text()
    assert any("--upright-camera" in p and "--upside-down-camera" in p for p in rep["problems"])
    assert "ros2 run" not in (out / "calibration.yaml").read_text()
    out = tmp_path / "unchecked"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11_a2", "--out", str(out), "--no-refine", *swap,
                 "--wheel-order", "off"])
    rep = json.loads((out / "report.json").read_text())
    assert code == 1 and any("upside down" in p for p in rep["problems"])  # never exit 0 with the mirror
    assert "ros2 run" not in (out / "calibration.yaml").read_text()  # a flagged result has no TF line to paste


def test_a_board_of_the_wrong_size_is_flagged_not_trusted(recording, tmp_path, capsys):
    # The recording shows the A2 board (5 cm); calibrating with the desk board (2.5 cm) halves every distance.
    out = tmp_path / "wrong"
    code = main(["calibrate", str(recording), "--board", "acircles_4x11", "--out", str(out), "--no-refine"])
    rep = json.loads((out / "report.json").read_text())
    assert code == 1 and rep["ok"] is False
    assert any("square_size" in p for p in rep["problems"])


def test_too_short_a_recording_gets_a_diagnosis(tmp_path, capsys):
    log = tmp_path / "short.mcap"
    assert main(["simulate", "--ideal", "--motion", "rich", "--duration", "2.5", "--contrast", "0.45",
                 "--event-format", "evt3", "--out", str(log)]) == 0
    out = tmp_path / "c"
    code = main(["calibrate", str(log), "--board", "acircles_4x11_a2", "--out", str(out)])
    assert code == 1 and "NO CALIBRATION" in capsys.readouterr().out
    assert not (out / "calibration.yaml").exists()
    rep = json.loads((out / "report.json").read_text())
    assert rep["ok"] is False and rep["coverage"]["found"] > 0
    # The wrong board's pattern is found in no window: the diagnosis still says what each window gave.
    out = tmp_path / "wrong_board"
    code = main(["calibrate", str(log), "--board", "aprilgrid_6x6", "--out", str(out)])
    text = capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert code == 1 and "no board detected" in rep["problems"][0]
    assert rep["coverage"]["found"] == 0 and rep["coverage"]["windows"] == sum(rep["coverage"]["by_outcome"].values())
    assert f"board found in 0 of {rep['coverage']['windows']} windows" in text
    assert "--board" in rep["advice"][0] and "drive" not in rep["advice"][0]


def test_report_shows_detection_coverage_and_event_frames(calibrated):
    _, out, _ = calibrated
    rep = json.loads((out / "report.json").read_text())
    page = (out / "report.html").read_text()
    assert (out / "coverage.png").stat().st_size > 1000 and "coverage.png" in page
    assert (out / "event_frames.png").stat().st_size > 1000 and "event_frames.png" in page
    # The table's counts are the front end's: every window once, found or with its reason.
    windows = rep["discarded"]["frontend_windows"]
    found = re.search(r"found in (\d+) of (\d+) windows", page)
    assert found and int(found.group(2)) == windows
    cov = rep["coverage"]  # the same counts for scripts, with the windows of a still robot apart
    assert cov["windows"] == windows and cov["found"] == int(found.group(1))
    assert sum(cov["by_outcome"].values()) == windows and 0 < cov["found_fraction_robot_moving"] <= 1
    assert int(found.group(1)) >= rep["counts"]["camera_frames"]
