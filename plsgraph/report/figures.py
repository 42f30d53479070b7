"""Pictures for report.html: trajectories, residuals, time-offset curve, observability, method comparison.

The figures are drawn from :func:`figure_inputs` (the few arrays of a run they show), either here or in a
separate process (:mod:`plsgraph.report.figure_worker`) that has matplotlib loaded while the calibration runs.
"""

from __future__ import annotations

import html
import logging
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from ..core.geometry import rotation_error_deg
from ..refine.residuals import predicted_pixels
from .coverage import coverage_table
from .files import html_report, html_table, status_colour, write_text

log = logging.getLogger(__name__)


def _matplotlib_config_dir() -> None:
    """Where matplotlib keeps its font cache when its own folder (under HOME) cannot be written (a read-only HOME, a
    service account): one folder per user in the system's temp folder, reused by every run, instead of matplotlib's
    fresh temporary folder per process, left behind each time with a warning."""
    import os
    import stat
    import tempfile

    if "MPLCONFIGDIR" in os.environ:
        return

    def writable(base: str) -> bool:  # matplotlib's folder under base, or the nearest folder it would be made in
        probe = os.path.join(base, "matplotlib")
        while not os.path.isdir(probe) and os.path.dirname(probe) != probe:
            probe = os.path.dirname(probe)
        return os.access(probe, os.W_OK | os.X_OK)

    home = os.path.expanduser("~")
    config = os.environ.get("XDG_CONFIG_HOME") or os.path.join(home, ".config")
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(home, ".cache")  # the font cache goes there
    if writable(config) and writable(cache):
        return
    shared = os.path.join(tempfile.gettempdir(), f"plsgraph-matplotlib-{os.getuid()}")
    try:
        os.makedirs(shared, mode=0o700, exist_ok=True)
        st = os.lstat(shared)
    except OSError:
        return
    # Only a folder of this user's that nobody else can write (the name is predictable: another user could have made
    # it first, with a matplotlibrc of theirs in it).
    if stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        os.environ["MPLCONFIGDIR"] = shared


def _plt():
    _matplotlib_config_dir()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def frame_residuals(run: Any, T_base_cam: np.ndarray, td: float, T_world_board: np.ndarray):
    """Per-frame reprojection under a calibration: times (m,), RMS (px, m), the residual vectors (k, 2) of the frames
    the refinement took, and per frame whether it was left out as one taken while the base stood still
    (``run.still_frames``)."""
    det = run.camera_track.detections
    if det is None or len(det) == 0:
        return np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros(0, dtype=bool)
    uv, ok = predicted_pixels(det, run.base_track, run.camera, T_base_cam, td, T_world_board)
    r = uv - det.uv[ok]
    rms = np.sqrt(np.nanmean(np.sum(r**2, axis=-1), axis=1))
    mask = getattr(run, "still_frames", None)  # per frame of the camera track
    if mask is None or len(mask) != len(run.camera_track.t):
        still = np.zeros(int(np.count_nonzero(ok)), dtype=bool)
    else:
        mask = np.asarray(mask, dtype=bool)
        still = (mask if len(det) == len(mask) else np.isin(det.t, run.camera_track.t[mask]))[ok]
    flat = r[~still].reshape(-1, 2)
    return det.t[ok], rms, flat[np.all(np.isfinite(flat), axis=1)], still


#: Resolution of the report's figures. They are made at it, not only saved at it: the layout then measures each
#: label at the size it is drawn, and the drawing reuses those measurements (a quarter of the figures' time).
DPI = 110


