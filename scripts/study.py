#!/usr/bin/env python3
"""The validation study: N seeded random realistic recordings, each calibrated with the defaults.

    scripts/study.py --n 30 --out out/study --workers 2            # the full study (docs/validation.md)
    scripts/study.py --quick --out out/study_quick                   # 3 short runs, for CI
    scripts/study.py --only latency --n 3 --out out/abl_latency      # one effect over the ideal simulator
    scripts/study.py --ablation --n 2 --out out/ablation             # every effect alone, plus the ideal base

Each run draws every realism effect from its study range (plsgraph.sim.realism.draw_realism; --only switches
a single effect on over the ideal simulator), simulates the recording in memory, writes it as a ROS 2 MCAP
(EVT3 event packets, wheel joint states, camera info), and calibrates it through the library call with the
user's nominal wheel radius and track width and the board as its YAML states (the printed board may differ).
Everything is measured against the simulator's truth:

* ``visible_fraction``: share of the front end's detection windows in which the whole (printed) board is in the
  image; ``detected_fraction``: share of those windows in which the board was detected (the window each detection
  was found in); ``missed_moving``: the windows of a moving board in view without a detection, by the front end's
  outcome and the board's image speed;
* ``wrong_detections``: detections whose labelled points lie far (median > 5 px) from the true projections
  (a wrong correspondence); ``centre_err_px_median``: median point error of the other detections;
* closed-form and refined errors (rotation, td, floor-plane position), the refined per-axis sigmas and
  ``z`` = error / sigma in base axes (roll, pitch, yaw, x, y, td), the rotation NEES;
* ``flagged`` (the result's gate said not ok) and ``outcome`` (ok, flagged, diagnosis, error).

Writes DIR/study.json (runs + summary) and DIR/study.md (the tables). Runs are independent processes
(--workers); the recording of a run is deleted unless --keep.

The refinement alone, on the same detections: ``--save-tracks DIR`` keeps each run's tracks (the front end's and
the odometry's output, with the truth and the front-end figures) as DIR/runNNN.pkl; ``--from-tracks DIR`` solves
those again (closed form and refinement, a minute or two for 30 runs instead of a quarter of an hour), with
``--set NAME=VALUE`` changing a field of the refinement's options (plsgraph.refine.graph.RefinementOptions)::

    scripts/study.py --n 30 --out out/study --workers 2 --save-tracks out/tracks
    scripts/study.py --from-tracks out/tracks --out out/abl_tilt --set planar_sigma_tilt=0.01
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
import os
import pickle
import sys
import tempfile
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

BOARD = "acircles_4x11_a2"
AXES = ("roll", "pitch", "yaw", "x", "y", "td")
WRONG_PX = 5.0  # a detection whose median point error exceeds this is a wrong correspondence
MOVING_PX_S = 5.0  # a board moving slower than this across the image makes (almost) no events
LAG_PX_S = 40.0  # detections of a board at least this fast measure the detection lag


def _realism(kind: str, effect: str | None, rng: np.random.Generator):
    from plsgraph.sim import realism as R

    if kind == "ideal":
        return R.ideal()
    if kind == "only":
        return R.only(effect, rng)
    return R.draw_realism(rng)


def _board_in_view(sim, t_cam: np.ndarray) -> np.ndarray:
    """Whole printed board inside the image, seen from its printed side, at camera stamps (simulation seconds)."""
    from plsgraph.core.geometry import inv_T

    T_board_cam = sim.camera_poses_at(t_cam)
    T_cam_board = inv_T(T_board_cam)
    pts = sim.board_true.points if getattr(sim, "board_true", None) is not None else sim.board.points
    p = np.einsum("mij,nj->mni", T_cam_board[:, :3, :3], pts) + T_cam_board[:, None, :3, 3]
    front = p[..., 2] > 1e-3
    uv = sim.camera.project(np.where(front[..., None], p, [0.0, 0.0, 1.0]).reshape(-1, 3)).reshape(p.shape[:2] + (2,))
    inside = front & (uv[..., 0] >= 0) & (uv[..., 0] <= sim.camera.width - 1) & (uv[..., 1] >= 0) & (
        uv[..., 1] <= sim.camera.height - 1)
    z = T_board_cam[:, 2, 3]  # from behind the board is blank (circle grids are printed on its -z face)
    printed_side = (z < 0) if sim.board.pattern == "asymmetric_circles" else (z > 0)
    return inside.all(axis=1) & printed_side


def _true_pixels(sim, t_cam: np.ndarray) -> np.ndarray:
    from plsgraph.core.geometry import inv_T

    T_cam_board = inv_T(sim.camera_poses_at(t_cam))
    pts = sim.board_true.points if getattr(sim, "board_true", None) is not None else sim.board.points
    p = np.einsum("mij,nj->mni", T_cam_board[:, :3, :3], pts) + T_cam_board[:, None, :3, 3]
    p[..., 2] = np.maximum(p[..., 2], 1e-3)
    return sim.camera.project(p.reshape(-1, 3)).reshape(p.shape[:2] + (2,))


#: Image speeds (px/s) the missed windows of a moving board are counted by.
MISS_SPEED_BINS = (5.0, 20.0, 100.0, 300.0)


def _missed_moving(run, rec, t_grid: np.ndarray, missed: np.ndarray, speed: np.ndarray, rate_hz: float) -> dict:
    """Why the front end missed the windows in which the board was in view and moving: the front end's own outcome
    of the window (``window_outcomes``; a window it found the board in but whose detection was dropped later, e.g.
    by PnP or at a gap, counts as ``dropped_later``), and the board's image speed there."""
    wo = run.camera_track.info.get("window_outcomes") if run.camera_track is not None else None
    reasons: dict[str, int] = {}
    if wo and len(wo["t"]):
        tw = np.asarray(wo["t"], dtype=float) - rec.epoch_ns * 1e-9
        outcome = np.asarray(wo["outcome"], dtype=str)
        k = np.clip(np.searchsorted(tw, t_grid[missed] - 0.5 / rate_hz), 0, tw.size - 1)
        for o in outcome[k]:
            o = "dropped_later" if o in ("rims", "blobs", "image") else str(o)
            reasons[o] = reasons.get(o, 0) + 1
    edges = (*MISS_SPEED_BINS, math.inf)
    by_speed = {f"{lo:g}-{hi:g} px/s": int(np.count_nonzero(missed & (speed >= lo) & (speed < hi)))
                for lo, hi in zip(edges[:-1], edges[1:], strict=True)}
    return {"windows": int(missed.sum()), "by_outcome": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
            "by_speed": by_speed}


