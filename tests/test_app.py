"""The library API's calibration tail (closed form -> refinement -> result files) on simulated tracks, no events."""

import html
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import plsgraph
from plsgraph.api import calibrate_to_dir
from plsgraph.core.geometry import rotation_error_deg
from plsgraph.errors import InputError
from plsgraph.frontend.pose import camera_track_from_detections
from plsgraph.odometry.wheels import base_track_from_wheels
from plsgraph.options import CalibrationOptions, FrontendOptions, OdometryOptions
from plsgraph.report import figure_worker
from plsgraph.report.figure_worker import FigureWorker
from plsgraph.report.files import prepare_output_dir
from plsgraph.report.output import write_calibration
from plsgraph.report.text import calibration_text
from plsgraph.result import CalibrationResult
from plsgraph.sim.robot import simulate_robot


@pytest.fixture(scope="module")
def sim_run():
    sim = simulate_robot("rich", duration=12.0, seed=3, td=0.04, slip=0.0, realism="ideal")
    cam_track = camera_track_from_detections(sim.detections(noise_px=0.1, seed=4), sim.camera)
    base = base_track_from_wheels(sim.wheel_t, sim.wheel_left, sim.wheel_right, sim.wheel_radius, sim.track_width)
    truth = {"T_base_cam": sim.T_base_cam.tolist(), "td": sim.td}
    result = plsgraph.calibrate_tracks(cam_track, base, sim.camera, board="acircles_4x11", truth=truth)
    return sim, result


def test_refined_result_recovers_truth(sim_run):
    sim, result = sim_run
    assert isinstance(result, CalibrationResult) and result.ok and result.source == "refined"
    run = result.run
    ref = run.refinement
    np.testing.assert_allclose(result.T_base_cam[:, :3], ref.T_base_cam[:, :3])
    np.testing.assert_allclose(result.T_base_cam[:2, 3], ref.T_base_cam[:2, 3])
    assert result.T_base_cam[2, 3] == 0.0  # the height is not measured: written as 0, never a seed value
    assert result.time_offset_s == ref.td
    assert result.covariance.shape == (7, 7) and result.covariance_order[-1] == "td"
    assert set(result.closed_form) >= {"pls", "cca", "procrustes"}
    assert ref.converged
    # Tolerances: 0.1 px detection noise, no wheel slip; the refinement must beat the closed form.
    assert rotation_error_deg(ref.R_base_cam, sim.R_base_cam) < 0.1
    assert rotation_error_deg(ref.R_base_cam, sim.R_base_cam) < rotation_error_deg(run.closed_form.R_base_cam,
                                                                                    sim.R_base_cam)
    assert np.linalg.norm(ref.T_base_cam[:2, 3] - sim.T_base_cam[:2, 3]) < 0.01
    assert abs(ref.td - sim.td) < 0.003


def test_report_files_are_complete_and_parse(sim_run, tmp_path):
    sim, result = sim_run
    report = result.to_dict()
    out = prepare_output_dir(tmp_path / "calib")
    write_calibration(out, result)
    calib = yaml.safe_load((out / "calibration.yaml").read_text())
    rep = json.loads((out / "report.json").read_text())
    T = np.array(calib["T_base_cam"])
    assert rotation_error_deg(T[:3, :3], sim.R_base_cam) < 0.1
    assert calib["time_offset_s"] == pytest.approx(sim.td, abs=0.003)
    assert len(calib["covariance"]["matrix"]) == 7
    statuses = {o["name"]: o["status"] for o in calib["observability"]}
    assert statuses["z"] == "unobservable"  # camera height under planar motion
    assert {"direction", "status", "sigma", "note"} <= set(calib["observability"][0])
    assert "static_transform_publisher" in calib["ros_static_transform"]
    for method in ("pls", "cca", "procrustes"):
        assert method in rep["closed_form"]
    assert rep["truth_errors"]["refined.rot_err_deg"] < 0.1
    page = (out / "report.html").read_text()
    for png in ("trajectories.png", "residuals.png", "time_offset.png", "observability.png", "methods.png"):
        assert (out / png).stat().st_size > 1000 and png in page
    # One unit per row (before: "time offset (s) 0.011223 ± 8.42 ms"); a solver that warned is not listed "ok".
    assert f"time offset (ms)</td><td>{1e3 * calib['time_offset_s']:.3f}</td>" in page
    for name, m in rep["closed_form"].items():
        want = "error" if m["error"] else "warned" if m["warnings"] else "ok"
        assert f"<td>{name}</td><td><span class='st' style='background:" in page
        assert f">{want}</span></td><td>{html.escape(m['error'] or '')}" in page.split(f"<td>{name}</td>", 1)[1]
    text = calibration_text(report)
    assert "refined" in text
    tilt = rep["refinement"]["inflation"]["floor_tilt_rms_deg"]
    assert tilt < 0.1 and f"the base tilted {tilt:.2f} deg RMS" in text  # a level simulated floor