def _plain_ticks(axis) -> None:
    """Tick labels of a log axis as plain numbers (0.01, 1, 100): the default powers of ten are typeset as maths,
    the dearest text a figure here draws."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _save(plt, fig, out: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(out / name, dpi=DPI)
    plt.close(fig)
    return name


def trajectory_paths(run: Any) -> dict[str, np.ndarray]:
    """The top-view paths the trajectories figure draws (world x, y; metres): ``odometry`` (the base as recorded);
    with a refinement, ``camera_pnp`` (the camera through the board's pose and each detection) and ``camera_base``
    (the camera through the base at each detection's time and ``T_base_cam``): the base as the refinement solved it
    (its knots, which carry the odometry's effective radius and track) where the result holds them, else the
    odometry as recorded; ``base_refined`` the knots themselves. Where the calibration fits, ``camera_base`` runs
    through ``camera_pnp``: on a skid-steer robot the recorded odometry's turns are off by its effective track, so
    a path through it drifts from the PnP one while the calibration is right."""
    from ..core.geometry import PoseInterpolator

    paths = {"odometry": run.base_track.T_world_base[:, :2, 3]}
    ref = run.refinement
    if ref is None:
        return paths
    paths["camera_pnp"] = (ref.T_world_board @ run.camera_track.T_board_cam)[:, :2, 3]
    t_odom = run.camera_track.t + ref.td
    knot_t = np.asarray(getattr(ref, "knot_t", ()), dtype=float)
    knots = getattr(ref, "T_world_base", None)
    if knot_t.size >= 2 and knots is not None and len(knots) == knot_t.size:
        ok = (t_odom >= knot_t[0]) & (t_odom <= knot_t[-1])
        T_wb = PoseInterpolator(knot_t, np.asarray(knots, dtype=float))(t_odom[ok])
        paths["base_refined"] = np.asarray(knots, dtype=float)[:, :2, 3]
    else:
        ok = (t_odom >= run.base_track.t[0]) & (t_odom <= run.base_track.t[-1])
        T_wb = run.base_track.poses_at(t_odom[ok])
    paths["camera_base"] = (T_wb @ ref.T_base_cam)[:, :2, 3]
    return paths


def _fig_trajectories(run: Any, out: Path) -> str | None:
    ref = run.refinement
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 4.2), dpi=DPI)
    paths = trajectory_paths(run)
    bt = paths["odometry"]
    ax.plot(bt[:, 0], bt[:, 1], "-", lw=1, color="#999" if "base_refined" in paths else "#555",
            label="base (odometry as recorded)")
    if "base_refined" in paths:
        br = paths["base_refined"]
        ax.plot(br[:, 0], br[:, 1], "-", lw=1, color="#333", label="base (as refined)")
    if ref is not None:
        cb, cv = paths["camera_base"], paths["camera_pnp"]
        ax.plot(cb[:, 0], cb[:, 1], "-", lw=1.5, color="#1565c0",
                label="camera via refined base" if "base_refined" in paths else "camera via odometry")
        ax.plot(cv[:, 0], cv[:, 1], ".", ms=2, color="#e65100", label="camera via board (PnP)")
        b = ref.T_world_board[:3, 3]
        ax.plot([b[0]], [b[1]], "ks", label="board origin")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.axis("equal")
    ax.legend(fontsize=7)
    ax.set_title("aligned trajectories (top view)")
    return _save(plt, fig, out, "trajectories.png")


def _graph_residuals(ref: Any):
    """The refinement's own residuals at its solution (see :class:`~plsgraph.refine.graph.RefinementResult`): times,
    per-frame RMS (px) and the finite residual vectors (k, 2); None when the result does not carry them."""
    r = getattr(ref, "residual_px", None)
    t = getattr(ref, "residual_t", None)
    if r is None or t is None or len(t) != len(r):
        return None
    r = np.asarray(r, dtype=float)
    e2 = np.sum(r**2, axis=-1)
    n = np.sum(np.isfinite(e2), axis=1)
    rms = np.where(n > 0, np.sqrt(np.nansum(e2, axis=1) / np.maximum(n, 1)), np.nan)  # no point: no RMS
    flat = r.reshape(-1, 2)
    return np.asarray(t, dtype=float), rms, flat[np.all(np.isfinite(flat), axis=1)]


def _fig_residuals(run: Any, out: Path) -> str | None:
    """Per-frame RMS and the distribution of the residuals the refinement ended with: the graph's own (the base
    between its knots as solved, the odometry's effective radius and track), which report.json's RMS is. A result
    without them: the detections under the calibration and the odometry as recorded, the frames of a still base
    drawn apart."""
    ref = run.refinement
    if ref is None:
        return None
    mask = getattr(run, "still_frames", None)
    n_still = 0 if mask is None else int(np.count_nonzero(mask))
    graph = _graph_residuals(ref)
    if graph is not None:
        t, rms, r = graph
        still = np.zeros(t.size, dtype=bool)
    else:
        t, rms, r, still = frame_residuals(run, ref.T_base_cam, ref.td, ref.T_world_board)
    if rms.size == 0:
        return None
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8.5, 3.4), dpi=DPI)
    t0 = float(run.camera_track.t[0]) if len(run.camera_track.t) else float(t[0])
    a1.plot(t[~still] - t0, rms[~still], ".", ms=3)
    if still.any():  # rocking or humming while the base stood still: drawn apart, the refinement left them out
        a1.plot(t[still] - t0, rms[still], ".", ms=3, color="0.65",
                label=f"base still: left out ({int(still.sum())})")
        a1.legend(fontsize=7)
    a1.set_xlabel("camera time (s)")
    a1.set_ylabel("frame RMS (px)")
    a1.set_title("reprojection RMS per frame" + (f" ({n_still} of a still base left out)"
                                                  if n_still and graph is not None else ""),
                 fontsize=10 if n_still and graph is not None else None)
    lim = max(1.0, float(np.nanpercentile(np.abs(r), 99))) if r.size else 1.0
    a2.hist2d(r[:, 0], r[:, 1], bins=60, range=[[-lim, lim], [-lim, lim]], cmap="Blues")
    a2.set_xlabel("u residual (px)")
    a2.set_ylabel("v residual (px)")
    a2.set_title("residual distribution" + (" (frames refined)" if still.any() else ""))
    return _save(plt, fig, out, "residuals.png")


def _fig_time_offset(run: Any, out: Path) -> str | None:
    to = run.closed_form.time_offset if run.closed_form is not None else None
    if to is None or to.shifts is None or len(to.shifts) == 0:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.2, 3.4), dpi=DPI)
    order = np.argsort(to.shifts)
    ax.plot(1e3 * np.asarray(to.shifts)[order], np.asarray(to.values)[order], "-", lw=1.2)
    # The search's peak is where the closed form starts; its own td (refined with the rotation) can differ.
    ax.axvline(1e3 * to.td, color="#c62828", lw=1, label=f"search peak {1e3 * to.td:.1f} ms")
    cf_td = getattr(run.closed_form, "td", None)
    if cf_td is not None and np.isfinite(cf_td) and abs(cf_td - to.td) > 5e-5:
        ax.axvline(1e3 * cf_td, color="#ef6c00", lw=1, ls=":", label=f"closed form {1e3 * cf_td:.1f} ms")
    if run.refinement is not None:
        ax.axvline(1e3 * run.refinement.td, color="#2e7d32", lw=1, ls="--",
                   label=f"refined {1e3 * run.refinement.td:.1f} ms")
    shift = getattr(run, "clock_offset_s", 0.0)
    ax.set_xlabel("time offset td (ms)" if not shift else f"td (ms) after the coarse clock shift of {shift:.3f} s")
    ax.set_ylabel(f"score ({to.method})")
    ax.set_title("time-offset search")
    ax.legend(fontsize=7)
    return _save(plt, fig, out, "time_offset.png")


def _fig_observability(run: Any, out: Path) -> str | None:
    ref = run.refinement
    if ref is None or ref.observability is None or not ref.observability.axes:
        return None
    axes = ref.observability.axes
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 3.4), dpi=DPI)
    ratios = [max(a.ratio, 1e-6) for a in axes]
    ax.bar(range(len(axes)), ratios, color=[status_colour(a.status) for a in axes])
    ax.set_yscale("log")
    _plain_ticks(ax.yaxis)
    ax.set_xticks(range(len(axes)), [a.name for a in axes], rotation=30, fontsize=8)
    ax.set_ylabel("posterior sigma / prior sigma")
    ax.set_title("observability (green observable, yellow weak, red unobservable)", fontsize=9)
    return _save(plt, fig, out, "observability.png")


def _fig_methods(run: Any, out: Path, truth_T: np.ndarray | None) -> str | None:
    cf = run.closed_form
    if cf is None:
        return None
    ref_T = truth_T if truth_T is not None else (run.refinement.T_base_cam if run.refinement is not None else None)
    if ref_T is None:
        return None
    names, errs = [], []
    for name, m in cf.methods.items():
        if m.R_base_cam is not None:
            names.append(name)
            errs.append(float(rotation_error_deg(m.R_base_cam, ref_T[:3, :3])))
    if truth_T is not None and run.refinement is not None:
        names.append("refined")
        errs.append(float(rotation_error_deg(run.refinement.R_base_cam, truth_T[:3, :3])))
    if not names:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 3.4), dpi=DPI)
    ax.bar(range(len(names)), errs, color=["#2e7d32" if n == "refined" else "#1565c0" for n in names])
    ax.set_xticks(range(len(names)), names, rotation=35, fontsize=7, ha="right")
    ax.set_yscale("symlog", linthresh=0.1)
    ax.set_ylim(0.0, 3.0 * max(max(errs), 0.1))  # room above the tallest bar for its number
    for i, e in enumerate(errs):
        ax.annotate(f"{e:.2g}", (i, e), textcoords="offset points", xytext=(0, 2), ha="center", fontsize=7)
    _plain_ticks(ax.yaxis)
    ax.set_ylabel("rotation error (deg)" if truth_T is not None else "rotation difference to refined (deg)")
    ax.set_title("closed form vs refined")
    return _save(plt, fig, out, "methods.png")


FIGURES = (  # (caption, maker(run, out, truth_T)), in the order the page shows them
    ("aligned trajectories", lambda run, out, truth_T: _fig_trajectories(run, out)),
    ("reprojection residuals after refinement", lambda run, out, truth_T: _fig_residuals(run, out)),
    ("time-offset correlation curve", lambda run, out, truth_T: _fig_time_offset(run, out)),
    ("per-direction sigma with observability colours", lambda run, out, truth_T: _fig_observability(run, out)),
    ("closed form vs refined", _fig_methods),
    ("detection coverage: each window's outcome over time", lambda run, out, truth_T: _coverage("fig_coverage", run,
                                                                                                out)),
    ("event frames with the detected grid (green circles joined in the board's order, the first red)",
     lambda run, out, truth_T: _coverage("fig_event_frames", run, out)),
)


def _coverage(name: str, run: Any, out: Path) -> str | None:
    from . import coverage

    return getattr(coverage, name)(run, out)


def figure_inputs(run: Any, refinement: Any = None) -> SimpleNamespace:
    """What the figures read of a run, and nothing else: plain arrays and the two tracks (it pickles, to be drawn
    in another process). ``refinement`` (T_base_cam, R_base_cam, td, T_world_board, observability) stands in for
    the run's own, e.g. a solution before its second opinions (its knots, knot_t and T_world_base, where it has
    them)."""
    ref, cf = run.refinement if refinement is None else refinement, run.closed_form
    refinement = None
    if ref is not None:
        obs = None
        if ref.observability is not None:
            obs = SimpleNamespace(axes=[SimpleNamespace(name=a.name, ratio=a.ratio, status=a.status)
                                        for a in ref.observability.axes])
        refinement = SimpleNamespace(T_base_cam=ref.T_base_cam, R_base_cam=ref.R_base_cam, td=ref.td,
                                     T_world_board=ref.T_world_board, observability=obs,
                                     residual_t=getattr(ref, "residual_t", None),
                                     residual_px=getattr(ref, "residual_px", None),
                                     knot_t=getattr(ref, "knot_t", None),
                                     T_world_base=getattr(ref, "T_world_base", None))
    closed_form = None
    if cf is not None:
        to = cf.time_offset
        closed_form = SimpleNamespace(
            time_offset=None if to is None else SimpleNamespace(shifts=to.shifts, values=to.values, td=to.td,
                                                                method=to.method),
            methods={name: SimpleNamespace(R_base_cam=m.R_base_cam) for name, m in cf.methods.items()},
            td=getattr(cf, "td", None),
        )
    truth = None if run.truth is None else {"T_base_cam": np.asarray(run.truth["T_base_cam"], dtype=float)}
    return SimpleNamespace(camera_track=run.camera_track, base_track=run.base_track, camera=run.camera,
                           refinement=refinement, closed_form=closed_form, truth=truth,
                           clock_offset_s=getattr(run, "clock_offset_s", 0.0), log_path=getattr(run, "log_path", None),
                           event_frames=getattr(run, "event_frames", None),
                           still_frames=getattr(run, "still_frames", None))


def render_figures(out: Path, run: Any, which: Any = None) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """Draw the figures (all, or those of :data:`FIGURES` at the indices ``which``) into ``out``: the (caption, PNG
    name) of those drawn and the (caption, error) of those that failed. A figure that fails never stops the others."""
    truth_T = None if run.truth is None else np.asarray(run.truth["T_base_cam"], dtype=float)
    images: list[tuple[str, str]] = []
    failures: list[tuple[str, str]] = []
    for caption, make in FIGURES if which is None else [FIGURES[i] for i in which]:
        try:
            f = make(run, out, truth_T)
        except Exception as exc:  # a picture must never cost the user the numbers
            from ..core.processes import reraise_interrupt

            reraise_interrupt(exc)  # an interrupt inside matplotlib's import is the interrupt
            failures.append((caption, str(exc)))
            continue
        if f:
            images.append((caption, f))
    return images, failures


def note_figure_failures(report: dict, failures: list[tuple[str, str]]) -> None:
    """Log each figure that could not be drawn and add it to the report's warnings."""
    for caption, err in failures:
        log.warning("figure '%s' failed: %s", caption, err)
        report.setdefault("warnings", []).append(f"figure '{caption}' could not be drawn: {err}")


def write_html_report(out: Path, run: Any, report: dict,
                      figures: tuple[list[tuple[str, str]], list[tuple[str, str]]] | None = None) -> Path:
    """Write report.html into ``out`` with the figures: those already drawn (``figures``, as
    :func:`render_figures` returns them), else drawn here first. A figure that fails is logged, not fatal."""
    images, failures = render_figures(out, run) if figures is None else figures
    note_figure_failures(report, failures)
    c = report["calibration"]
    sections = []  # what a person needs first: the result with its sigmas, then what is wrong, then the pictures
    status = "OK" if report["ok"] else "FLAGGED: do not use this calibration"
    sections.append(("Result", f"<p><b>{html.escape(status)}</b> (from {html.escape(c['source'])})</p>"
                     + _summary_table(c) + _robot_notes(report) + "<pre>" + html.escape(_result_block(c)) + "</pre>"))
    if report["problems"]:
        kept = ([f"<li>The calibration this folder held before is kept in <a href='{report['previous_calibration']}/"
                 f"report.html'>{report['previous_calibration']}/</a>.</li>"] if report.get("previous_calibration")
                else [])
        sections.append(("Problems", "<ul>" + "".join(f"<li class='warn'><b>{html.escape(p)}</b></li>"
                                                      for p in report["problems"]) + "".join(kept) + "</ul>"))
    if report["warnings"]:
        sections.append(("Warnings", "<ul>" + "".join(f"<li class='warn'>{html.escape(w)}</li>"
                                                      for w in report["warnings"]) + "</ul>"))
    tail = []
    if c["observability"]:
        tail.append(("Observability", html_table(c["observability"], ["direction", "status", "sigma", "unit",
                                                                       "note"])))
    rows = []
    for name, m in report["closed_form"].items():
        # "warned": it gave an answer, with a caveat about it (e.g. a hand-eye solver on planar motion).
        rows.append({"method": name, "status": "error" if m["error"] else "warned" if m["warnings"] else "ok",
                     "detail": m["error"] or "",
                     "warnings": "; ".join(m["warnings"])})
    tail.append(("Closed-form solvers", html_table(rows, ["method", "status", "detail", "warnings"])))
    if "truth_errors" in report:
        tail.append(("Errors against truth", html_table(
            [{"quantity": k, "value": v} for k, v in report["truth_errors"].items()], ["quantity", "value"])))
    track = getattr(run, "camera_track", None)
    table = None if track is None else coverage_table(track.info, run)
    if table:
        sections.append(("Detection coverage", table))
    if report["discarded"]:
        tail.append(("Discarded", "<pre>" + html.escape(_pretty(report["discarded"])) + "</pre>"))
    page = html_report(f"plsgraph calibration of {Path(report['recording']).name}", sections, images, tail)
    write_text(out / "report.html", page)
    return out / "report.html"


def _summary_table(c: dict) -> str:
    """rpy, translation and time offset with their one-sigma (from the covariance, when there is one)."""
    m = (c.get("covariance") or {}).get("matrix")
    sig = np.sqrt(np.clip(np.diag(np.asarray(m, dtype=float)), 0, None)) if m is not None else None
    rpy_sig = c.get("rpy_sigma_deg")
    if rpy_sig is None and m is not None:  # a report written before the Euler angles had their own sigmas
        from .files import rpy_sigma_deg

        rpy_sig = rpy_sigma_deg(np.asarray(c["T_base_cam"], dtype=float)[:3, :3], np.asarray(m, dtype=float))
    rows = []
    for i, name in enumerate(("roll", "pitch", "yaw")):
        v = None if rpy_sig is None else rpy_sig[i]
        # None or NaN near pitch +-90 deg (a camera on its side), where roll and yaw are no separate angles
        s = "-" if v is None or not np.isfinite(v) else f"± {v:.3f}"
        rows.append({"parameter": f"{name} (deg, Euler)", "value": f"{c['rpy_deg'][i]:.3f}", "sigma": s})
    for i, name in enumerate(("x", "y", "z")):
        s = "-" if sig is None else f"± {sig[3 + i]:.4f}"
        rows.append({"parameter": f"{name} (m)", "value": f"{c['translation_m'][i]:.4f}", "sigma": s})
    td = c["time_offset_s"]
    s = "-" if sig is None else f"± {1e3 * sig[6]:.2f}"
    rows.append({"parameter": "time offset (ms)", "value": f"{1e3 * td:.3f}", "sigma": s})
    note = ("<p>sigma: one standard deviation from the refinement's covariance; '-' when there is none (closed "
            "form only). Roll, pitch and yaw are the Euler angles about the fixed axes x, y, z of the camera's optical "
            "frame (z forward) in the base frame, their sigmas propagated from the covariance; the observability list "
            "gives the sigmas of small rotations about the base axes instead, which differ from these wherever yaw "
            "is not zero. A sigma of 1 m on z means: not observable.</p>")
    return html_table(rows, ["parameter", "value", "sigma"]) + note


def _robot_notes(report: dict) -> str:
    """The odometry file (two-file runs), the clock alignment and the effective wheel geometry, as the terminal
    summary gives them."""
    c = report["calibration"]
    notes = []
    odo_file = ((report.get("options") or {}).get("inputs") or {}).get("odometry_file")
    if odo_file:
        notes.append(f"odometry read from {odo_file} (a second file, its own clock)")
    clock = c.get("clock_alignment") or {}
    if clock.get("coarse"):
        notes.append(f"clocks aligned coarsely from the motion: {clock['offset_s']:.3f} s (correlation "
                     f"{clock.get('score', float('nan')):.2f}, second peak ratio "
                     f"{clock.get('second_peak_ratio', float('nan')):.2f}); {clock.get('rule', '')}")
    odo = c.get("odometry") or {}
    if odo.get("wheel_radius_m") is not None:
        sr, sb = odo.get("wheel_radius_sigma_m"), odo.get("track_width_sigma_m")
        notes.append(f"effective wheel radius {odo['wheel_radius_m']:.4f} m"
                     + ("" if sr is None else f" ± {sr:.4f}") + f", track width {odo['track_width_m']:.3f} m"
                     + ("" if sb is None else f" ± {sb:.3f}") + f" ({odo.get('source', '')})")
    return "".join(f"<p>{html.escape(n)}</p>" for n in notes)


def _result_block(c: dict) -> str:
    T = "\n".join("  " + " ".join(f"{v:10.6f}" if v is not None else "       n/a" for v in row)
                  for row in c["T_base_cam"])
    return (f"T_base_cam =\n{T}\nquaternion xyzw = {c['quaternion_xyzw']}\ntime offset = {c['time_offset_s']} s"
            f" ({c['time_offset_convention']})\n\n{c['ros_static_transform']}")


def _pretty(d: dict) -> str:
    import json

    return json.dumps(d, indent=2, default=str)