def _sum_counts(parts: list) -> dict:
    """The missed-window counts of all runs added up."""
    total: dict = {"windows": 0, "by_outcome": {}, "by_speed": {}}
    for part in parts:
        if not part:
            continue
        total["windows"] += part["windows"]
        for key in ("by_outcome", "by_speed"):
            for k, v in part[key].items():
                total[key][k] = total[key].get(k, 0) + v
    total["by_outcome"] = dict(sorted(total["by_outcome"].items(), key=lambda kv: -kv[1]))
    return total


def _still_windows(run, rec, t_grid, in_view, detected, speed, rate_hz: float) -> dict:
    """The product's own account of the windows missed while the robot stood still (report.json ``coverage``,
    from the odometry and the calibrated td), checked against the truth: ``robot_still_windows`` in view,
    ``robot_still_moving_board`` of them with the true board moving (>= MOVING_PX_S; should be none), and
    ``detected_fraction_robot_moving``: detected share of the in-view windows not so labelled."""
    from plsgraph.report.coverage import window_outcomes

    wo = run.camera_track.info.get("window_outcomes") if run.camera_track is not None else None
    if not wo or not len(wo["t"]):
        return {}
    tw = np.asarray(wo["t"], dtype=float) - rec.epoch_ns * 1e-9
    k = np.clip(np.searchsorted(tw, t_grid - 0.5 / rate_hz), 0, tw.size - 1)
    still = (window_outcomes(run.camera_track.info, run) == "robot_still")[k] & ~detected
    rest = in_view & ~still
    return {"robot_still_windows": int((still & in_view).sum()),
            "robot_still_moving_board": int((still & in_view & (speed >= MOVING_PX_S)).sum()),
            "detected_fraction_robot_moving": float((detected & rest).sum() / max(1, rest.sum()))}


