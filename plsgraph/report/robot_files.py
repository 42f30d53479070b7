"""Files a robot uses directly: a URDF joint (``base_to_camera.urdf``) and a ROS 2 launch file
(``static_tf.launch.py``) that publishes ``T_base_cam`` as a static transform.

A flagged result (``ok`` false) gets neither as a usable file: each is written as a comment-only file that says
why, so nothing on a robot can pick up a calibration plsgraph itself does not trust. When the camera height was
not measured (no ``--camera-height`` / ``--board-height``), z is written as 0 with a comment that it must be
measured: planar driving cannot observe it.
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from .files import frames_note, write_text

URDF_NAME = "base_to_camera.urdf"
LAUNCH_NAME = "static_tf.launch.py"


def _pose(T_base_cam: np.ndarray, height_measured: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """xyz (m) and URDF rpy (rad: fixed-axis roll about x, then pitch about y, then yaw about z, R = Rz Ry Rx, the
    convention of URDF and of tf2's --roll/--pitch/--yaw). An unmeasured height is written as exactly 0 (the
    refinement only wanders a few µm around its seed there)."""
    T = np.asarray(T_base_cam, dtype=float)
    xyz = T[:3, 3].copy()
    if not height_measured:
        xyz[2] = 0.0
    return xyz, Rotation.from_matrix(T[:3, :3]).as_euler("xyz")


def _height_note(height_measured: bool) -> str | None:
    if height_measured:
        return None
    return ("z (the camera height) is NOT measured: planar driving cannot observe it, so 0 is written; measure the "
            "height of the camera above the base frame origin and put it here (or give it to plsgraph calibrate as "
            "its camera-height option)")


def urdf_text(T_base_cam: np.ndarray, parent: str, child: str, *, ok: bool = True, problems: tuple[str, ...] = (),
              height_measured: bool = True, time_offset_s: float | None = None) -> str:
    """A URDF fragment: one fixed ``<joint>`` from ``parent`` to ``child`` with ``<origin xyz rpy>`` = T_base_cam."""
    xyz, rpy = _pose(T_base_cam, height_measured)
    head = ['<?xml version="1.0"?>', "<!-- plsgraph: camera extrinsic T_base_cam as a fixed URDF joint. -->"]
    if not ok:
        why = " ".join(f"- {p}" for p in problems) or "- the result is flagged"
        head.append("<!-- NO USABLE CALIBRATION: the result is flagged, so no joint is written. "
                    + _xml_comment(why) + " -->")
        return "\n".join(head + ['<robot name="plsgraph_camera_mount">', "</robot>", ""])
    note = _height_note(height_measured)
    lines = head + ['<robot name="plsgraph_camera_mount">', f"  <!-- {_xml_comment(frames_note(parent, child))} -->"]
    if time_offset_s is not None:
        sign = "-" if time_offset_s < 0 else "+"
        lines.append(f"  <!-- time offset: t_odom = t_cam {sign} {abs(time_offset_s):.9f} s (not part of the URDF) -->")
    if note:
        lines.append(f"  <!-- {_xml_comment(note)} -->")
    lines += [
        f"  <link name={quoteattr(parent)}/>",
        f"  <link name={quoteattr(child)}/>",
        f"  <joint name={quoteattr(f'{parent}_to_{child}')} type=\"fixed\">",
        f"    <parent link={quoteattr(parent)}/>",
        f"    <child link={quoteattr(child)}/>",
        f"    <origin xyz=\"{xyz[0]:.6f} {xyz[1]:.6f} {xyz[2]:.6f}\" rpy=\"{rpy[0]:.9f} {rpy[1]:.9f} {rpy[2]:.9f}\"/>",
        "  </joint>",
        "</robot>",
        "",
    ]
    return "\n".join(lines)


def node_name(child: str) -> str:
    """The static transform publisher's ROS 2 node name for ``child``: ``<child>_static_tf`` with every character a node
    name may not hold ([A-Za-z0-9_] only, not starting with a digit) as ``_`` (frame "robot1/cam.0" ->
    "robot1_cam_0_static_tf")."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", child) + "_static_tf"
    return "_" + name if name[0].isdigit() else name


def _xml_comment(text: str) -> str:
    return text.replace("--", "- -")  # "--" may not appear inside an XML comment


