"""Intrinsics files: plsgraph / ROS YAML, OpenCV FileStorage YAML and Kalibr camchains, written in the test."""

from __future__ import annotations

import re

import numpy as np
import pytest

from plsgraph.core.camera import CameraModel
from plsgraph.errors import InputError
from plsgraph.io.camera_files import load_camera_file, read_camera_file, split_camera_choice

K = np.array([[321.5, 0.0, 170.25], [0.0, 322.0, 131.5], [0.0, 0.0, 1.0]])
D = np.array([-0.11, 0.05, 0.001, -0.0004, 0.002])

CHAIN = """\
cam0:
  camera_model: pinhole
  intrinsics: [500.0, 501.0, 320.0, 240.0]
  distortion_model: radtan
  distortion_coeffs: [-0.2, 0.03, 0.001, 0.002]
  resolution: [640, 480]
  rostopic: /rgb/image_raw
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, 0.1]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  intrinsics: [321.5, 322.0, 170.25, 131.5]
  distortion_model: radtan
  distortion_coeffs: [-0.11, 0.05, 0.001, -0.0004]
  resolution: [346, 260]
  rostopic: /dvs/image_raw
"""


def _opencv_file(path, dist=D, drop=None):
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fields = {"image_width": 346, "image_height": 260, "camera_matrix": K, "distortion_coefficients": dist[None, :]}
    for k, v in fields.items():
        if k != drop:
            fs.write(k, v)
    fs.release()
    return path