def _frontend_metrics(rec, run, rate_hz: float) -> dict:
    """Coverage, wrong labels and centre error of the front end's detections against the truth."""
    sim, ev = rec.sim, rec.events
    period = int(round(1e9 / rate_hz))
    grid = np.arange(ev.t_first + period, ev.t_last + 1, period, dtype=np.int64)
    t_grid = (grid - rec.epoch_ns) * 1e-9
    in_view = _board_in_view(sim, t_grid)
    det = run.camera_track.detections if run is not None and run.camera_track is not None else None
    out = {"windows": int(grid.size), "windows_in_view": int(in_view.sum()),
           "visible_fraction": float(in_view.mean()) if grid.size else 0.0}
    if det is None or len(det) == 0:
        out.update(detected_fraction=0.0, detections=0, wrong_detections=0, centre_err_px_median=None)
        return out
    # Detection times are seconds on the recording's clock (epoch included); map them onto the window grid.
    t_det_s = np.asarray(det.t, dtype=float) - rec.epoch_ns * 1e-9
    # A detection covers the window it was found in (the front end's info["window_t"]). Its stamp, the mean time
    # of its events, lies up to half a span earlier: mapped by the stamp, detections of adjacent windows can share
    # a slot (a stamp half a window back sits on the rounding boundary) and long spans land windows back; that
    # mapping, used up to study_v19, is kept as ``detected_fraction_by_stamp``.
    t0 = (grid[0] - rec.epoch_ns) * 1e-9

    def slots(times_s: np.ndarray) -> np.ndarray:
        k = np.rint((times_s - t0) * rate_hz).astype(int)
        hit = np.zeros(grid.size, dtype=bool)
        hit[k[(k >= 0) & (k < grid.size)]] = True
        return hit

    by_stamp = slots(t_det_s)
    win = run.camera_track.info.get("window_t")
    detected = slots(np.asarray(win, dtype=float) - rec.epoch_ns * 1e-9) if win is not None and len(win) == len(det) \
        else by_stamp
    uv_true = _true_pixels(sim, t_det_s)
    err = np.linalg.norm(np.asarray(det.uv) - uv_true, axis=-1)
    med = np.nanmedian(err, axis=1)
    wrong = med > WRONG_PX
    good_err = err[~wrong]
    # Windows in which the board moves: a still board makes no events, and no detector can find it there.
    uv_grid = _true_pixels(sim, t_grid)
    speed = np.r_[0.0, np.median(np.linalg.norm(np.diff(uv_grid, axis=0), axis=-1), axis=1) * rate_hz]
    moving = in_view & (speed >= MOVING_PX_S)
    out["windows_in_view_moving"] = int(moving.sum())
    out["detected_fraction_moving"] = float((detected & moving).sum() / max(1, moving.sum()))
    out["missed_moving"] = _missed_moving(run, rec, t_grid, moving & ~detected, speed, rate_hz)
    out.update(_still_windows(run, rec, t_grid, in_view, detected, speed, rate_hz))
    # Detection lag: the shift of the true board's time that best fits each detection (median over the
    # detections of a board moving fast enough to show it). Pixel latency makes it negative: the events show
    # the board where it was a moment before their stamps.
    tb = sim.truth_base.t
    lo, hi = tb[0] - sim.td + 0.031, tb[-1] - sim.td - 0.031  # camera times with truth 30 ms either side
    shifts = np.arange(-0.03, 0.0301, 0.0005)
    inside = ~wrong & (t_det_s > lo) & (t_det_s < hi)
    t_in = t_det_s[inside]
    v_det = np.median(np.linalg.norm(_true_pixels(sim, t_in + 0.01) - _true_pixels(sim, t_in - 0.01), axis=-1),
                      axis=1) / 0.02 if t_in.size else np.zeros(0)
    fast = v_det >= LAG_PX_S
    out["detection_lag_ms"] = None
    if fast.sum() >= 5:
        uv_u, t_u = np.asarray(det.uv)[inside][fast], t_in[fast]
        cost = np.stack([np.nanmedian(np.linalg.norm(uv_u - _true_pixels(sim, t_u + s), axis=-1), axis=1)
                         for s in shifts])
        out["detection_lag_ms"] = float(1e3 * np.median(shifts[np.argmin(cost, axis=0)]))
    src = np.asarray(run.camera_track.info.get("detector") or [], dtype=str)
    if src.size == len(det):
        out["detections_by_detector"] = {str(k): [int((src == k).sum()), int((wrong & (src == k)).sum())]
                                         for k in np.unique(src)}  # detector: [detections, wrong]
    out.update(
        detections=int(len(det)),
        detected_fraction=float((detected & in_view).sum() / max(1, in_view.sum())),
        detected_fraction_by_stamp=float((by_stamp & in_view).sum() / max(1, in_view.sum())),
        detected_out_of_view=int((detected & ~in_view).sum()),
        wrong_detections=int(wrong.sum()),
        centre_err_px_median=float(np.nanmedian(good_err)) if good_err.size else None,
    )
    return out