FIGURE_FILES = ("trajectories.png", "residuals.png", "time_offset.png", "observability.png", "methods.png")


def test_figures_drawn_by_the_worker_are_those_drawn_in_process(sim_run, tmp_path):
    _, result = sim_run
    here, there = prepare_output_dir(tmp_path / "here"), prepare_output_dir(tmp_path / "there")
    write_calibration(here, result)
    with FigureWorker.start() as worker:
        assert worker.available
        write_calibration(there, result, worker)
        assert not worker.available  # it ends once it has answered
    for f in FIGURE_FILES:  # the same drawing code on the same arrays: the same pictures
        assert (there / f).read_bytes() == (here / f).read_bytes()
    for f in ("calibration.yaml", "report.html"):
        assert (there / f).read_text() == (here / f).read_text()
    rep = json.loads((there / "report.json").read_text())
    assert rep["timing_s"]["figures"] >= 0 and not any("figure" in w for w in rep["warnings"])


def test_a_worker_told_to_warm_up_early_draws_the_same_figures(sim_run, tmp_path):
    """calibrate_to_dir tells the worker to warm up once the front end is done (warm() before send(); twice is
    once); the figures are the same."""
    _, result = sim_run
    here, there = prepare_output_dir(tmp_path / "here"), prepare_output_dir(tmp_path / "there")
    write_calibration(here, result)
    with FigureWorker.start() as worker:
        worker.warm()
        worker.warm()
        assert worker.available
        write_calibration(there, result, worker)
    for f in FIGURE_FILES:
        assert (there / f).read_bytes() == (here / f).read_bytes()
    FigureWorker().warm()  # a worker that never started: nothing to do


@pytest.fixture(scope="module")
def sample_result():
    """The bundled rich sample calibrated (its run has the front end's coverage and the recording for the event
    frames)."""
    from realdata import SAMPLE

    from plsgraph.pipeline import run_recording
    from plsgraph.result import calibration_result

    if not SAMPLE.exists():
        pytest.skip("the sample recording is not in this checkout")
    return calibration_result(run_recording(SAMPLE, CalibrationOptions.build(board="acircles_4x11_a2")))


def test_figures_drawn_while_the_calibration_runs_are_the_same(tmp_path):
    """calibrate_to_dir has the worker draw the event frames once the tracks are final, while the closed form and the
    refinement run, into a subfolder moved into the run's folder with the rest: the same files, the same pictures, and
    no subfolder left, as when every figure is drawn in the process."""
    from realdata import SAMPLE

    if not SAMPLE.exists():
        pytest.skip("the sample recording is not in this checkout")
    opts = CalibrationOptions.build(board="acircles_4x11_a2")
    calibrate_to_dir(SAMPLE, tmp_path / "worker", opts, figure_worker=True)
    calibrate_to_dir(SAMPLE, tmp_path / "here", opts, figure_worker=False)
    there, here = tmp_path / "worker", tmp_path / "here"
    assert not (there / figure_worker.EARLY_DIR).exists() and not (there / figure_worker.SPECULATIVE_DIR).exists()
    names = sorted(p.name for p in there.iterdir())
    assert names == sorted(p.name for p in here.iterdir()) and "event_frames.png" in names
    for f in names:
        if f.endswith(".png"):
            assert (there / f).read_bytes() == (here / f).read_bytes(), f
    rep = json.loads((there / "report.json").read_text())
    assert not any("figure" in w for w in rep["warnings"])