def test_opencv_filestorage(tmp_path):
    p = _opencv_file(tmp_path / "cam.yaml")
    assert p.read_text().startswith("%YAML:1.0")
    f = read_camera_file(p)
    assert f.format == "opencv" and (f.camera.width, f.camera.height) == (346, 260)
    np.testing.assert_allclose(f.camera.K, K)
    np.testing.assert_allclose(f.camera.dist, D)
    # 8 coefficients (rational model) with zero extras are plumb_bob; non-zero extras are refused.
    p8 = _opencv_file(tmp_path / "cam8.yaml", np.r_[D, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(load_camera_file(p8).dist, D)
    p8b = _opencv_file(tmp_path / "cam8b.yaml", np.r_[D, 0.1, 0.0, 0.0])
    with pytest.raises(InputError, match="distortion_coefficients.*plumb_bob"):
        load_camera_file(p8b)
    # plsgraph's own YAML reader (bundled presets) refuses it with a clear error rather than misreading it.
    with pytest.raises(InputError):
        CameraModel.from_yaml(p)


@pytest.mark.parametrize("field", ["camera_matrix", "distortion_coefficients", "image_width", "image_height"])
def test_opencv_missing_field_is_named(tmp_path, field):
    p = _opencv_file(tmp_path / "cam.yaml", drop=field)
    with pytest.raises(InputError, match=f"{p}.*'{field}' is missing"):
        load_camera_file(p)


def test_ros_and_plsgraph_yaml(tmp_path):
    ros = tmp_path / "ros.yaml"
    ros.write_text(
        "image_width: 346\nimage_height: 260\ncamera_name: dvs\n"
        f"camera_matrix: {{rows: 3, cols: 3, data: {K.ravel().tolist()}}}\n"
        "distortion_model: plumb_bob\n"
        f"distortion_coefficients: {{rows: 1, cols: 5, data: {D.tolist()}}}\n"
    )
    f = read_camera_file(ros)
    assert f.format == "ros"
    np.testing.assert_allclose(f.camera.dist, D)
    # A distortion line cut short (before: padded with zeros, a wrong camera taken as right).
    for data in ([float(D[0])], [], D[:3].tolist()):
        ros.write_text(ros.read_text().rsplit("distortion_coefficients", 1)[0]
                       + f"distortion_coefficients: {{rows: 1, cols: 5, data: {data}}}\n")
        with pytest.raises(InputError, match=rf"has {len(data)} numbers where rows x cols say 5"):
            read_camera_file(ros)
    own = tmp_path / "own.yaml"
    own.write_text(f"width: 346\nheight: 260\nK: {K.tolist()}\nD: {D.tolist()}\n")
    assert read_camera_file(own).format == "plsgraph"
    np.testing.assert_allclose(load_camera_file(own).K, K)
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"width: 346\nK: {K.tolist()}\nD: []\n")
    with pytest.raises(InputError, match=f"{bad}.*'height' is missing"):
        load_camera_file(bad)
    bad.write_text("width: 346\nheight: 260\nK: [1, 2, 3]\nD: []\n")
    with pytest.raises(InputError, match="'K' must have 9 numbers, got 3"):
        load_camera_file(bad)
    # A principal point at (0, 0) or outside the image, a last row that is not [0, 0, 1]: refused (before: taken, and
    # the run ended blaming the clocks).
    for Kb, words in ((np.array([[255.0, 0, 0], [0, 255.0, 0], [0, 0, 1]]), "principal point (0, 0)"),
                      (np.array([[255.0, 0, 400], [0, 255.0, 130], [0, 0, 1]]), "principal point (400, 130)"),
                      (np.array([[255.0, 0, 173], [0, 255.0, 130], [0, 0, 0]]), "last row")):
        bad.write_text(f"width: 346\nheight: 260\nK: {Kb.tolist()}\nD: []\n")
        with pytest.raises(InputError, match=re.escape(words)):
            load_camera_file(bad)
    bad.write_text(f"width: 346\nheight: 260\nK: {K.tolist()}\nD: []\ndistortion_model: equidistant\n")
    with pytest.raises(InputError, match="distortion_model.*equidistant"):
        load_camera_file(bad)


def test_kalibr_choice_by_topic_name_and_default(tmp_path, caplog):
    p = tmp_path / "camchain.yaml"
    p.write_text(CHAIN)
    # The events topic shares the namespace of cam1's image topic.
    f = read_camera_file(p, events_topic="/dvs/events")
    assert (f.format, f.name, f.warnings) == ("kalibr", "cam1", ())
    np.testing.assert_allclose(f.camera.K, K)
    np.testing.assert_allclose(f.camera.dist, np.r_[D[:4], 0.0])
    assert (f.camera.width, f.camera.height) == (346, 260)
    # Exact topic match.
    assert read_camera_file(p, events_topic="/rgb/image_raw").name == "cam0"
    # Explicit choice: FILE:camN (or FILE:N) wins over the topic; when another camera's topic is the events', a
    # warning says so (a review: cam0 of a stereo partner chosen by mistake passed with y 3.5 sigma off).
    other = read_camera_file(f"{p}:cam0", events_topic="/dvs/events")
    assert other.name == "cam0"
    (said,) = other.warnings
    assert "cam0 was chosen, but its rostopic /rgb/image_raw" in said and "cam1's (/dvs/image_raw) is" in said
    assert read_camera_file(f"{p}:cam1", events_topic="/dvs/events").warnings == ()
    assert read_camera_file(f"{p}:cam0", events_topic="/prophesee/events").warnings == ()  # nothing matches
    assert read_camera_file(f"{p}:1").name == "cam1"
    assert split_camera_choice(f"{p}:cam1") == (p, "cam1")
    with pytest.raises(InputError, match="no camera 'cam7'.*cam0, cam1"):
        read_camera_file(f"{p}:cam7")
    # Nothing to match: refused, naming the cameras and the way to choose (before: cam0 with a warning, which gave a
    # confident wrong answer where cam0 was another camera: the lever arm 10 cm off against a 1 cm sigma).
    for topic in ("/prophesee/events", None):
        with pytest.raises(InputError, match=r"2 cameras: cam0 \(/rgb/image_raw\), cam1 \(/dvs/image_raw\).*:camN"):
            read_camera_file(p, events_topic=topic)
    # A malformed choice names the file that exists and the form of a choice (before: "does not exist").
    for bad in (":cam", ":", ":CAM1", ":-1", ":cam1:cam0"):
        with pytest.raises(InputError, match=r"is not a camera of a Kalibr camchain; choose one as"):
            read_camera_file(f"{p}{bad}")
    # A single camera is taken whatever the topic.
    single = tmp_path / "single.yaml"
    single.write_text(CHAIN.split("cam1:")[0])
    f = read_camera_file(single, events_topic="/dvs/events")
    assert f.name == "cam0" and f.warnings == ()


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (("distortion_model: radtan", "distortion_model: equidistant"), "cam1.distortion_model.*equidistant.*fisheye"),
        (("camera_model: pinhole", "camera_model: omni"), "cam1.camera_model.*omni"),
        (("  intrinsics: [321.5, 322.0, 170.25, 131.5]\n", ""), "cam1.intrinsics' is missing"),
        (("[321.5, 322.0, 170.25, 131.5]", "[321.5, 322.0, 170.25]"), "cam1.intrinsics' must have 4 numbers"),
        (("  resolution: [346, 260]\n", ""), "cam1.resolution' is missing"),
        (("[346, 260]", "[346]"), r"cam1.resolution' must be \[width, height\]"),
        (("[-0.11, 0.05, 0.001, -0.0004]", "[-0.11, 0.05]"), "cam1.distortion_coeffs' must have 4 numbers"),
        (("[321.5, 322.0", "[-321.5, 322.0"), "focal lengths must be positive"),
    ],
)
def test_kalibr_bad_fields_name_field_and_file(tmp_path, edit, match):
    p = tmp_path / "camchain.yaml"
    # cam1 only gets the damage: the error must name cam1's field, not cam0's.
    head, tail = CHAIN.split("cam1:")
    p.write_text(head + "cam1:" + tail.replace(*edit))
    with pytest.raises(InputError, match=match) as info:
        read_camera_file(f"{p}:cam1")
    assert str(p) in str(info.value)


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_camera_file(tmp_path / "nope.yaml")
    p = tmp_path / "broken.yaml"
    p.write_text("{broken: [\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_camera_file(p)
    p.write_text("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n")
    with pytest.raises(InputError, match=str(p)):
        load_camera_file(p)


def test_pipeline_picks_the_camchain_camera_of_the_events_topic(tmp_path):
    """read_inputs matches a camchain camera to the recording's events topic (here /dvs/events -> cam1)."""
    from plsgraph.core.events import EventStream
    from plsgraph.io import JointStates, write_recording
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, read_inputs

    rng = np.random.default_rng(0)
    t = 10**18 + np.arange(200) * 1_000_000
    ev = EventStream.from_arrays(t, rng.integers(0, 346, 200), rng.integers(0, 260, 200), rng.random(200) < 0.5,
                                 346, 260)
    js = JointStates(t[::10], ("left_wheel", "right_wheel"), np.zeros((20, 2)), np.zeros((20, 2)))
    rec_path = tmp_path / "r.mcap"
    write_recording(rec_path, ev, js, None, None)
    chain = tmp_path / "camchain.yaml"
    chain.write_text(CHAIN)
    run = Run(rec_path, CalibrationOptions.build(camera_info=chain))
    read_inputs(run)
    np.testing.assert_allclose(run.camera.K, K)
    assert run.warnings == [] or all("cam0 is used" not in w for w in run.warnings)
    run = Run(rec_path, CalibrationOptions.build(camera_info=f"{chain}:cam0"))
    read_inputs(run)
    assert run.camera.width == 640


def test_intrinsics_given_that_differ_from_the_recordings_camera_info_are_used_and_warned_of():
    # Before: --camera-info silently replaced the recording's CameraInfo even where the two differed by 5 %.
    from plsgraph.core.camera import CameraModel
    from plsgraph.pipeline import camera_disagreement

    rec = CameraModel(346, 260, K, D)
    assert camera_disagreement(rec, CameraModel(346, 260, K, D), "f.yaml") == []
    K5 = K.copy()
    K5[0, 0] *= 1.05
    (w,) = camera_disagreement(rec, CameraModel(346, 260, K5, D), "f.yaml")
    assert "differ from the recording's CameraInfo" in w and "by up to 5 %" in w and "f.yaml is used" in w
    K6 = K.copy()
    K6[0, 2], K6[1, 2] = 320.0, 240.0
    (w,) = camera_disagreement(rec, CameraModel(640, 480, K6, D), "f.yaml")
    assert "640 x 480" in w and "346 x 260" in w


def test_intrinsics_without_distortion_are_said():
    """A red-team recording whose CameraInfo lacked the lens's distortion (k1 -0.06) came out with the lever arm 20 cm
    off, exit 0, at a reprojection RMS of 0.23 px. Rectified events have no distortion, so it is a warning."""
    import numpy as np

    from plsgraph.core.camera import CameraModel, davis346_default
    from plsgraph.pipeline import no_distortion_warning

    cam = davis346_default()
    assert no_distortion_warning(cam) == []
    (msg,) = no_distortion_warning(CameraModel(cam.width, cam.height, cam.K, np.zeros(5)))
    assert "no lens distortion" in msg and "--camera-info" in msg and "rectified" in msg
    assert no_distortion_warning(None) == []