def _errors(run, truth: dict) -> dict:
    """Closed-form and refined errors; per-axis z of the refined result in base axes."""
    from plsgraph.core.geometry import rotation_error_deg, so3_log

    T_gt = np.asarray(truth["T_base_cam"], dtype=float)
    td_gt = float(truth["td"])
    cf = run.closed_form
    out: dict = {"closed_form": None, "refined": None}
    if cf is not None and cf.R_base_cam is not None:
        out["closed_form"] = {
            "rot_err_deg": float(rotation_error_deg(cf.R_base_cam, T_gt[:3, :3])),
            "td_err_ms": 1e3 * (cf.td - td_gt),
            "txy_err_m": None if cf.t_xy is None else float(np.linalg.norm(np.asarray(cf.t_xy) - T_gt[:2, 3])),
            "odometry_scale": {k: float(v) for k, v in (cf.odometry_scale or {}).items()
                               if isinstance(v, int | float)},
        }
    ref = run.refinement
    if ref is not None and ref.converged:
        d_rot = so3_log(ref.R_base_cam @ T_gt[:3, :3].T)  # small rotation about the base axes
        e = np.r_[d_rot, ref.T_base_cam[:2, 3] - T_gt[:2, 3], ref.td - td_gt]
        cov = ref.cov_base_axes
        refined = {
            "rot_err_deg": float(rotation_error_deg(ref.R_base_cam, T_gt[:3, :3])),
            "td_err_ms": 1e3 * (ref.td - td_gt),
            "txy_err_m": float(np.linalg.norm(ref.T_base_cam[:2, 3] - T_gt[:2, 3])),
            "err": dict(zip(AXES, e.tolist(), strict=True)),
            # what the reported sigmas are made of: the fit's chi2/dof and the second opinions applied
            "chi2_per_dof": float(ref.chi2_per_dof),
            "inflation": {k: v for k, v in (ref.inflation or {}).items() if isinstance(v, int | float | dict)},
        }
        held = getattr(ref, "held_solution", None)
        if held is not None:  # the solve before the noise model's adaptation, against the truth
            refined["held_err"] = dict(zip(AXES, np.r_[so3_log(held[0][:3, :3] @ T_gt[:3, :3].T),
                                                     held[0][:2, 3] - T_gt[:2, 3], held[1] - td_gt].tolist(),
                                           strict=True))
        from plsgraph.gate import _estimated_scales, _path_scales

        path, est = _path_scales(ref, run.base_track), _estimated_scales(ref)
        if path is not None:  # the refined path against the (scaled) odometry's, as the gate measures it
            refined["path_scales"] = [p / e for p, e in zip(path, est, strict=True)] if est else list(path)
        if cov is not None:
            idx = [0, 1, 2, 3, 4, 6]
            sig = np.sqrt(np.diag(cov)[idx])
            refined["sigma"] = dict(zip(AXES, sig.tolist(), strict=True))
            refined["z"] = dict(zip(AXES, (e / sig).tolist(), strict=True))
            try:
                refined["nees_rot"] = float(d_rot @ np.linalg.solve(cov[:3, :3], d_rot))
            except np.linalg.LinAlgError:
                refined["nees_rot"] = None
        odo = ref.odometry or {}
        if odo.get("wheel_radius_m") and truth.get("wheel_radius_true") and truth.get("track_width_effective"):
            refined["odometry"] = {
                "wheel_radius_err_pct": 100 * (odo["wheel_radius_m"] / truth["wheel_radius_true"] - 1),
                "track_width_err_pct": 100 * (odo["track_width_m"] / truth["track_width_effective"] - 1),
            }
            truths = (("wheel_radius", truth["wheel_radius_true"]), ("track_width", truth["track_width_effective"]))
            for name, true in truths:
                if odo.get(f"{name}_sigma_m"):
                    refined["odometry"][f"{name}_z"] = (odo[f"{name}_m"] - true) / odo[f"{name}_sigma_m"]
        out["refined"] = refined
    return out