def _solution(run, rotate_deg: float = 0.0):
    """The run's refined solution as the refinement hands it over before its second opinions, its rotation turned
    by ``rotate_deg`` about z."""
    from types import SimpleNamespace

    from plsgraph.core.geometry import make_T, so3_exp

    ref = run.refinement
    T = ref.T_base_cam
    if rotate_deg:
        T = T @ make_T(so3_exp(np.array([0.0, 0.0, np.radians(rotate_deg)])), np.zeros(3))
    return SimpleNamespace(T_base_cam=T, R_base_cam=T[:3, :3], td=ref.td, T_world_board=ref.T_world_board,
                           observability=None, residual_t=ref.residual_t, residual_px=ref.residual_px,
                           knot_t=ref.knot_t, T_world_base=ref.T_world_base)


@pytest.mark.parametrize("rotate_deg", [0.0, 2.0])
def test_speculative_figures_are_kept_only_for_the_final_solution(sample_result, tmp_path, monkeypatch, rotate_deg):
    """Figures drawn from the refinement's solution before its second opinions are kept when the result's solution is
    that one (the final job draws only the rest) and drawn again when it is not: either way the pictures are those
    drawn in the process, and no subfolder is left."""
    here = prepare_output_dir(tmp_path / "here")
    write_calibration(here, sample_result)
    jobs = []
    frame = figure_worker._frame
    monkeypatch.setattr(figure_worker, "_frame", lambda job: jobs.append(job) or frame(job))
    out = prepare_output_dir(tmp_path / "worker")
    with FigureWorker.start() as worker:
        worker.warm()
        worker.early(out, sample_result.run)
        worker.speculate(out, sample_result.run, _solution(sample_result.run, rotate_deg))
        write_calibration(out, sample_result, worker)
    final = [j for j in jobs if j[3]]
    assert len(jobs) == 3 and len(final) == 1
    # The event frames' images travel with the job that draws them only.
    assert jobs[0][1].event_frames and jobs[1][1].event_frames is None
    assert (final[0][1].event_frames is None) == (figure_worker.EVENT_FRAMES_FIGURE not in final[0][2])
    kept = str(out / figure_worker.SPECULATIVE_DIR) in final[0][4]
    assert kept == (rotate_deg == 0.0)
    assert set(final[0][2]) == ({3} if kept else {0, 1, 2, 3, 4, 5})
    assert not (out / figure_worker.SPECULATIVE_DIR).exists() and not (out / figure_worker.EARLY_DIR).exists()
    pngs = sorted(p.name for p in here.iterdir() if p.suffix == ".png")
    assert len(pngs) == 7 and pngs == sorted(p.name for p in out.iterdir() if p.suffix == ".png")
    for f in pngs:
        assert (out / f).read_bytes() == (here / f).read_bytes(), f


def test_calibrate_keeps_the_figures_drawn_from_the_refinements_solution(tmp_path, monkeypatch):
    """calibrate_to_dir has the worker draw the figures that need only the refined solution when the refinement's solve
    ends; on the sample the result's solution is that one, so they are kept."""
    from realdata import SAMPLE

    if not SAMPLE.exists():
        pytest.skip("the sample recording is not in this checkout")
    jobs = []
    frame = figure_worker._frame
    monkeypatch.setattr(figure_worker, "_frame", lambda job: jobs.append(job) or frame(job))
    calibrate_to_dir(SAMPLE, tmp_path / "c", CalibrationOptions.build(board="acircles_4x11_a2"), figure_worker=True)
    assert [j[2] for j in jobs] == [figure_worker.EARLY, figure_worker.SPECULATIVE, (3,)]
    assert len(jobs[2][4]) == 2


