"""Plain-text renderings of the results, for people (the command prints these)."""

from __future__ import annotations

from typing import Any


def _num(v: Any, width: int, digits: int) -> str:
    return f"{v:{width}.{digits}f}" if isinstance(v, int | float) else "n/a".rjust(width)


def _height_note(report: dict) -> str:
    obs = report["calibration"]["observability"]
    if not any(o.get("name") == "z" and o["status"] != "observable" for o in obs):
        return ""
    if report["options"]["refine"].get("camera_height") is not None:
        return "   (z from --camera-height: the motion cannot observe it)"
    return "   (z unknown, written as 0: driving on a floor cannot observe the height; give --camera-height)"


def _offset_line(c: dict) -> str:
    td = c["time_offset_s"]
    if abs(td) < 1.0:
        return f"time offset    {1e3 * td:.2f} ms (t_odom = t_cam + offset)"
    return f"time offset    {td:.6f} s (t_odom = t_cam + offset; the clocks differ)"


def calibration_text(report: dict) -> str:
    """The summary of a calibration's report dict."""
    c = report["calibration"]
    lines = []
    if not report.get("ok", True):  # first, before any number a reader could copy
        lines.append(f"FLAGGED: do not use this calibration ({len(report['problems'])} problem(s), listed under "
                     "PROBLEMS below; the robot files hold no transform)")
    lines += [
        f"recording      {report['recording']}",
        f"result from    {c['source']}",
        "T_base_cam     " + "\n               ".join(" ".join(_num(v, 9, 5) for v in row) for row in c["T_base_cam"]),
        f"rpy (deg)      {' '.join(_num(v, 8, 3) for v in c['rpy_deg'])}",
        f"translation m  {' '.join(_num(v, 8, 4) for v in c['translation_m'])}" + _height_note(report),
        _offset_line(c),
    ]
    clock = c.get("clock_alignment") or {}
    if clock.get("coarse"):
        lines.append(f"clocks         coarse alignment {clock['offset_s']:.3f} s (correlation {clock['score']:.2f}, "
                     f"second peak ratio {clock['second_peak_ratio']:.2f}); {clock['rule']}")
    odo = c.get("odometry") or {}
    if odo.get("wheel_radius_m") is not None:
        def pm(v, sig, digits):
            return f"{v:.{digits}f}" + ("" if sig is None else f" +- {sig:.{digits}f}")

        radius = pm(odo["wheel_radius_m"], odo.get("wheel_radius_sigma_m"), 4)
        lines.append(f"odometry       effective wheel radius {radius} m, track width "
                     f"{pm(odo['track_width_m'], odo.get('track_width_sigma_m'), 3)} m (nominal "
                     f"{odo.get('wheel_radius_nominal_m', odo.get('nominal_wheel_radius_m'))} m, "
                     f"{odo.get('track_width_nominal_m', odo.get('nominal_track_width_m'))} m)")
    elif odo.get("turn_rate_scale") is not None:  # nav_msgs/Odometry: its scales, not a wheel geometry
        def sc(k):
            sig = odo.get(f"{k}_sigma")
            return f"x{odo[k]:.3f}" + ("" if sig is None else f" +- {sig:.3f}")

        lines.append(f"odometry       the camera sees {sc('speed_scale')} the odometry's speed and "
                     f"{sc('turn_rate_scale')} its turn rate (nav_msgs/Odometry: no wheel geometry to estimate)")
    wo = c.get("wheel_order") or {}
    if wo.get("corrected"):
        lines.append(f"wheels         CORRECTED: {wo['description']} (see warnings)")
    ref = report.get("refinement")
    if ref:
        lines.append(
            f"refinement     converged={ref['converged']} iterations={ref['iterations']} "
            f"reprojection RMS {ref['rms_px_initial']:.3f} -> {ref['rms_px_final']:.3f} px"
        )
        tilt = (ref.get("inflation") or {}).get("floor_tilt_rms_deg")
        if tilt is not None:
            lines.append(f"floor          the base tilted {tilt:.2f} deg RMS along the drive (about 0.03 on a level "
                         "floor); roll and pitch are measured against the floor's mean plane")
        focal = focal_line((ref.get("inflation") or {}).get("focal_length_sensitivity"))
        if focal:
            lines.append(focal)
    if c["observability"]:
        lines.append("observability:")
        for o in c["observability"]:
            sig = "-" if o["sigma"] is None else f"{o['sigma']:.3g} {o.get('unit', '')}"
            lines.append(f"  {o['status']:<13} {o['direction']:<40} sigma {sig}")
    if "truth_errors" in report:
        lines.append("errors against truth:")
        errs = {k: v for k, v in report["truth_errors"].items() if v is not None}
        width = max([36, *map(len, errs)])
        lines += [f"  {k:<{width}} {v:.4g}" for k, v in errs.items()]
    if report["problems"]:
        lines.append("PROBLEMS (the calibration is flagged: do not use it):")
        lines += [f"  - {p}" for p in report["problems"]]
    if report["warnings"]:
        lines.append(f"warnings ({len(report['warnings'])}):")
        lines += [f"  - {w}" for w in report["warnings"][:12]]
    return "\n".join(lines)