def run_one(args: tuple) -> dict:
    """One study run in a worker process: draw, simulate, write, calibrate, measure."""
    index, base_seed, kind, effect, duration, keep_dir, surface, tracks_dir = args
    from plsgraph.api import simulate_recording
    from plsgraph.errors import DegenerateMotionError, InsufficientDataError
    from plsgraph.io.writer import write_recording, write_truth
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, build_tracks, load_truth, solve
    from plsgraph.result import calibration_result

    seed = int(np.random.SeedSequence([base_seed, index]).generate_state(1)[0] % (2**31))
    rng = np.random.default_rng(seed)
    realism = _realism(kind, effect, rng)
    td = float(rng.uniform(-0.1, 0.1))
    row: dict = {"index": index, "seed": seed, "effect": effect or kind, "td_true_s": td}
    t0 = time.perf_counter()
    tmp = tempfile.mkdtemp(prefix="plsgraph-study-", dir=keep_dir)
    path = Path(tmp) / f"run{index:03d}.mcap"
    try:
        rec = simulate_recording("rich", duration, seed, td, BOARD, realism=realism)
        row["nuisances"] = rec.truth.get("realism", {})
        row["truth"] = {k: rec.truth.get(k) for k in ("wheel_radius_true", "wheel_radius_nominal",
                                                        "track_width_effective", "track_width_nominal",
                                                        "board_scale", "td", "board_distance_m",
                                                        "board_in_view_fraction")}
        row["events"] = len(rec.events)
        write_recording(path, rec.events, rec.joints, None, rec.sim.camera, truth=None, event_format="evt3",
                        overwrite=True)
        truth_file = write_truth(path, rec.truth)
        row["seconds_simulate"] = round(time.perf_counter() - t0, 2)
        t1 = time.perf_counter()
        # The library's calibrate, step by step, so that a run refused late still shows its front end.
        opts = CalibrationOptions.build(board=BOARD, wheel_radius=rec.truth["wheel_radius_nominal"],
                                        track_width=rec.truth["track_width_nominal"], truth=truth_file,
                                        surface=surface, frontend_workers=1)
        run = Run(path, opts)
        run.truth = load_truth(opts.truth)
        saved = None  # the tracks, pickled, when kept (none when the front end refused the recording)
        try:
            build_tracks(run)
            # The front end's kept event frames (images for the report) are not part of the tracks.
            saved = pickle.dumps(dataclasses.replace(run, event_frames=None)) if tracks_dir is not None else None
            solve(run, refine=True)
            result = calibration_result(run)
            row["outcome"] = "ok" if result.ok else "flagged"
            row["flagged"] = not result.ok
            row["problems"] = list(result.problems)
            row["warnings"] = list(result.warnings)
        except (DegenerateMotionError, InsufficientDataError) as exc:
            row.update(outcome="diagnosis", flagged=True, problems=[str(exc)])
        row["seconds_calibrate"] = round(time.perf_counter() - t1, 2)
        frontend = _frontend_metrics(rec, run, opts.frontend.rate_hz)  # the windows' grid is the front end's
        row.update(frontend)
        if run.closed_form is not None:
            row.update(_errors(run, rec.truth))
        if tracks_dir is not None and saved is not None:
            keep = {k: row[k] for k in ("index", "seed", "effect", "td_true_s", "nuisances", "truth", "events")}
            with open(Path(tracks_dir) / f"run{index:03d}.pkl", "wb") as fh:
                pickle.dump({"run": saved, "truth": rec.truth, "row": {**keep, **frontend}}, fh)
    except Exception as exc:  # a crash is a finding of the study, recorded, not fatal
        row.update(outcome=f"error: {type(exc).__name__}: {exc}", flagged=True,
                   traceback=traceback.format_exc()[-2000:])
    finally:
        if keep_dir is None:
            for f in Path(tmp).glob("*"):
                f.unlink()
            os.rmdir(tmp)
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def _with_refinement_options(changes: dict) -> None:
    """Make the pipeline's refinements use RefinementOptions with ``changes`` (field -> value) applied."""
    import dataclasses

    from plsgraph.refine import graph

    plain = graph.refine

    def changed(camera_track, base_track, camera, seed, td, opts, **kw):
        return plain(camera_track, base_track, camera, seed, td, dataclasses.replace(opts, **changes), **kw)

    graph.refine = changed


def solve_saved(args: tuple) -> dict:
    """One run of ``--from-tracks``: the saved tracks solved again (closed form, refinement) and measured."""
    path, changes = args
    from plsgraph.errors import DegenerateMotionError, InsufficientDataError
    from plsgraph.pipeline import solve
    from plsgraph.result import calibration_result

    if changes:
        _with_refinement_options(changes)
    with open(path, "rb") as fh:
        saved = pickle.load(fh)
    row = dict(saved["row"])
    t0 = time.perf_counter()
    try:
        run = pickle.loads(saved["run"])
        try:
            solve(run, refine=True)
            result = calibration_result(run)
            row.update(outcome="ok" if result.ok else "flagged", flagged=not result.ok,
                       problems=list(result.problems), warnings=list(result.warnings))
        except (DegenerateMotionError, InsufficientDataError) as exc:
            row.update(outcome="diagnosis", flagged=True, problems=[str(exc)])
        if run.closed_form is not None:
            row.update(_errors(run, saved["truth"]))
    except Exception as exc:  # a crash is a finding of the study, recorded, not fatal
        row.update(outcome=f"error: {type(exc).__name__}: {exc}", flagged=True,
                   traceback=traceback.format_exc()[-2000:])
    row["seconds_calibrate"] = row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def _option_changes(items: list[str], ap: argparse.ArgumentParser) -> dict:
    """--set NAME=VALUE (a RefinementOptions field, the value a Python literal) -> {name: value}."""
    import dataclasses

    from plsgraph.refine.graph import RefinementOptions

    names = {f.name for f in dataclasses.fields(RefinementOptions)}
    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or name not in names:
            ap.error(f"--set {item!r}: expected NAME=VALUE with NAME a field of RefinementOptions")
        try:
            out[name] = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            ap.error(f"--set {item!r}: the value must be a Python literal (a number, True/False, None, a string)")
        if name == "odometry_noise":  # a dict of OdometryNoise fields, e.g. "{'tilt': (0.0, 0.01, 1e-4)}"
            from factors.odometry import OdometryNoise

            if not isinstance(out[name], dict):
                ap.error(f"--set {item!r}: odometry_noise takes a dict of OdometryNoise fields")
            try:
                out[name] = OdometryNoise(**out[name])
            except (TypeError, ValueError) as exc:
                ap.error(f"--set {item!r}: {exc}")
    return out