def test_the_worker_draws_with_the_callers_plsgraph_whatever_the_working_folder_holds(sim_run, tmp_path, monkeypatch):
    """A plsgraph folder in the working folder (another checkout, run from its root) is not what the worker imports:
    ``python -c`` would put it first on the path."""
    _, result = sim_run
    other = tmp_path / "checkout"
    (other / "plsgraph" / "report").mkdir(parents=True)
    (other / "plsgraph" / "__init__.py").write_text("raise ImportError('the wrong plsgraph')\n")
    monkeypatch.chdir(other)
    out = prepare_output_dir(tmp_path / "calib")
    with FigureWorker.start() as worker:
        worker.send(out, result.run)
        drawn = worker.result()
    assert drawn is not None and len(drawn[0]) >= 5 and not drawn[1]


def test_the_event_frames_come_from_the_front_end_without_reading_the_recording_again(sample_result, tmp_path,
                                                                                      monkeypatch):
    """The streaming front end keeps the count images of a few detections' windows (each span's first and last among
    them, at most EVENT_FRAMES_KEPT): the recording's events in those windows, as a second pass would count them. The
    event frames figure draws from them, the first and the last detection among its tiles."""
    from plsgraph.frontend.track import EVENT_FRAMES_KEPT
    from plsgraph.report import coverage
    from plsgraph.report.figures import figure_inputs

    run = sample_result.run
    kept = run.event_frames
    assert kept and len(kept) <= EVENT_FRAMES_KEPT and "event_frames" not in run.camera_track.info
    half = int(run.camera_track.info["window_s"] * 0.5e9)
    decoded = coverage._window_counts(run.log_path, [(m - half, m + half) for m, _ in kept])
    for (_, img), ref in zip(kept, decoded, strict=True):
        np.testing.assert_array_equal(img, ref)
    det = run.camera_track.detections
    mids = {m for m, _ in kept}
    shift = run.clock_offset_s
    assert {int(round((float(det.t[i]) - shift) * 1e9)) for i in (0, len(det) - 1)} <= mids

    def no_second_pass(*args, **kw):
        raise AssertionError("the recording was read again")

    monkeypatch.setattr(coverage, "_window_counts", no_second_pass)
    assert coverage.fig_event_frames(figure_inputs(run), tmp_path) == "event_frames.png"


