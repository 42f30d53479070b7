"""The command's user-facing behaviour: exit codes, messages, refusal to overwrite, machine-readable output."""

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from realdata import SAMPLE, SHARED_REAL_DIR

import plsgraph
from plsgraph.cli.main import main

DAVIS = SHARED_REAL_DIR / "davis346_tagboard.mcap"


def test_help_and_bad_flags_exit_cleanly(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    assert "calibrate" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["calibrate"])  # no recording, no --out
    assert e.value.code == 2
    assert "plsgraph calibrate --help" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--motion", "sideways", "--out", "x.mcap"])
    assert e.value.code == 2


def _command(*args: str, shell_tail: str = "") -> subprocess.CompletedProcess:
    """The console script's entry point (run) in a fresh process, importing this tree's plsgraph."""
    env = {**os.environ, "PYTHONPATH": str(Path(plsgraph.__file__).resolve().parent.parent)}
    cmd = [sys.executable, "-c", "from plsgraph.cli.main import run; run()", *args]
    if shell_tail:
        return subprocess.run(" ".join(f"'{a}'" for a in cmd) + shell_tail, shell=True, capture_output=True,
                              text=True, env=env, executable="/bin/bash")
    return subprocess.run(cmd, capture_output=True, text=True, env=env)


@pytest.mark.skipif(not SAMPLE.exists(), reason="the sample recording is not in this checkout")
def test_the_command_ends_at_once_with_all_its_output(tmp_path):
    # inspect, simulate, calibrate, diagnose and compare end the process without the interpreter's teardown: what
    # they print must all arrive, through a pipe too, with their exit code.
    r = _command("-v", "inspect", str(SAMPLE), "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["topics"], r.stderr
    r = _command("inspect", str(tmp_path / "nosuch.mcap"))
    assert r.returncode == 2 and "plsgraph: error:" in r.stderr
    r = _command("inspect", str(SAMPLE), shell_tail=" | head -c 10; exit ${PIPESTATUS[0]}")
    assert r.returncode == 0 and len(r.stdout) == 10 and "Traceback" not in r.stderr
    r = _command("--help")  # no command: the ordinary exit
    assert r.returncode == 0 and "calibrate" in r.stdout


def test_the_command_gives_blas_one_thread_unless_the_user_chose(monkeypatch):
    """numpy's BLAS gets one thread in the command's processes (its threads spin on after each call and the processors
    are already busy); a user's own OPENBLAS_NUM_THREADS is kept."""
    from plsgraph.cli.main import single_threaded_blas

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "")  # records the variable as it was: undone after the test
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")
    single_threaded_blas()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    single_threaded_blas()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "4"


def test_missing_recording_is_a_user_error(tmp_path, capsys):
    code = main(["calibrate", str(tmp_path / "nope.mcap"), "--board", "acircles_4x11", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "does not exist" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # a refused run leaves no empty output folder behind


def test_corrupt_recording_is_a_user_error(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 50)
    code = main(["inspect", str(bad)])
    err = capsys.readouterr().err
    assert code == 2 and "plsgraph: error:" in err and "Traceback" not in err


@pytest.mark.skipif(not DAVIS.exists(), reason="shared real recordings not present")
def test_inspect_json_on_real_event_recording(capsys):
    assert main(["inspect", str(DAVIS), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    (topic,) = [t for t in info["topics"] if "events" in t]
    assert topic["type"] == "event_camera_msgs/msg/EventPacket"
    assert topic["messages"] == 100
    assert topic["events"] == topic["events_on"] + topic["events_off"] > 0
    assert (topic["width"], topic["height"]) == (346, 260)
    assert 0.9e9 < topic["t_last_ns"] - topic["t_first_ns"] < 1.1e9


def test_reproduce_paper_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "tables"
    assert main(["reproduce-paper", "--quick", "--trials", "3", "--out", str(out)]) == 0
    first = (out / "paper_tables.json").read_text()
    assert main(["reproduce-paper", "--quick", "--trials", "4", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "paper_tables.json").read_text() == first
    assert main(["reproduce-paper", "--quick", "--trials", "4", "--out", str(out), "--force"]) == 0


def test_batch_reports_failures_without_stopping(tmp_path, capsys):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    (tmp_path / "in" / "b.mcap").write_bytes(b"\x89MCAP0\r\n")
    code = main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(tmp_path / "out"),
                 "--jobs", "1"])
    assert code == 1
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [r["status"] for r in summary["recordings"]] == ["failed", "failed"]
    assert all(r["error"] for r in summary["recordings"])
    # Nothing in the folder is skipped without a word (before: silently): event-only files, sub-folders' recordings.
    (tmp_path / "in" / "ev.raw").write_bytes(b"x")
    (tmp_path / "in" / "sub").mkdir()
    (tmp_path / "in" / "sub" / "c.mcap").write_bytes(b"x")
    capsys.readouterr()
    main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(tmp_path / "out2"), "--jobs", "1"])
    out = capsys.readouterr().out
    assert "not calibrated: ev.raw" in out and "--odometry" in out and "not calibrated: sub/c.mcap" in out
    assert main(["batch", str(tmp_path / "in" / "ev.raw"), "--board", "acircles_4x11", "--out",
                 str(tmp_path / "out3")]) == 2
    assert "holds events only" in capsys.readouterr().err and not (tmp_path / "out3").exists()
    # Each failed recording has its folder saying so (before: only where an earlier folder was replaced).
    for name in ("a", "b"):
        rep = json.loads((tmp_path / "out" / name / "report.json").read_text())
        assert rep["ok"] is False and rep["calibration"] is None and rep["problems"]


def test_an_interrupted_batch_leaves_no_summary_of_the_batch_before(tmp_path, monkeypatch, caplog):
    # Before: Ctrl-C during batch --force left the earlier batch's summary.json beside folders of the new run.
    import plsgraph.refine.batch as rb

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    out = tmp_path / "out"
    assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(out), "--jobs", "1"]) == 1
    assert (out / "summary.json").exists()

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(rb, "refine_many", interrupted)
    with caplog.at_level(logging.WARNING):
        assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(out), "--jobs", "1",
                     "--force"]) == 130
    assert not (out / "summary.json").exists() and not (out / "summary.md").exists()
    assert any("batch interrupted: no recording had finished yet" in r.message and "no summary is written" in r.message
               for r in caplog.records)

    def after_one(items, fn, executor=None, progress=None):
        folder = Path(items[0][1])
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "report.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(rb, "refine_many", after_one)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(out), "--jobs", "1",
                     "--force"]) == 130
    assert any("so far the folders of a are this run's" in r.message for r in caplog.records)