def diagnosis_text(d: Any) -> str:
    """A :class:`plsgraph.result.Diagnosis` for people."""
    lines = [f"recording {d.recording}"]
    if d.camera_frames or d.odometry_samples:
        frames = ("not searched for (the run stopped before the board search: see the problem)"
                  if d.camera_frames is None else d.camera_frames)
        lines += [f"camera frames with the board: {frames}", f"odometry samples: {d.odometry_samples}"]
    clock = getattr(d, "clock_alignment", None) or {}
    if clock.get("coarse"):
        nan = float("nan")
        lines.append(f"clocks: coarse alignment {clock['offset_s']:.3f} s (correlation {clock.get('score', nan):.2f}, "
                     f"second peak ratio {clock.get('second_peak_ratio', nan):.2f}); {clock.get('rule', '')}")
    if d.excitation:
        lines.append("excitation (closed form):")
        lines += [f"  {k:<28} {v:.4g}" for k, v in d.excitation.items()]
    if d.observable_closed_form:
        lines.append("observable from the closed form: "
                     + ", ".join(f"{k}={'yes' if v else 'NO'}" for k, v in d.observable_closed_form.items()))
    if d.observability:
        lines.append("observability after refinement:")
        for o in d.observability:
            sig = "-" if o.get("sigma") is None else f"{o['sigma']:.3g} {o.get('unit', '')}".rstrip()
            lines.append(f"  {o['status']:<13} {o['direction']:<40} sigma {sig}")
            note = o.get("note") or ""
            if note.startswith(o["direction"]):  # the line above names it
                note = note[len(o["direction"]):].lstrip()
            if note:
                lines.append(f"{'':16}{note}")
    lines += [f"problem: {p}" for p in d.problems]
    lines += [f"warning: {w}" for w in getattr(d, "warnings", ())[:12]]
    lines.append("verdict: " + ("good enough" if d.ok else "NOT good enough"))
    lines += [f"advice: {a}" for a in d.advice]
    return "\n".join(lines)


def comparison_text(c: Any) -> str:
    """A :class:`plsgraph.result.Comparison` for people."""
    text = c.markdown
    if c.failed:
        text += "\n\nno answer from: " + "; ".join(f"{n}: {e}" for n, e in c.failed.items())
    if getattr(c, "problems", ()):
        text += "\n\nFLAGGED (the refined result is not fit to use):\n" + "\n".join(f"  - {p}" for p in c.problems)
    if getattr(c, "warnings", ()):
        text += f"\n\nwarnings ({len(c.warnings)}):\n" + "\n".join(f"  - {w}" for w in c.warnings[:12])
    return text


def focal_line(sens: dict | None) -> str | None:
    """The summary's line on the focal length: how far x and y move for 1 % of it, and how much the sigmas hold."""
    if not sens or not sens.get("focal_change"):
        return None
    per = 0.01 / float(sens["focal_change"])  # the move per 1 %
    held = float(sens.get("focal_sigma_in_sigmas") or 0.0)
    moves = ", ".join(f"{a} by {_mm(1e3 * per * float(sens[a]))} mm" for a in ("x", "y") if sens.get(a) is not None)
    said = (f"the sigmas hold a {100 * held:.2g} % focal-length error (--focal-sigma)" if held > 0 else
            "the sigmas take the focal length as exact (--focal-sigma 0)")
    return f"focal length   1 % longer would move {moves}; {said}"


def _mm(v: float) -> str:
    return f"{v:+.0f}" if abs(v) >= 9.5 else f"{v:+.1f}"
