"""End to end: events in one file, wheel joints in another on a clock 3725.4 s ahead; the robot files and the
HTML report that come out (one calibration of the bundled sample, ~10 s)."""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from plsgraph.api import calibrate_to_dir
from plsgraph.core.geometry import rotation_error_deg
from plsgraph.options import CalibrationOptions
from plsgraph.report.robot_files import launch_text, urdf_text

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sample" / "rich_sample.mcap"
DIFF = 3725.4


class _Images(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.headings: list[str] = []
        self._in_h2 = False

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.images.append(dict(attrs)["src"])
        self._in_h2 = tag == "h2"

    def handle_data(self, data):
        if self._in_h2:
            self.headings.append(data)
            self._in_h2 = False


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    if not SAMPLE.exists():
        pytest.skip("bundled sample missing")
    sys.path.insert(0, str(ROOT / "scripts"))
    from make_two_clock_pair import main as split

    out = tmp_path_factory.mktemp("pair")
    assert split([str(SAMPLE), "--out", str(out), "--clock-difference", str(DIFF)]) == 0
    return out


@pytest.fixture(scope="module")
def calibrated(pair, tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "cal"
    opts = CalibrationOptions.build(board="acircles_4x11_a2", odometry_file=pair / "odometry.mcap",
                                    truth=pair / "events.truth.yaml", child_frame="dvxplorer")
    summary = calibrate_to_dir(pair / "events.mcap", out, opts)
    return out, summary


def test_two_files_recover_the_clock_difference(pair, calibrated):
    out, summary = calibrated
    truth = yaml.safe_load((pair / "events.truth.yaml").read_text())
    assert summary["ok"], summary["report"]["problems"]
    c = yaml.safe_load((out / "calibration.yaml").read_text())
    # 3725.4 s recovered to within the result's own time-offset sigma (6.4 ms here, which holds the event sensor's
    # latency: docs/refinement.md). The error has been 0.4-3.6 ms as the front end's detections changed; one sigma
    # guards this recording against a change that moves it further.
    sigma = {o["name"]: o["sigma"] for o in c["observability"]}
    assert sigma["td"] < 10.0  # ms
    assert c["time_offset_s"] == pytest.approx(truth["td"], abs=1e-3 * sigma["td"])
    assert c["clock_alignment"]["coarse"] and c["clock_alignment"]["offset_s"] == pytest.approx(truth["td"], abs=0.03)
    # The rotation within three times its sigma (0.5-0.6 degrees, mostly yaw, on this 10 s sample), and below a degree.
    rot_sigma = float(np.linalg.norm([sigma["roll"], sigma["pitch"], sigma["yaw"]]))
    rot_err = rotation_error_deg(np.asarray(c["T_base_cam"])[:3, :3], np.asarray(truth["T_base_cam"])[:3, :3])
    assert rot_err < min(3 * rot_sigma, 1.0)
    assert c["wheel_order"]["hypothesis"] == "as_given"
    assert c["child_frame"] == "dvxplorer" and "--child-frame-id dvxplorer" in c["ros_static_transform"]
    assert "odometry.mcap" in summary["report"]["recording_info"]["odometry_file"]
    assert "the clocks differ" in summary["text"]


def test_diagnose_says_how_the_clocks_were_aligned(pair, calibrated):
    # A review: diagnose of a two-clock pair said "good enough" with nothing on the coarse alignment it relied on.
    from plsgraph.api import diagnose
    from plsgraph.report.text import diagnosis_text

    out, summary = calibrated
    d = diagnose(pair / "events.mcap", board="acircles_4x11_a2", odometry_file=pair / "odometry.mcap")
    c = yaml.safe_load((out / "calibration.yaml").read_text())["clock_alignment"]
    assert d.clock_alignment["coarse"] and d.clock_alignment["offset_s"] == pytest.approx(c["offset_s"], abs=1e-6)
    assert "clocks: coarse alignment 3725" in diagnosis_text(d)
    assert d.to_dict()["clock_alignment"]["score"] == pytest.approx(c["score"])


def test_robot_files_carry_the_result(calibrated):
    out, _ = calibrated
    c = yaml.safe_load((out / "calibration.yaml").read_text())
    root = ET.parse(out / "base_to_camera.urdf").getroot()
    joint = root.find("joint")
    assert joint.find("parent").get("link") == "base_link" and joint.find("child").get("link") == "dvxplorer"
    origin = joint.find("origin")
    xyz = [float(v) for v in origin.get("xyz").split()]
    rpy = [float(v) for v in origin.get("rpy").split()]
    T = np.asarray(c["T_base_cam"])
    np.testing.assert_allclose(xyz[:2], T[:2, 3], atol=1e-6)
    assert xyz[2] == 0.0  # not measured: written as 0 ...
    assert "NOT measured" in (out / "base_to_camera.urdf").read_text()  # ... with a comment saying so
    np.testing.assert_allclose(Rotation.from_euler("xyz", rpy).as_matrix(), T[:3, :3], atol=1e-8)
    launch = (out / "static_tf.launch.py").read_text()
    tree = ast.parse(launch)
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    for flag in ("--x", "--roll", "--frame-id", "--child-frame-id", "dvxplorer", "static_transform_publisher"):
        assert flag in launch


def test_flagged_result_gets_no_usable_robot_files():
    T = np.eye(4)
    urdf = urdf_text(T, "base_link", "cam", ok=False, problems=("the wheels -- swapped",))
    root = ET.fromstring(urdf.split("\n", 1)[1])  # well-formed XML ...
    assert root.find("joint") is None  # ... without a joint
    assert "NO USABLE CALIBRATION" in urdf and "swapped" in urdf
    launch = launch_text(T, "base_link", "cam", ok=False, problems=("the wheels are swapped",))
    assert all(line.startswith("#") or not line.strip() for line in launch.splitlines())


def test_report_html_puts_the_result_first_and_every_image_exists(calibrated):
    out, _ = calibrated
    p = _Images()
    p.feed((out / "report.html").read_text())
    assert p.images, "the report shows no figures"
    for src in p.images:
        assert (out / src).is_file(), f"report.html references a missing image {src}"
    assert p.headings[0] == "Result" and p.headings.index("Figures") < p.headings.index("Observability")
    page = (out / "report.html").read_text()
    assert "± " in page
    # Before: the page named neither the odometry file nor the clock step, which the terminal and report.json gave.
    assert "odometry read from" in page and "odometry.mcap" in page and "clocks aligned coarsely" in page
    assert "effective wheel radius" in page


def test_a_damaged_odometry_file_is_said_to_be_damaged_not_to_lack_its_topic(pair, tmp_path):
    # Before: "holds neither sensor_msgs/JointState nor nav_msgs/Odometry messages (it has /joint_states
    # (sensor_msgs/msg/JointState), ...)": the topic was listed as there while said to be missing.
    from plsgraph.errors import RecordingError
    from plsgraph.pairing import merge_odometry_file
    from plsgraph.pipeline import Run

    data = bytearray((pair / "odometry.mcap").read_bytes())
    data[200:4296] = bytes(4096)  # the start of its only data chunk overwritten
    bad = tmp_path / "odo_damaged.mcap"
    bad.write_bytes(bytes(data))
    run = Run(pair / "events.mcap", CalibrationOptions.build(board="acircles_4x11_a2", odometry_file=bad))
    from plsgraph.pairing import read_events_file

    with pytest.raises(RecordingError) as e:
        merge_odometry_file(run, read_events_file(run.log_path, None))
    msg = str(e.value)
    assert "damaged" in msg and "holds neither" not in msg, msg


def test_the_recording_given_as_its_own_odometry_file_is_refused_and_a_second_odometry_is_said_to_win(pair):
    # Before: the same file as both ran, saying its odometry came "from another file, so from another clock"; an
    # events file with its own odometry had it ignored without a word.
    from plsgraph.errors import InputError
    from plsgraph.pairing import merge_odometry_file, read_events_file
    from plsgraph.pipeline import Run

    run = Run(SAMPLE, CalibrationOptions.build(board="acircles_4x11_a2", odometry_file=SAMPLE))
    with pytest.raises(InputError, match="names the recording itself"):
        merge_odometry_file(run, read_events_file(run.log_path, None))
    run = Run(SAMPLE, CalibrationOptions.build(board="acircles_4x11_a2", odometry_file=pair / "odometry.mcap"))
    merge_odometry_file(run, read_events_file(run.log_path, None))
    assert any("has wheel odometry of its own; the odometry of odometry.mcap (--odometry) is used instead" in w
               for w in run.warnings), run.warnings


def test_the_two_files_given_the_wrong_way_round_are_told_to_be_swapped(pair):
    # Before: "odometry file events.mcap holds neither sensor_msgs/JointState nor nav_msgs/Odometry ...; name the topic
    # with --joints-topic/--odom-topic", advice that cannot help.
    from plsgraph.errors import InputError
    from plsgraph.pairing import merge_odometry_file, read_events_file
    from plsgraph.pipeline import Run

    run = Run(pair / "odometry.mcap", CalibrationOptions.build(board="acircles_4x11_a2",
                                                               odometry_file=pair / "events.mcap"))
    with pytest.raises(InputError, match=r"wrong way round: the events are in events\.mcap .* odometry\.mcap has none "
                                         r"but has the wheel odometry; swap them"):
        merge_odometry_file(run, read_events_file(run.log_path, None))
    # Events in both files (the recording's own and the second's): not a swap; the second file's lack of odometry is
    # what is said.
    run = Run(SAMPLE, CalibrationOptions.build(board="acircles_4x11_a2", odometry_file=pair / "events.mcap"))
    with pytest.raises(Exception, match="holds neither"):
        merge_odometry_file(run, read_events_file(run.log_path, None))