def test_an_interrupted_batch_removes_what_its_killed_workers_left(tmp_path, monkeypatch):
    # A review: Ctrl-C on batch left the killed worker's staging folder and lock file beside the result folder.
    import plsgraph.refine.batch as rb

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    out = tmp_path / "out"
    out.mkdir()
    kept = out / "a"
    kept.mkdir()
    (kept / "report.json").write_text('{"earlier": true}')

    def killed_mid_run(items, fn, executor=None, progress=None):  # what a worker killed while writing leaves
        stage = out / ".a.staging-abcd1234"
        stage.mkdir()
        (stage / "calibration.yaml").write_text("half")
        (out / ".a.plsgraph-lock").write_text("")
        raise KeyboardInterrupt

    monkeypatch.setattr(rb, "refine_many", killed_mid_run)
    assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--out", str(out), "--jobs", "1",
                 "--force"]) == 130
    assert sorted(p.name for p in out.iterdir()) == ["a"]
    assert (kept / "report.json").read_text() == '{"earlier": true}'


SAMPLE = __import__("realdata").SAMPLE


@pytest.mark.parametrize(
    "flag, content, expect",
    [
        ("--board", "pattern: asymmetric_circles\ncols: four\nrows: 11\n", "wrong type"),
        ("--board", "pattern: [unclosed\n", "not valid YAML"),
        ("--camera-info", "width: 346\nheight: 260\nK: [1, 2, 3]\nD: []\n", "camera"),
        ("--camera-info", "{broken: [\n", "not valid YAML"),
        ("--truth", "42\n", "4 x 4 T_base_cam"),
    ],
)
def test_bad_side_files_are_user_errors(tmp_path, capsys, flag, content, expect):
    f = tmp_path / "side.yaml"
    f.write_text(content)
    args = ["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o"), flag, str(f)]
    if flag == "--board":
        args = ["calibrate", str(SAMPLE), "--out", str(tmp_path / "o"), "--board", str(f)]
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2 and expect in err and "Traceback" not in err


