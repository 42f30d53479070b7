"""The orchestration tail (closed form -> refinement -> result files) on simulated tracks, no events."""

import json

import numpy as np
import pytest
import yaml

from plsgraph.app import PipelineOptions, build_report, run_from_tracks, summary_text
from plsgraph.errors import InputError
from plsgraph.figures import write_html_report
from plsgraph.geometry import rotation_error_deg
from plsgraph.odometry import base_track_from_wheels
from plsgraph.pose import camera_track_from_detections
from plsgraph.report import prepare_output_dir, write_json, write_yaml
from plsgraph.sim.robot import simulate_robot


@pytest.fixture(scope="module")
def sim_run():
    sim = simulate_robot("rich", duration=12.0, seed=3, td=0.04, slip=0.0, realism="ideal")
    cam_track = camera_track_from_detections(sim.detections(noise_px=0.1, seed=4), sim.camera)
    base = base_track_from_wheels(sim.wheel_t, sim.wheel_left, sim.wheel_right, sim.wheel_radius, sim.track_width)
    truth = {"T_base_cam": sim.T_base_cam.tolist(), "td": sim.td}
    run = run_from_tracks(cam_track, base, sim.camera, PipelineOptions(), truth=truth)
    return sim, run


def test_refined_result_recovers_truth(sim_run):
    sim, run = sim_run
    ref = run.refinement
    assert ref.converged
    # Tolerances: 0.1 px detection noise, no wheel slip; the refinement must beat the closed form.
    assert rotation_error_deg(ref.R_base_cam, sim.R_base_cam) < 0.1
    assert rotation_error_deg(ref.R_base_cam, sim.R_base_cam) < rotation_error_deg(run.closed_form.R_base_cam,
                                                                                    sim.R_base_cam)
    assert np.linalg.norm(ref.T_base_cam[:2, 3] - sim.T_base_cam[:2, 3]) < 0.01
    assert abs(ref.td - sim.td) < 0.003


def test_report_files_are_complete_and_parse(sim_run, tmp_path):
    sim, run = sim_run
    report = build_report(run)
    out = prepare_output_dir(tmp_path / "calib")
    write_yaml(out / "calibration.yaml", report["calibration"])
    write_json(out / "report.json", report)
    write_html_report(out, run, report)
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
    assert "refined" in summary_text(report)


def test_options_reject_nonsense():
    with pytest.raises(InputError):
        PipelineOptions(wheel_radius=-1.0)
    with pytest.raises(InputError):
        PipelineOptions(rate_hz=float("nan"))