def _pct(values: list[float], q: float) -> float | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.percentile(v, q)) if v else None


def summarize(runs: list[dict]) -> dict:
    def col(path: str) -> list:
        out = []
        for r in runs:
            v = r
            for k in path.split("."):
                v = v.get(k) if isinstance(v, dict) else None
            out.append(v)
        return out

    refined_ok = [r for r in runs if (r.get("refined") or {}).get("z")]
    z = np.array([[r["refined"]["z"][a] for a in AXES] for r in refined_ok]) if refined_ok else np.zeros((0, 6))
    nees = [r["refined"].get("nees_rot") for r in refined_ok]
    pairs = [(r["closed_form"]["rot_err_deg"], r["refined"]["rot_err_deg"]) for r in runs
             if r.get("closed_form") and r.get("refined")]
    det_frac = [x for x in col("detected_fraction") if x is not None]
    dets = sum(x or 0 for x in col("detections"))
    wrong = sum(x or 0 for x in col("wrong_detections"))
    return {
        "runs": len(runs),
        "outcomes": {o: sum(1 for r in runs if str(r.get("outcome", "")).split(":")[0] == o)
                     for o in ("ok", "flagged", "diagnosis", "error")},
        "visible_fraction_median": _pct(col("visible_fraction"), 50),
        "detected_fraction_median": _pct(det_frac, 50),
        "detected_fraction_p10": _pct(det_frac, 10),
        "detected_fraction_by_stamp_median": _pct([x for x in col("detected_fraction_by_stamp") if x is not None], 50),
        "detected_fraction_by_stamp_p10": _pct([x for x in col("detected_fraction_by_stamp") if x is not None], 10),
        "detected_fraction_moving_median": _pct([x for x in col("detected_fraction_moving") if x is not None], 50),
        "detected_fraction_moving_p10": _pct([x for x in col("detected_fraction_moving") if x is not None], 10),
        "detected_fraction_robot_moving_median": _pct(
            [x for x in col("detected_fraction_robot_moving") if x is not None], 50),
        "detected_fraction_robot_moving_p10": _pct(
            [x for x in col("detected_fraction_robot_moving") if x is not None], 10),
        "robot_still_windows": sum(x or 0 for x in col("robot_still_windows")),
        "robot_still_moving_board": sum(x or 0 for x in col("robot_still_moving_board")),
        "detection_lag_ms_median": _pct([x for x in col("detection_lag_ms") if x is not None], 50),
        "wrong_detection_rate": wrong / dets if dets else None,
        "detections_by_detector": {k: [sum((r.get("detections_by_detector") or {}).get(k, [0, 0])[i] for r in runs)
                                       for i in (0, 1)]
                                   for k in sorted({k for r in runs for k in (r.get("detections_by_detector") or {})})},
        "centre_err_px_median": _pct(col("centre_err_px_median"), 50),
        "missed_moving": _sum_counts([r.get("missed_moving") for r in runs]),
        "closed_form_rot_err_deg_median": _pct(col("closed_form.rot_err_deg"), 50),
        "closed_form_rot_err_deg_p95": _pct(col("closed_form.rot_err_deg"), 95),
        "closed_form_abs_td_err_ms_median": _pct([abs(x) for x in col("closed_form.td_err_ms") if x is not None], 50),
        "closed_form_txy_err_m_median": _pct(col("closed_form.txy_err_m"), 50),
        "refined_rot_err_deg_median": _pct(col("refined.rot_err_deg"), 50),
        "refined_rot_err_deg_p95": _pct(col("refined.rot_err_deg"), 95),
        "refined_abs_td_err_ms_median": _pct([abs(x) for x in col("refined.td_err_ms") if x is not None], 50),
        "refined_abs_td_err_minus_lag_ms_median": _pct(
            [abs(r["refined"]["td_err_ms"] - r["detection_lag_ms"]) for r in runs
             if (r.get("refined") or {}).get("td_err_ms") is not None and r.get("detection_lag_ms") is not None], 50),
        "refined_txy_err_m_median": _pct(col("refined.txy_err_m"), 50),
        "refined_wheel_radius_abs_err_pct_median": _pct([abs(x) for x in col("refined.odometry.wheel_radius_err_pct")
                                                         if x is not None], 50),
        "refined_track_width_abs_err_pct_median": _pct([abs(x) for x in col("refined.odometry.track_width_err_pct")
                                                        if x is not None], 50),
        "odometry_z_within_3_fraction": {
            name: float(np.mean(np.abs(v) <= 3)) if v else None
            for name in ("wheel_radius", "track_width")
            for v in [[x for x in col(f"refined.odometry.{name}_z") if x is not None]]},
        "refined_not_worse_fraction": (sum(1 for c, f in pairs if f <= c) / len(pairs)) if pairs else None,
        "z_within_3_fraction": float(np.mean(np.abs(z) <= 3)) if z.size else None,
        "z_within_3_fraction_per_axis": {a: float(np.mean(np.abs(z[:, i]) <= 3)) for i, a in enumerate(AXES)}
        if z.size else {},
        "nees_rot_mean": float(np.mean([x for x in nees if x is not None])) if any(x is not None for x in nees)
        else None,
        "flagged": sum(1 for r in runs if r.get("flagged")),
    }