def test_output_into_a_file_is_a_user_error(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    code = main(["simulate", "--duration", "2", "--out", str(f / "x.mcap")])
    assert code == 2 and "Traceback" not in capsys.readouterr().err


def test_inspect_says_each_warning_once_on_each_stream(tmp_path):
    """Before: every reader warning came three times, twice on stderr (logged, then printed again)."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(Path(SAMPLE).read_bytes()[:6_000_000])
    p = subprocess.run([sys.executable, "-m", "plsgraph.cli.main", "inspect", str(cut)], capture_output=True, text=True,
                       timeout=120, env=dict(os.environ, PYTHONPATH=str(Path(plsgraph.__file__).parents[1])))
    assert p.returncode == 0
    assert p.stdout.count("file is truncated or corrupt") == 1
    assert p.stderr.count("file is truncated or corrupt") == 1


def test_diagnose_and_compare_answer_a_recording_too_short_to_calibrate_as_calibrate_does(tmp_path, capsys):
    """Before: calibrate gave exit 1 and a diagnosis for a recording cut after 300 kB, diagnose exit 2 (and --json
    printed nothing), compare exit 2."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(Path(SAMPLE).read_bytes()[:300_000])
    args = [str(cut), "--board", "acircles_4x11_a2"]
    assert main(["calibrate", *args, "--out", str(tmp_path / "c")]) == 1
    capsys.readouterr()
    rep = json.loads((tmp_path / "c" / "report.json").read_text())  # before: the board blamed, no warning kept
    assert "cut short or damaged" in rep["problems"][0] and "cut short or damaged" in rep["advice"][0]
    # The keys every report.json has (a review: a diagnosis had only a few of them).
    assert {"created_utc", "options", "recording_info", "counts", "discarded", "timing_s", "coverage"} <= rep.keys()
    assert rep["options"]["board"] == "acircles_4x11_a2" and rep["counts"]["odometry_samples"] > 0
    assert any("truncated or corrupt" in w for w in rep["warnings"]) and "--board" not in rep["advice"][0]
    assert main(["diagnose", *args, "--json"]) == 1
    d = json.loads(capsys.readouterr().out)
    assert d["ok"] is False and d["problems"] and d["advice"]
    assert main(["compare", *args]) == 1
    assert "no comparison" in capsys.readouterr().err
    assert main(["compare", *args, "--json"]) == 1  # before: nothing on stdout
    c = json.loads(capsys.readouterr().out)
    assert c["ok"] is False and c["problems"] and c["rows"] == []


def test_a_recording_with_events_alone_is_said_to_lack_the_odometry(tmp_path, capsys):
    """Before: 'nothing plsgraph can use; the file has: /event_camera/events', of a file whose events are usable."""
    from recordings import copy_mcap

    only = tmp_path / "events_only.mcap"
    copy_mcap(SAMPLE, only, lambda topic: 1 if topic.endswith("events") else 0)
    assert main(["calibrate", str(only), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "has events but no odometry" in err and "--odometry" in err and "nothing plsgraph can use" not in err


def test_batch_force_keeps_the_results_of_recordings_not_given_unless_pruned(tmp_path, capsys):
    """A recording's folder from an earlier batch once stayed beside a new summary that no longer listed it; then
    --force removed it, and so calibrating one recording again removed every other's good result (a review). It now
    stays and is listed as an earlier run; --prune removes it."""
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    out = tmp_path / "out"
    (out / "gone").mkdir(parents=True)
    # The folder holds another result than the earlier summary says (a batch was interrupted after replacing it, before
    # writing its summary; a review): the row is the folder's.
    (out / "gone" / "report.json").write_text(json.dumps(
        {"ok": False, "problems": ["the camera comes out upside down"], "warnings": [],
         "calibration": {"rpy_deg": [4.0, 5.0, 6.0], "time_offset_s": 0.02, "observability": []}}))
    (out / "mine").mkdir()
    (out / "mine" / "notes.txt").write_text("kept")
    # A calibration's folder put beside the batch's by hand (no earlier summary lists it): not the batch's to remove.
    (out / "robotA_final").mkdir()
    (out / "robotA_final" / "calibration.yaml").write_text("ok: true\n")
    earlier = {"recordings": [{"recording": "/somewhere/gone.mcap", "status": "ok", "rpy_deg": [1.0, 2.0, 3.0]}]}
    (out / "summary.json").write_text(json.dumps(earlier))
    assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--force",
                 "--jobs", "1"]) == 1  # this batch's one recording failed
    text = capsys.readouterr().out
    assert "kept the earlier results of recordings not in this batch" in text and "gone" in text
    assert (out / "gone" / "report.json").exists()
    rows = {Path(r["recording"]).stem: r for r in json.loads((out / "summary.json").read_text())["recordings"]}
    assert rows["gone"]["earlier_run"] is True and rows["gone"]["rpy_deg"] == [4.0, 5.0, 6.0]
    assert rows["gone"]["status"] == "flagged" and rows["gone"]["problems"] == ["the camera comes out upside down"]
    assert rows["a"]["status"] == "failed" and rows["a"]["problems"] == [rows["a"]["error"]]
    assert set(rows["a"]) >= {"folder", "sigma", "warnings", "translation_m", "rpy_deg", "rpy_sigma_deg",
                              "time_offset_s"}
    # --prune (with --force) removes them; --prune alone is refused.
    assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--prune"]) == 2
    capsys.readouterr()
    assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--force",
                 "--prune", "--jobs", "1"]) == 1
    assert "removed the earlier results of recordings not in this batch (--prune): gone" in capsys.readouterr().out
    assert not (out / "gone").exists() and (out / "mine" / "notes.txt").read_text() == "kept"
    assert (out / "robotA_final" / "calibration.yaml").read_text() == "ok: true\n"
    # Without an earlier summary nothing but this batch's own folders is touched (before: every result folder went).
    (out / "summary.json").unlink()
    (out / "robotB_final").mkdir()
    (out / "robotB_final" / "report.json").write_text('{"ok": true}')
    main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--force", "--jobs", "1"])
    assert "removed" not in capsys.readouterr().out
    assert (out / "robotB_final" / "report.json").exists() and (out / "robotA_final").exists()