def launch_text(T_base_cam: np.ndarray, parent: str, child: str, *, ok: bool = True, problems: tuple[str, ...] = (),
                height_measured: bool = True) -> str:
    """A ROS 2 Python launch file: tf2_ros static_transform_publisher with the new-style named arguments."""
    xyz, rpy = _pose(T_base_cam, height_measured)
    if not ok:
        lines = ["# plsgraph: NO USABLE CALIBRATION. The result is flagged, so no transform is published:"]
        lines += [f"#   - {p}" for p in (problems or ("the result is flagged",))]
        lines += ["# Fix the problems above and calibrate again.", ""]
        return "\n".join(lines)
    note = _height_note(height_measured)
    z_comment = f"  # {note}" if note else ""
    return "\n".join([
        '"""plsgraph: publish the camera extrinsic T_base_cam as a static transform (ROS 2).',
        "",
        f"    ros2 launch {LAUNCH_NAME}   (or include it from your robot's launch file)",
        "",
        *textwrap.wrap(frames_note(parent, child) + ".", 100, initial_indent="", subsequent_indent=""),
        '"""',
        "",
        "from launch import LaunchDescription",
        "from launch_ros.actions import Node",
        "",
        f"X, Y = {xyz[0]:.6f}, {xyz[1]:.6f}",
        f"Z = {xyz[2]:.6f}{z_comment}",
        f"ROLL, PITCH, YAW = {rpy[0]:.9f}, {rpy[1]:.9f}, {rpy[2]:.9f}  # rad, fixed axes x, y, z",
        "",
        "",
        "def generate_launch_description():",
        "    return LaunchDescription([",
        "        Node(",
        '            package="tf2_ros",',
        '            executable="static_transform_publisher",',
        f'            name="{node_name(child)}",',
        "            arguments=[",
        '                "--x", str(X), "--y", str(Y), "--z", str(Z),',
        '                "--roll", str(ROLL), "--pitch", str(PITCH), "--yaw", str(YAW),',
        f'                "--frame-id", "{parent}", "--child-frame-id", "{child}",',
        "            ],",
        "        ),",
        "    ])",
        "",
    ])


LENS_CAMERA_NAME = "camera_from_board_views.yaml"


def lens_camera_text(camera: Any, lens: Any, recording: str) -> str:
    """A camera file (plsgraph / ROS camera_calibration YAML, as --camera-info reads it) of ``camera`` with the radial
    distortion the board views fit (``lens``, a :class:`plsgraph.calib.lens.LensCheck`), for a second run."""
    import numpy as np

    cam = lens.camera(camera)
    K = [float(x) for x in np.asarray(cam.K, dtype=float).ravel()]
    D = [float(x) for x in np.asarray(cam.dist, dtype=float).ravel()]
    return "\n".join([
        "# The camera intrinsics of the recording with the radial distortion (k1, k2) the board views fit, the rest as",
        "# the recording's camera model had it. Written because the views disagreed with that model's distortion by",
        f"# {lens.shift_px:+.2f} px ({abs(lens.shift_px) / max(lens.shift_sigma_px, 1e-12):.0f} sigma) at the board's "
        f"outer image radius ({lens.n_frames} views of {recording}).",
        "# A calibration of the camera itself is the better source; this one comes from a moving board's event",
        "# detections. Calibrate again with: plsgraph calibrate ... --camera-info THIS_FILE",
        f"width: {int(cam.width)}",
        f"height: {int(cam.height)}",
        "distortion_model: plumb_bob",
        f"K: [{', '.join(repr(x) for x in K)}]",
        f"D: [{', '.join(repr(x) for x in D)}]",
        "",
    ])


def write_lens_camera(out: Path, result: Any) -> list[Path]:
    """camera_from_board_views.yaml when the board views disagree with the camera model's distortion (else nothing)."""
    run = getattr(result, "run", None)
    lens = getattr(run, "lens", None) if run is not None else None
    if lens is None or not lens.significant or getattr(run, "camera", None) is None:
        return []
    write_text(out / LENS_CAMERA_NAME, lens_camera_text(run.camera, lens, Path(str(run.log_path)).name))
    return [out / LENS_CAMERA_NAME]


def write_robot_files(out: Path, result: Any) -> list[Path]:
    """base_to_camera.urdf and static_tf.launch.py for a :class:`plsgraph.result.CalibrationResult`."""
    c = result.report["calibration"]
    opts = result.report.get("options", {})
    refine = opts.get("refine", {}) or {}
    measured = refine.get("camera_height") is not None or refine.get("board_height") is not None
    parent, child = c.get("parent_frame", "base_link"), c.get("child_frame", "event_camera")
    kw = dict(ok=bool(result.ok), problems=tuple(result.problems), height_measured=measured)
    write_text(out / URDF_NAME, urdf_text(result.T_base_cam, parent, child, time_offset_s=result.time_offset_s, **kw))
    write_text(out / LAUNCH_NAME, launch_text(result.T_base_cam, parent, child, **kw))
    return [out / URDF_NAME, out / LAUNCH_NAME]