def _f(v, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def _mm(v) -> str:
    return "-" if v is None else f"{1e3 * v:.1f}"


def markdown(runs: list[dict], summary: dict, command: str, wall_s: float) -> str:
    lines = [f"# plsgraph validation study\n\n`{command}` — {len(runs)} runs, {wall_s / 60:.1f} min wall time\n",
             "## Summary\n", "| quantity | value |", "|---|---|"]
    for k, v in summary.items():
        if isinstance(v, dict):
            v = "; ".join(f"{a}: " + ", ".join(f"{b} {y}" for b, y in x.items()) if isinstance(x, dict)
                          else f"{a} {_f(x, '.2f') if isinstance(x, float) else x}" for a, x in v.items())
        elif isinstance(v, float):
            v = _f(v, ".4g")
        lines.append(f"| {k} | {v} |")
    lines += ["", "## Runs\n",
              "| # | effect | outcome | visible | detected | wrong | centre px | cf rot ° | ref rot ° | cf td ms "
              "| ref td ms | cf xy mm | ref xy mm | max abs z | s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(runs, key=lambda r: r["index"]):
        cf, ref = r.get("closed_form") or {}, r.get("refined") or {}
        zmax = max((abs(x) for x in (ref.get("z") or {}).values()), default=None)
        lines.append(
            f"| {r['index']} | {r['effect']} | {str(r.get('outcome', ''))[:40]} "
            f"| {_f(r.get('visible_fraction'), '.2f')} "
            f"| {_f(r.get('detected_fraction'), '.2f')} | {r.get('wrong_detections', '-')} "
            f"| {_f(r.get('centre_err_px_median'), '.2f')} | {_f(cf.get('rot_err_deg'))} "
            f"| {_f(ref.get('rot_err_deg'))} "
            f"| {_f(cf.get('td_err_ms'), '.2f')} | {_f(ref.get('td_err_ms'), '.2f')} "
            f"| {_f(None if cf.get('txy_err_m') is None else 1e3 * cf['txy_err_m'], '.1f')} "
            f"| {_f(None if ref.get('txy_err_m') is None else 1e3 * ref['txy_err_m'], '.1f')} "
            f"| {_f(zmax, '.1f')} | {_f(r.get('seconds'), '.0f')} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=30, help="runs (per effect with --ablation)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--quick", action="store_true", help="3 short runs (CI)")
    ap.add_argument("--only", help="switch one effect on over the ideal simulator (a name of realism.EFFECTS)")
    ap.add_argument("--ablation", action="store_true", help="every effect alone (--n runs each) plus the ideal base")
    ap.add_argument("--ideal", action="store_true", help="the ideal simulator only")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=20.0, help="seconds per recording (default 20)")
    ap.add_argument("--surface", default="count", help="front-end surface kind (plsgraph calibrate --surface)")
    ap.add_argument("--keep", action="store_true", help="keep the recordings in OUT/recordings")
    ap.add_argument("--force", action="store_true", help="overwrite OUT/study.json")
    ap.add_argument("--save-tracks", type=Path, metavar="DIR", help="keep each run's tracks as DIR/runNNN.pkl")
    ap.add_argument("--from-tracks", type=Path, metavar="DIR",
                    help="solve the tracks a --save-tracks study kept instead of simulating (refinement ablation)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="with --from-tracks: a RefinementOptions field changed (repeatable; odometry_noise takes a "
                         "dict of OdometryNoise fields)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from plsgraph.sim.realism import EFFECTS

    if a.n < 1 or a.workers < 1 or not a.duration > 1:
        ap.error("--n and --workers must be >= 1 and --duration > 1")
    if a.only and a.only not in EFFECTS:
        ap.error(f"unknown effect {a.only!r}; one of {', '.join(EFFECTS)}")
    if a.quick:
        a.n, a.duration = 3, 8.0
    a.out.mkdir(parents=True, exist_ok=True)
    if (a.out / "study.json").exists() and not a.force:
        ap.error(f"{a.out / 'study.json'} exists; pass --force or choose another --out")
    changes = _option_changes(a.set, ap) if a.set else {}
    if changes and a.from_tracks is None:
        ap.error("--set needs --from-tracks")
    saved = []
    if a.from_tracks is not None:
        saved = sorted(a.from_tracks.glob("run*.pkl"))
        if not saved:
            ap.error(f"no run*.pkl in {a.from_tracks}")
    tracks_dir = None
    if a.save_tracks is not None:
        a.save_tracks.mkdir(parents=True, exist_ok=True)
        tracks_dir = str(a.save_tracks)
    keep_dir = None
    if a.keep:
        keep_dir = str(a.out / "recordings")
        Path(keep_dir).mkdir(exist_ok=True)
    jobs = []
    worker = run_one
    if saved:
        worker = solve_saved
        jobs = [(str(p), changes) for p in saved]
    elif a.ablation:
        jobs += [(i, a.seed, "ideal", None, a.duration, keep_dir, a.surface, tracks_dir) for i in range(a.n)]
        for j, eff in enumerate(EFFECTS):
            jobs += [((j + 1) * 1000 + i, a.seed, "only", eff, a.duration, keep_dir, a.surface, tracks_dir)
                     for i in range(a.n)]
    else:
        kind = "only" if a.only else "ideal" if a.ideal else "drawn"
        jobs = [(i, a.seed, kind, a.only, a.duration, keep_dir, a.surface, tracks_dir) for i in range(a.n)]
    t0 = time.perf_counter()
    runs = []
    with ProcessPoolExecutor(max_workers=a.workers) as pool:
        futs = [pool.submit(worker, j) for j in jobs]
        for k, f in enumerate(as_completed(futs), 1):
            r = f.result()
            runs.append(r)
            cf, ref = r.get("closed_form") or {}, r.get("refined") or {}
            print(f"[{k}/{len(jobs)}] run {r['index']} {r['effect']}: {r.get('outcome')} detected "
                  f"{_f(r.get('detected_fraction'), '.2f')} cf {_f(cf.get('rot_err_deg'))} deg ref "
                  f"{_f(ref.get('rot_err_deg'))} deg ({r.get('seconds')} s)", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    runs.sort(key=lambda r: r["index"])
    command = "scripts/study.py " + " ".join(argv if argv is not None else sys.argv[1:])
    out = {"command": command, "wall_s": wall, "runs": runs}
    if a.ablation:
        groups: dict[str, list] = {}
        for r in runs:
            groups.setdefault(r["effect"], []).append(r)
        out["summary"] = {eff: summarize(rs) for eff, rs in groups.items()}
        md = [f"# plsgraph ablation\n\n`{command}` — {len(runs)} runs, {wall / 60:.1f} min wall time\n",
              "| effect | runs | outcomes | detected (median) | wrong | centre px | cf rot ° | ref rot ° | cf td ms "
              "| ref td ms | cf xy mm | ref xy mm | |z|<=3 |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for eff, s in out["summary"].items():
            oc = " ".join(f"{k}:{v}" for k, v in s["outcomes"].items() if v)
            md.append(
                f"| {eff} | {s['runs']} | {oc} | {_f(s['detected_fraction_median'], '.2f')} "
                f"| {_f(s['wrong_detection_rate'], '.4f')} | {_f(s['centre_err_px_median'], '.2f')} "
                f"| {_f(s['closed_form_rot_err_deg_median'])} | {_f(s['refined_rot_err_deg_median'])} "
                f"| {_f(s['closed_form_abs_td_err_ms_median'], '.2f')} "
                f"| {_f(s['refined_abs_td_err_ms_median'], '.2f')} "
                f"| {_mm(s['closed_form_txy_err_m_median'])} | {_mm(s['refined_txy_err_m_median'])} "
                f"| {_f(s['z_within_3_fraction'], '.2f')} |")
        text = "\n".join(md) + "\n"
    else:
        out["summary"] = summarize(runs)
        text = markdown(runs, out["summary"], command, wall)
    (a.out / "study.json").write_text(json.dumps(out, indent=1, default=float))
    (a.out / "study.md").write_text(text)
    print(text)
    print(f"written: {a.out / 'study.json'}, {a.out / 'study.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