def test_flags_that_cannot_make_sense_are_refused_before_any_work(tmp_path, capsys):
    # Before: reproduce-paper --seed -1 ended in an internal error (exit 3); --td-range 1e9 ran the whole front end
    # to a diagnosis; --trials 1e8 filled the memory; a camera frame equal to the base frame wrote robot files tf2
    # refuses; batch with an unknown board failed every recording one by one (exit 1).
    def refused(argv, words):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, err
        assert all(w in err for w in words), err

    refused(["reproduce-paper", "--quick", "--seed", "-1", "--out", str(tmp_path / "t")], ["--seed", ">= 0"])
    refused(["reproduce-paper", "--trials", "100000000", "--out", str(tmp_path / "t")], ["--trials", "10000"])
    assert not (tmp_path / "t").exists()
    cal = ["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o")]
    refused([*cal, "--td-range", "1e9"], ["--td-range", "--clock-offset"])
    refused([*cal, "--child-frame", "base_link"], ["same frame", "base_link"])
    refused([*cal, "--parent-frame", "cam", "--child-frame", "cam"], ["same frame"])
    assert not (tmp_path / "o").exists()
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    refused(["batch", str(tmp_path / "in"), "--board", "nosuch", "--out", str(tmp_path / "b")], ["nosuch"])
    refused(["batch", str(tmp_path / "in"), "--board", "acircles_4x11", "--camera-info", str(tmp_path / "no.yaml"),
             "--out", str(tmp_path / "b")], ["no.yaml", "does not exist"])
    assert not (tmp_path / "b").exists()
    (tmp_path / "in" / "sub").mkdir()
    (tmp_path / "in" / "sub" / "a.bag").write_bytes(b"x")
    refused(["batch", str(tmp_path / "in" / "a.mcap"), str(tmp_path / "in" / "sub" / "a.bag"), "--board",
             "acircles_4x11", "--out", str(tmp_path / "b")], ["share a name", "a.mcap", "a.bag"])
    # A review: the same file twice (overlapping globs) was "recordings share a name ... rename one"; two recordings
    # given to calibrate got only "unrecognized arguments"; reproduce-paper into a file ended in "[Errno 17]".
    from plsgraph.batch import find_recordings

    a = tmp_path / "in" / "a.mcap"
    assert find_recordings([a, tmp_path / "in", tmp_path / "in" / "." / "a.mcap"]) == [a]
    for extra, words in ([str(tmp_path / "in" / "sub" / "a.bag")], ["takes one recording", "plsgraph batch"]), \
            (["--nosuch"], ["unrecognized arguments: --nosuch"]):
        with pytest.raises(SystemExit) as stop:  # argparse's usage errors
            main(["calibrate", str(a), *extra, "--board", "acircles_4x11", "--out", str(tmp_path / "b")])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and all(w in err for w in words), err
    (tmp_path / "afile").write_text("x")
    refused(["reproduce-paper", "--quick", "--out", str(tmp_path / "afile")], ["exists and is not a folder"])