def test_the_kept_event_frames_spread_evenly_over_a_long_recording():
    """However many spans, the front end keeps at most EVENT_FRAMES_KEPT frames, the first and the last among them,
    evenly spread (an earlier thinning halved the old frames again at every span and kept mostly the last few)."""
    from plsgraph.frontend.track import EVENT_FRAMES_KEPT, _FrameSample

    for total in (3, 24, 25, 100, 481, 5000):
        sample = _FrameSample(EVENT_FRAMES_KEPT)
        for k in range(total):
            sample.add((k, None))
        kept = [k for k, _ in sample.frames()]
        assert kept[0] == 0 and kept[-1] == total - 1 and len(kept) <= EVENT_FRAMES_KEPT
        assert len(kept) >= min(total, EVENT_FRAMES_KEPT // 2)
        gaps = np.diff(kept[:-1])  # the last one is kept besides the even sample
        assert gaps.size == 0 or gaps.min() == gaps.max()


def test_event_frames_far_from_the_kept_windows_are_read_from_the_recording(sample_result, tmp_path, monkeypatch):
    """Where the front end kept no window near a pick (a track cut at a gap keeps only part of the recording), that
    pick's window is read from the recording: the figure still has its three tiles."""
    from plsgraph.report import coverage
    from plsgraph.report.figures import figure_inputs

    inputs = figure_inputs(sample_result.run)
    inputs.event_frames = inputs.event_frames[:1]  # only the first detection's window
    read = []
    counts = coverage._window_counts
    monkeypatch.setattr(coverage, "_window_counts", lambda path, windows: read.append(windows) or counts(path, windows))
    assert coverage.fig_event_frames(inputs, tmp_path) == "event_frames.png"
    assert len(read) == 1 and len(read[0]) == 2  # the middle and the last
    import cv2

    img = cv2.imread(str(tmp_path / "event_frames.png"))
    assert img.shape[1] == 3 * 2 * sample_result.run.camera.width + 2 * 6  # three tiles, twice the sensor's width


def test_stopping_the_worker_stops_its_fork_too(tmp_path):
    """The worker draws a job's figures in two processes (it forks); stopped (the calibration gave up on it), both
    end, so nothing goes on writing into the run's folder. A stand-in worker that forks and sleeps shows it."""
    import subprocess
    import sys

    if not Path("/proc/self/stat").exists() or not hasattr(os, "fork"):
        pytest.skip("reads the processes from /proc")
    worker = FigureWorker()
    worker.proc = subprocess.Popen([sys.executable, "-c", "import os, time; os.fork(); time.sleep(60)"],
                                   stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True)
    pgid = worker.proc.pid
    deadline = time.monotonic() + 10
    while len(_group_members(pgid)) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(_group_members(pgid)) == 2  # the worker and its fork
    worker.close()
    deadline = time.monotonic() + 5
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not _group_members(pgid)


def _group_members(pgid: int) -> list[int]:
    """Processes of the process group ``pgid`` that are not zombies (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append(int(d.name))
    return out


def test_early_figures_of_a_worker_that_died_are_removed(sample_result, tmp_path):
    out = prepare_output_dir(tmp_path / "calib")
    worker = FigureWorker.start()
    worker.early(out, sample_result.run)
    early = out / figure_worker.EARLY_DIR / "event_frames.png"
    deadline = time.monotonic() + 60
    while not early.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert early.exists()  # drawn before the final job
    worker.proc.kill()  # dies before the final job
    worker.proc.wait()
    write_calibration(out, sample_result, worker)  # drawn in this process instead
    assert not (out / figure_worker.EARLY_DIR).exists() and worker.proc is None
    for f in (*FIGURE_FILES, "event_frames.png", "coverage.png"):
        assert (out / f).stat().st_size > 1000


def test_a_worker_that_died_costs_no_figure(sim_run, tmp_path):
    _, result = sim_run
    out = prepare_output_dir(tmp_path / "calib")
    worker = FigureWorker.start()
    worker.proc.kill()
    worker.proc.wait()
    write_calibration(out, result, worker)  # drawn in this process instead
    for f in FIGURE_FILES:
        assert (out / f).stat().st_size > 1000
    worker = FigureWorker.start()
    worker.send(out, result.run)
    worker.proc.kill()  # dies before it answers
    assert worker.result() is None and worker.proc is None


def test_the_worker_is_used_only_when_a_processor_is_free(monkeypatch):
    monkeypatch.setattr(figure_worker.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    # What the processors do now decides: idle processors over a short look.
    for idle, free in ((2.0, True), (1.85, True), (1.5, False), (0.2, False)):
        monkeypatch.setattr(figure_worker, "idle_processors", lambda cpus, idle=idle, **kw: idle)
        monkeypatch.setattr(figure_worker.os, "getloadavg", lambda: (3.0, 3.0, 3.0))  # a minute of ended work
        assert figure_worker.processor_free() is free
    # Where that cannot be seen, the load average.
    monkeypatch.setattr(figure_worker, "idle_processors", lambda cpus, **kw: None)
    for load, free in ((0.3, True), (0.9, True), (1.2, False), (3.0, False)):
        monkeypatch.setattr(figure_worker.os, "getloadavg", lambda load=load: (load, load, load))
        assert figure_worker.processor_free() is free
    # The processor time of this process (its numerical libraries' threads, which spin on after a call) is the
    # calibration's, not another's: it counts as idle.
    monkeypatch.setattr(figure_worker, "idle_processors", lambda cpus, own=False, **kw: 2.0 if own else 1.6)
    assert figure_worker.processor_free() is True
    monkeypatch.setattr(figure_worker.os, "sched_getaffinity", lambda pid: {0})
    monkeypatch.setattr(figure_worker.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert not figure_worker.processor_free()  # one processor: the calibration has it


def _fake_proc_stat(monkeypatch, texts) -> None:
    """open() gives the next of ``texts`` to read (as /proc/stat)."""

    class Stat:
        def __init__(self, *a, **k):
            self.text = next(texts)

        def __enter__(self):
            return self

        def __exit__(self, *a):
            return False

        def read(self):
            return self.text

    monkeypatch.setattr("builtins.open", Stat)


def test_idle_processors_are_read_from_the_kernel_counters(monkeypatch):
    stats = iter([
        "cpu  10 0 10 100 0 0 0 0 0 0\ncpu0 5 0 5 50 0 0 0 0 0 0\ncpu1 5 0 5 50 0 0 0 0 0 0\ncpu2 0 0 0 0 0 0 0 0 0 0",
        # over the look: cpu0 busy 40 of 100 jiffies (idle 50 + iowait 10), cpu1 idle throughout, cpu2 not ours
        "cpu  0 0 0 0 0 0 0 0 0 0\ncpu0 35 0 15 100 10 0 0 0 0 0\ncpu1 5 0 5 150 0 0 0 0 0 0\n"
        "cpu2 90 0 0 0 0 0 0 0 0 0",
    ])
    _fake_proc_stat(monkeypatch, stats)
    assert figure_worker.idle_processors({0, 1}, sample_s=0.0) == pytest.approx(2 * 160 / 200)
    _fake_proc_stat(monkeypatch, iter(["cpu0 5 0 5\ncpu1 5 0 5 50 0 0 0 0 0 0"]))  # too short to hold the idle count
    assert figure_worker.idle_processors({0, 1}, sample_s=0.0) is None  # then the load average decides
    if Path("/proc/stat").exists():
        monkeypatch.undo()
        idle = figure_worker.idle_processors(set(os.sched_getaffinity(0)))
        assert idle is not None and 0.0 <= idle <= len(os.sched_getaffinity(0)) + 1e-9


def test_a_look_ahead_is_taken_by_the_next_question_and_counts_this_process_as_idle(monkeypatch):
    """``plsgraph calibrate`` looks at the processors in a thread while it imports: the next processor_free() takes
    that look (once), and the processor time this process took meanwhile counts as idle (it is the calibration's)."""
    import threading
    import time

    answers = iter([True, False, False])  # the look ahead's, then each look of processor_free's own
    monkeypatch.setattr(figure_worker, "_processor_free", lambda: next(answers))
    figure_worker.look_ahead()
    assert figure_worker.processor_free() is True
    assert figure_worker.processor_free() is False  # taken once; then a look of its own
    done = threading.Thread(target=lambda: None)
    done.start()
    done.join()
    figure_worker._LOOK["look"] = {"started": time.monotonic() - 60.0, "result": True, "thread": done}
    assert figure_worker.processor_free() is False  # a look from long ago is not used
    monkeypatch.undo()
    stats = iter(["cpu0 0 0 0 100 0 0 0 0\ncpu1 0 0 0 100 0 0 0 0",
                  "cpu0 40 0 0 160 0 0 0 0\ncpu1 10 0 0 190 0 0 0 0"])  # 0.5 of 2 processors busy
    clock = iter([10.0, 10.04])  # this process: 0.04 s of processor time over the look's 0.1 s
    wall = iter([5.0, 5.1])
    _fake_proc_stat(monkeypatch, stats)
    monkeypatch.setattr(time, "process_time", lambda: next(clock))
    monkeypatch.setattr(time, "monotonic", lambda: next(wall))
    assert figure_worker.idle_processors({0, 1}, sample_s=0.0, own=True) == pytest.approx(1.5 + 0.4)


def test_a_worker_without_a_job_just_ends(tmp_path):
    worker = FigureWorker.start()
    proc = worker.proc
    worker.close()
    assert proc.returncode is not None and worker.result() is None


def test_options_reject_nonsense():
    with pytest.raises(InputError):
        OdometryOptions(wheel_radius=-1.0)
    with pytest.raises(InputError):
        FrontendOptions(rate_hz=float("nan"))
    with pytest.raises(InputError, match="unknown calibration option"):
        CalibrationOptions.build(wheel_radus=0.1)
    opts = CalibrationOptions.build(board="b", wheel_radius=0.1, surface="polarity", camera_height=0.3)
    assert (opts.odometry.wheel_radius, opts.frontend.surface, opts.refine.camera_height) == (0.1, "polarity", 0.3)


@pytest.mark.parametrize("setting, match", [
    # Before: each was used as given, and the run ended with advice about the driving, or exit 0 with z = -5 m.
    ({"camera_height": -5.0}, r"camera_height \(--camera-height\) -5 m is outside -1 .. 3 m"),
    ({"camera_height": 25.0}, "lengths are in metres"),
    ({"board_height": -0.2}, r"board_height \(--board-height\) -0.2 m"),
    ({"wheel_radius": 1e-9}, "wheel radius"),
    ({"wheel_radius": 98.0}, "wheel radius"),
    ({"track_width": 37.0}, "track width"),
    ({"left_joint": "front_left_wheel_joint", "right_joint": "front_left_wheel_joint"}, "name the same joint"),
    ({"rate_hz": 0.5}, "below 5 Hz: windows of 2 s"),
])
def test_lengths_no_ground_robot_has_and_one_joint_for_both_wheels_are_refused(setting, match):
    with pytest.raises(InputError, match=match):
        CalibrationOptions.build(board="b", **setting)
    CalibrationOptions.build(board="b", camera_height=-0.2, board_height=0.0, wheel_radius=0.3, track_width=1.2)


def test_the_summary_of_a_flagged_result_says_so_before_any_number(sim_run):
    """Before: the terminal summary of a flagged result opened with T_base_cam and rpy and named the problems only
    on line 33, never saying 'flagged'."""
    _, result = sim_run
    report = result.to_dict()
    assert report["ok"] and "FLAGGED" not in calibration_text(report)
    # No height given: z is written as 0 and has no error against the truth (before: one of the unwritten seed's).
    assert "refined.t_z_err_m" not in report["truth_errors"] and "refined.t_xy_err_m" in report["truth_errors"]
    flagged = {**report, "ok": False, "problems": ["yaw disagrees with the closed form by 4.1 sigma"]}
    lines = calibration_text(flagged).splitlines()
    assert lines[0].startswith("FLAGGED: do not use this calibration (1 problem(s)")
    assert lines.index("PROBLEMS (the calibration is flagged: do not use it):") > 0


def test_a_flagged_result_keeps_the_calibration_it_replaces_and_a_failed_copy_costs_only_the_copy(
        sim_run, tmp_path, monkeypatch):
    # Before: --force with a recording whose result came out flagged replaced a good calibration without a trace.
    import copy
    import dataclasses
    import shutil

    from plsgraph.report import output
    from plsgraph.report.output import write_result_folder

    _, result = sim_run
    report = copy.deepcopy(result.report)
    report["ok"], report["problems"] = False, ["a problem made up for the test"]
    report["calibration"] = dict(report["calibration"], ok=False, problems=report["problems"])
    flagged = dataclasses.replace(result, ok=False, problems=tuple(report["problems"]), report=report)
    out = tmp_path / "calib"
    write_result_folder(out, lambda stage: (write_calibration(stage, result), {"ok": True, "text": ""})[1])
    good = (out / "calibration.yaml").read_text()
    write_result_folder(out, lambda stage: (write_calibration(stage, flagged, earlier=out),
                                            {"ok": False, "text": ""})[1])
    assert yaml.safe_load((out / "calibration.yaml").read_text())["ok"] is False
    assert (out / "previous_calibration" / "calibration.yaml").read_text() == good
    assert json.loads((out / "report.json").read_text())["previous_calibration"] == "previous_calibration"
    assert "href='previous_calibration/report.html'" in (out / "report.html").read_text()
    # Flagged again: the good one stays kept (preferred over the flagged one the folder now holds).
    write_result_folder(out, lambda stage: (write_calibration(stage, flagged, earlier=out),
                                            {"ok": False, "text": ""})[1])
    assert (out / "previous_calibration" / "calibration.yaml").read_text() == good
    # A nearly full disk (a review: the earlier calibration was lost when it could not be copied): the kept files
    # are hard links, which need no room.
    def full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shutil, "copy2", full)
    write_result_folder(out, lambda stage: (write_calibration(stage, flagged, earlier=out),
                                            {"ok": False, "text": ""})[1])
    assert (out / "previous_calibration" / "calibration.yaml").read_text() == good
    # Where neither a link nor a copy can be made, the new result is whole, without the kept one.
    def refuse(*a, **k):
        raise PermissionError("not readable")

    monkeypatch.setattr(shutil, "copy2", refuse)
    monkeypatch.setattr(output.os, "link", refuse)
    write_result_folder(out, lambda stage: (write_calibration(stage, flagged, earlier=out),
                                            {"ok": False, "text": ""})[1])
    assert not (out / "previous_calibration").exists() and (out / "report.json").exists()
    assert "previous_calibration" not in json.loads((out / "report.json").read_text())
    assert output.PREVIOUS_CALIBRATION == "previous_calibration"


def test_motion_advice_names_what_the_motion_left_undetermined():
    """Before: a straight drive (roll undetermined, yaw determined) was told it left the yaw undetermined, a spin in
    place got the same straight-driving advice, and a board of the wrong size got advice on the camera height only."""
    from types import SimpleNamespace

    from plsgraph.api import motion_advice

    def obs(**o):
        full = {"roll": True, "pitch": True, "yaw": True, "x": True, "y": True, "z": False, "td": True}
        return SimpleNamespace(observable={**full, **o})

    z = [{"name": "z", "status": "unobservable"}]
    straight = " ".join(motion_advice(obs(roll=False, x=False, y=False), z))
    assert "roll" in straight and "yaw" not in straight and "driving straight" in straight
    spin = " ".join(motion_advice(obs(yaw=False, x=False, y=False), z))
    assert "turning in place" in spin and "yaw" in spin and "straight" not in spin
    scale = motion_advice(obs(), z, ["the camera and the wheel odometry disagree on distances by x0.518 (...)"])
    assert any("board's size" in a for a in scale) and not any("turn" in a for a in scale)
    assert motion_advice(obs(), []) == []


def test_an_event_frames_picture_that_cannot_be_written_is_a_failed_figure_not_a_silent_gap(sample_result, tmp_path,
                                                                                           monkeypatch):
    """A review: on a full disk OpenCV's write failed (its return value unread), the run ended ok and report.html showed
    a broken image with no warning."""
    import cv2

    from plsgraph.report import coverage
    from plsgraph.report.figures import figure_inputs

    monkeypatch.setattr(cv2, "imwrite", lambda *a, **k: False)
    with pytest.raises(OSError, match="event_frames.png could not be written"):
        coverage.fig_event_frames(figure_inputs(sample_result.run), tmp_path)
    assert not (tmp_path / "event_frames.png").exists()