def test_a_truth_file_that_does_not_exist_is_named_plainly(tmp_path, capsys):
    out = tmp_path / "o"
    for truth in ("nosuch.yaml", "nosuch.truth.yaml"):
        assert main(["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--truth", str(tmp_path / truth),
                     "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert f"truth file {tmp_path / truth} does not exist" in err, err


def test_intrinsics_missing_from_both_files_names_both(tmp_path, capsys):
    jackal = SHARED_REAL_DIR / "jackal_odometry.bag"
    if not (DAVIS.exists() and jackal.exists()):
        pytest.skip("real recordings missing")
    assert main(["diagnose", str(DAVIS), "--odometry", str(jackal), "--board", "aprilgrid_4x3_tagboard"]) == 2
    err = capsys.readouterr().err
    assert "has no sensor_msgs/CameraInfo topic (nor does the odometry file" in err and "--camera-info" in err


def test_json_commands_answer_an_input_error_in_json_too(tmp_path, capsys):
    # Before: `diagnose notes.mcap --json` exited 2 with nothing on stdout, so a script's json.loads failed.
    notes = tmp_path / "notes.mcap"
    notes.write_text("not a recording")
    for argv in (["diagnose", str(notes), "--board", "acircles_4x11_a2", "--json"], ["inspect", str(notes), "--json"],
                 ["compare", str(notes), "--board", "acircles_4x11_a2", "--json"]):
        assert main(argv) == 2
        out = capsys.readouterr()
        d = json.loads(out.out)
        assert d["ok"] is False and d["exit_code"] == 2 and d["error"] in out.err
    assert main(["diagnose", str(notes), "--board", "acircles_4x11_a2"]) == 2
    assert capsys.readouterr().out == ""  # without --json the terminal output stays as it was


def test_batch_takes_each_recordings_own_settings_from_its_options_file(tmp_path, capsys):
    """A review: a fleet batch could not give robots their own wheels, camera height or topics. NAME.options.yaml
    beside NAME.mcap holds them (checked before any work)."""
    from plsgraph.batch import recording_options
    from plsgraph.options import CalibrationOptions

    base = CalibrationOptions.build(board="acircles_4x11_a2", wheel_radius=0.098)
    rec = tmp_path / "robot2.mcap"
    rec.write_bytes(b"")
    assert recording_options(rec, base) is base  # no file: the batch's options
    (tmp_path / "cam.yaml").write_text("x: 1\n")
    (tmp_path / "robot2.options.yaml").write_text("wheel_radius: 0.11\ncamera_height: 0.31\ncamera_info: cam.yaml\n")
    mine = recording_options(rec, base).to_dict()
    flat = {k: v for sec in mine.values() if isinstance(sec, dict) for k, v in sec.items()}
    assert flat["wheel_radius"] == 0.11 and flat["camera_height"] == 0.31
    assert flat["camera_info"] == str(tmp_path / "cam.yaml")  # relative to the options file
    # A wrong name is refused before any recording is calibrated, naming the file.
    (tmp_path / "robot2.options.yaml").write_text("wheel_radus: 0.11\n")
    rec.write_bytes(b"not a recording")
    assert main(["batch", str(rec), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "robot2.options.yaml" in err and "wheel_radus" in err and not (tmp_path / "b").exists()


def test_batch_says_when_a_recordings_earlier_calibration_was_kept(tmp_path, monkeypatch):
    # A review: the folder kept its earlier calibration in previous_calibration/, and neither the terminal nor the
    # summary said so.
    from concurrent.futures import ThreadPoolExecutor

    import plsgraph.api as api
    from plsgraph.batch import run_batch
    from plsgraph.options import CalibrationOptions

    rec = tmp_path / "rec1.mcap"
    rec.write_bytes(b"stand-in")

    def flagged(log_path, out_dir, opts, force=False, figure_worker=None):
        return {"ok": False, "report": {"calibration": None, "problems": ["spun in place"], "warnings": [],
                                        "previous_calibration": "previous_calibration"}}

    monkeypatch.setattr(api, "calibrate_to_dir", flagged)
    with ThreadPoolExecutor(1) as pool:  # threads: the stand-in calibration is this process's
        res = run_batch([rec], tmp_path / "out", CalibrationOptions.build(board="acircles_4x11_a2"), executor=pool)
    (row,) = res["rows"]
    assert row["status"] == "flagged" and row["previous_calibration"].endswith("rec1/previous_calibration")
    assert "kept the calibration rec1's folder held before in" in res["text"]
    saved = json.loads((tmp_path / "out" / "summary.json").read_text())["recordings"][0]
    assert saved["previous_calibration"] == row["previous_calibration"] and saved["problems"] == ["spun in place"]


def test_batch_options_files_paths_and_checks_and_an_interrupted_batchs_earlier_rows(tmp_path, capsys):
    # A review of the batch changes: an intrinsics file named in NAME.options.yaml was not checked before work, a
    # truth named there was dropped, paths stayed relative to the working folder, and an interrupted batch's next run
    # no longer listed the earlier batch's folders.
    from plsgraph.batch import EARLIER_SUMMARY, _earlier_batch_rows, _kept_calibration, recording_options
    from plsgraph.errors import InputError
    from plsgraph.options import CalibrationOptions

    base = CalibrationOptions.build(board="acircles_4x11_a2")
    (tmp_path / "sub").mkdir()
    rec = tmp_path / "run.2024.mcap"
    rec.write_bytes(b"not a recording")
    opts_file = tmp_path / "run.2024.options.yaml"
    opts_file.write_text("camera_info: sub/none.yaml:cam1\n")
    with pytest.raises(InputError, match=r"run\.2024\.options\.yaml: camera file .*none\.yaml(:cam1)? does not exist"):
        recording_options(rec, base)
    assert main(["batch", str(rec), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()
    capsys.readouterr()
    opts_file.write_text("truth: sub/t.yaml\nodometry_file: sub/odo.mcap\n")
    (tmp_path / "sub" / "odo.mcap").write_bytes(b"x")  # a missing odometry file is refused (test below)
    got = recording_options(rec, base)
    assert Path(got.truth) == tmp_path / "sub" / "t.yaml" and got.inputs.odometry_file == tmp_path / "sub" / "odo.mcap"
    opts_file.write_text("topics: {joints: 5}\n")
    with pytest.raises(InputError, match="topics must map roles"):
        recording_options(rec, base)
    # An interrupted batch set the earlier summary aside; the next batch still finds its rows (with every key).
    out = tmp_path / "b"
    out.mkdir()
    (out / EARLIER_SUMMARY).write_text(json.dumps({"recordings": [{"recording": "/x/old.mcap", "status": "ok"}]}))
    rows = _earlier_batch_rows(out)
    assert rows["old"]["status"] == "ok" and rows["old"]["warnings"] == [] and "sigma" in rows["old"]
    # A failed recording's folder that kept its earlier calibration says so in its row, as an absolute path.
    (out / "old").mkdir()
    (out / "old" / "report.json").write_text(json.dumps({"previous_calibration": "previous_calibration"}))
    assert _kept_calibration(str(out / "old")) == str((out / "old" / "previous_calibration").absolute())


def _front_end_arguments(monkeypatch) -> dict:
    """The keyword arguments the next calibration hands the streaming front end (which then stops it, exit 3)."""
    import plsgraph.frontend.track as track

    seen: dict = {}

    class Stop(Exception):
        pass

    def capture(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(track, "camera_track_from_event_chunks", capture)
    return seen


def test_window_and_tau_reach_the_front_end_and_are_checked(tmp_path, monkeypatch, capsys):
    # A review: the bundled board of the real DAVIS346 recording is found only with a leaky surface of tau 0.3 s over
    # 0.9 s windows (tests/test_real_tagboard.py), which the command line could not set.
    seen = _front_end_arguments(monkeypatch)
    args = ["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o")]
    assert main([*args, "--surface", "leaky", "--tau", "0.3", "--window", "0.9"]) == 3  # stopped at the front end
    assert seen["kind"] == "leaky" and seen["window_s"] == 0.9 and seen["surface_params"] == {"tau_s": 0.3}
    seen.clear()
    main(args)
    assert "window_s" not in seen and "surface_params" not in seen  # the defaults: as before
    capsys.readouterr()
    assert main([*args, "--tau", "0.3"]) == 2  # the count surface has no time constant
    assert "has none" in capsys.readouterr().err
    assert main([*args, "--window", "9"]) == 2
    assert "outside 0.001 .. 5 s" in capsys.readouterr().err


def test_a_second_batch_into_the_same_folder_fails_at_once(tmp_path, capsys):
    """A review: two batches into one --out both ran, marked each other's recordings failed, and the last summary said
    failed of a folder holding an ok calibration."""
    from plsgraph.report.files import OutputLock

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.mcap").write_bytes(b"not a recording")
    out = tmp_path / "out"
    out.mkdir()
    with OutputLock(out):  # the first batch, still running
        assert main(["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--force",
                     "--jobs", "1"]) == 2
    assert "another plsgraph run is writing the output folder" in capsys.readouterr().err
    assert not (out / "a").exists()


def test_an_interrupted_batch_stops_its_workers_at_once():
    """A review: Ctrl-C (or kill -INT of the batch alone) let the recording a worker had queued start and finish after
    the message that named the finished folders."""
    import time

    from plsgraph.batch import _stop_workers
    from plsgraph.refine.batch import default_executor

    ex = default_executor(2, 2)
    try:
        futs = [ex.submit(time.sleep, 30) for _ in range(3)]
        deadline = time.monotonic() + 20
        while not (len(ex._processes) == 2 and all(p.is_alive() for p in ex._processes.values())
                   and any(f.running() for f in futs)) and time.monotonic() < deadline:
            time.sleep(0.05)
        pids = list(ex._processes)
        assert len(pids) == 2
        t0 = time.monotonic()
        _stop_workers(ex)

        def running(pid):  # by the system's account (the pool's own thread may reap them first)
            try:
                with open(f"/proc/{pid}/stat") as f:
                    return f.read().split(")")[-1].split()[0] != "Z"
            except OSError:
                return False

        while any(running(p) for p in pids) and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        assert not any(running(p) for p in pids)  # stopped, not after the 30 s sleeps
    finally:
        ex.shutdown(wait=False, cancel_futures=True)


def test_a_killed_worker_process_is_named_not_reported_as_a_bug(tmp_path, monkeypatch, capsys):
    """A review: a front-end worker killed (an out-of-memory kill) gave 'internal error (BrokenProcessPool ...);
    please report it'."""
    from concurrent.futures.process import BrokenProcessPool

    import plsgraph.frontend.track as track

    def killed(*args, **kwargs):
        raise BrokenProcessPool("A process in the process pool was terminated abruptly")

    monkeypatch.setattr(track, "camera_track_from_event_chunks", killed)
    assert main(["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o")]) == 3
    err = capsys.readouterr().err
    assert "worker process ended abruptly" in err and "out of memory" in err and "please report" not in err


def test_a_full_disk_is_named_with_the_folder_and_the_earlier_result_kept(tmp_path, monkeypatch, capsys):
    """A review: a full disk gave only 'plsgraph: error: [Errno 28] No space left on device' (no path, nothing on what
    became of the results)."""
    import errno

    import plsgraph.report.output as output

    out = tmp_path / "o"
    out.mkdir()
    (out / "calibration.yaml").write_text("ok: true\n")
    (out / "report.json").write_text("{}")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(output, "write_calibration", full)
    code = main(["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--no-refine", "--out", str(out), "--force"])
    err = capsys.readouterr().err
    assert code == 2 and f"no space left on the disk of {out}" in err and "earlier result" in err
    assert (out / "calibration.yaml").read_text() == "ok: true\n"


def test_a_simulation_larger_than_the_available_memory_is_refused_before_it_starts(tmp_path, monkeypatch, capsys):
    """A review: --duration was accepted up to an hour, which would need about 115 GB (the events are held in
    memory), without a word."""
    import plsgraph.api as api

    monkeypatch.setattr(api, "_available_memory", lambda: 2e9)
    assert main(["simulate", "--duration", "120", "--out", str(tmp_path / "s.mcap")]) == 2
    err = capsys.readouterr().err
    assert "needs about 4.3 GB of memory" in err and "2.0 GB are available" in err and "at most about 52 s" in err
    assert not (tmp_path / "s.mcap").exists()


def test_the_front_ends_progress_bar_knows_an_mcap_recordings_length(tmp_path, monkeypatch):
    """A review: on MCAP files the 'detecting board' bar had no total (the topic's time span is not in the summary)
    and looked finished all along (8998/8998 for 72 s)."""
    from plsgraph.io.source import open_source

    seen = _front_end_arguments(monkeypatch)
    main(["calibrate", str(SAMPLE), "--board", "acircles_4x11_a2", "--out", str(tmp_path / "o")])
    first, last = seen["expected_span_ns"]
    times = [m.log_time_ns for m in open_source(SAMPLE).iter_raw({"/event_camera/events"})]
    assert first <= min(times) and last >= max(times) and (last - first) < 1.1 * (max(times) - min(times)) + 1e9


def test_a_progress_bar_whose_count_starts_again_shows_passes_and_a_warning_starts_a_new_line():
    """A review: the refinement's bar restarted about ten times (each pass counts its iterations from 0), showed an
    estimate of 297 s for a 24 s step, and a warning was printed at the end of its line."""
    import io
    import logging

    from plsgraph.cli.progress import ProgressBar, end_bar_line

    stream = io.StringIO()
    with ProgressBar("refining (GTSAM)", stream=stream, force=True, min_interval_s=0.0) as bar:
        for it in range(4):
            bar(it, 30)
        assert "eta" in stream.getvalue().split("\r")[-1]
        for it in range(3):  # the next pass
            bar(it, 30)
        last = stream.getvalue().split("\r")[-1]
        assert "pass 2, step 2" in last and "eta" not in last and "/30" not in last
        record = logging.LogRecord("x", logging.WARNING, __file__, 1, "a warning", None, None)
        assert end_bar_line(record) is True and stream.getvalue().endswith("\n")  # the bar's line is ended first
        bar(3, 30)
    assert stream.getvalue().endswith("\n")


def test_batch_resume_calibrates_only_the_recordings_without_a_result(tmp_path, capsys):
    """A review: an interrupted batch could not be resumed (refused without --force; with it the finished recordings
    were computed again)."""
    (tmp_path / "in").mkdir()
    for name in ("a", "b"):
        (tmp_path / "in" / f"{name}.mcap").write_bytes(b"not a recording")
    out = tmp_path / "out"
    (out / "a").mkdir(parents=True)  # finished before the interrupt
    (out / "a" / "report.json").write_text(json.dumps(
        {"ok": True, "problems": [], "warnings": [], "calibration": {"rpy_deg": [1.0, 2.0, 3.0],
                                                                    "time_offset_s": 0.01, "observability": []}}))
    before = (out / "a" / "report.json").read_text()
    args = ["batch", str(tmp_path / "in"), "--board", "acircles_4x11_a2", "--out", str(out), "--jobs", "1"]
    assert main([*args, "--resume", "--force"]) == 2  # one or the other
    capsys.readouterr()
    assert main([*args, "--resume"]) == 1  # b fails (not a recording): the exit code is about every recording given
    text = capsys.readouterr().out
    assert "--resume: 1 recording(s) already had a result and were not calibrated again" in text
    assert (out / "a" / "report.json").read_text() == before  # not calibrated again
    rows = {Path(r["recording"]).stem: r for r in json.loads((out / "summary.json").read_text())["recordings"]}
    assert rows["a"]["earlier_run"] and rows["a"]["status"] == "ok" and rows["a"]["rpy_deg"] == [1.0, 2.0, 3.0]
    assert rows["b"]["status"] == "failed" and not rows["b"].get("earlier_run")
    assert (out / "b" / "report.json").is_file()
    # A failure's folder is tried again (a broken file, a full disk: it may work now); the calibrated one is not.
    assert main([*args, "--resume"]) == 1
    assert "--resume: 1 recording(s) already had a result and were not calibrated again (listed as earlier runs): a" \
        in capsys.readouterr().out


@pytest.mark.skipif(not SAMPLE.exists(), reason="the sample recording is not in this checkout")
def test_the_way_to_the_front_end_loads_no_scipy():
    """Everything calibrate does before the front end starts (the command, reading the recording's other topics, the
    wheel odometry) leaves scipy unloaded: it costs 0.2 s to load and is loaded while the front end's workers detect,
    when this process only waits."""
    code = ("import sys; from pathlib import Path; import plsgraph.cli.main, plsgraph.api; "
            "from plsgraph import pipeline as P; from plsgraph.options import CalibrationOptions; "
            f"run = P.Run(Path({str(SAMPLE)!r}), CalibrationOptions.build(None, board='acircles_4x11_a2')); "
            "rec = P.read_inputs(run); track = P.build_base_track(run, rec); assert len(track.t) > 100; "
            "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.'))[:5])")
    env = {**os.environ, "PYTHONPATH": str(Path(plsgraph.__file__).resolve().parent.parent)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_focal_sigma_is_checked_and_reaches_the_refinement(monkeypatch):
    """--focal-sigma: a relative accuracy from 0 to 0.2 (0.5 % by default), handed to the refinement."""
    import pytest as _pytest

    from plsgraph.errors import InputError
    from plsgraph.options import CalibrationOptions

    assert CalibrationOptions.build(board="acircles_4x11_a2").refine.focal_sigma == 0.005
    assert CalibrationOptions.build(board="acircles_4x11_a2", focal_sigma=0).refine.focal_sigma == 0
    for bad in (-0.01, 0.5, float("nan"), True, "1%"):
        with _pytest.raises(InputError, match="focal_sigma"):
            CalibrationOptions.build(board="acircles_4x11_a2", focal_sigma=bad)
    import plsgraph.cli.main as cli

    args = cli._build_parser().parse_args(["calibrate", "rec.mcap", "--board", "acircles_4x11_a2", "--out", "o",
                                          "--focal-sigma", "0.01"])
    assert cli._options(args).refine.focal_sigma == 0.01


def test_batch_takes_a_ros2_bag_folder_as_one_recording_with_its_own_files_beside_it(tmp_path):
    # A review: batch found no recording in a folder of bag folders; given a bag folder, it calibrated each of its
    # split .db3 files as a recording of its own (each reading the whole bag) and dropped the options and truth files
    # beside the folder.
    from plsgraph.batch import find_recordings, recording_name, recording_options, skipped_in_folders
    from plsgraph.options import CalibrationOptions

    fleet = tmp_path / "fleet"
    bag = fleet / "robot2"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    for k in range(2):
        (bag / f"robot2_{k}.db3").write_bytes(b"x")
    (fleet / "robot1.mcap").write_bytes(b"x")
    (fleet / "robot2.options.yaml").write_text("camera_height: 0.25\n")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 8\n")
    data = tmp_path / "dataset"  # a dataset's own metadata.yaml beside its recordings: not a bag
    data.mkdir()
    (data / "metadata.yaml").write_text("robot: jackal\n")
    (data / "run1.mcap").write_bytes(b"x")
    assert find_recordings([data]) == [data / "run1.mcap"]
    assert find_recordings([fleet]) == [fleet / "robot1.mcap", bag]
    assert find_recordings([bag]) == [bag]
    assert skipped_in_folders([fleet]) == []  # the bag's .db3 files are the bag's, not skipped recordings
    assert recording_options(bag, CalibrationOptions()).refine.camera_height == 0.25
    dotted = fleet / "run.v2"  # a bag folder's whole name is its name
    dotted.mkdir()
    (dotted / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 8\n")
    (fleet / "run.v2.options.yaml").write_text("camera_height: 0.3\n")
    assert recording_name(dotted) == "run.v2" and recording_name(fleet / "robot1.mcap") == "robot1"
    assert recording_options(dotted, CalibrationOptions()).refine.camera_height == 0.3


def test_an_options_file_takes_the_command_lines_names_and_suggests_the_nearest(tmp_path):
    # A review: rate, events_topic, wheel-radius (calibrate's flags) were refused as unknown without a hint; a missing
    # odometry file was found only after the other recordings had been calibrated.
    from plsgraph.batch import recording_options
    from plsgraph.errors import InputError
    from plsgraph.options import CalibrationOptions

    rec = tmp_path / "r3.mcap"
    rec.write_bytes(b"x")
    opts = tmp_path / "r3.options.yaml"
    opts.write_text("rate: 20\nwheel-radius: 0.1\nevents_topic: /rear/events\ntopics: {joints: /js}\n")
    o = recording_options(rec, CalibrationOptions(board="acircles_4x11_a2"))
    assert (o.frontend.rate_hz, o.odometry.wheel_radius) == (20, 0.1)
    assert o.inputs.topics == {"joints": "/js", "events": "/rear/events"}
    opts.write_text("wheel_raduis: 0.1\n")
    with pytest.raises(InputError, match=r"wheel_raduis \(did you mean wheel_radius\?\).*rate_hz"):
        recording_options(rec, CalibrationOptions(board="acircles_4x11_a2"))
    opts.write_text("rate: 20\nrate_hz: 25\n")
    with pytest.raises(InputError, match="given twice"):
        recording_options(rec, CalibrationOptions(board="acircles_4x11_a2"))
    opts.write_text("odometry: nosuch.mcap\n")
    with pytest.raises(InputError, match=f"odometry file {tmp_path / 'nosuch.mcap'} does not exist"):
        recording_options(rec, CalibrationOptions(board="acircles_4x11_a2"))


def test_a_diagnosis_whose_board_search_found_nothing_says_zero_frames():
    # A review of the "not searched for" line: a front end that ran and found no board must still say 0.
    from plsgraph.api import diagnose
    from plsgraph.report.text import diagnosis_text

    d = diagnose(SAMPLE, board="aprilgrid_6x6")
    assert not d.ok and d.camera_frames == 0 and "no board detected" in d.problems[0]
    assert "camera frames with the board: 0" in diagnosis_text(d)
