"""Is the refinement never worse than its seed, and do its sigmas cover its errors? Track-level study.

For N seeded realistic recordings (``plsgraph.sim.robot.simulate_robot(motion="rich")`` with every robot and
scene effect drawn by ``plsgraph.sim.realism.draw_realism``): the wheel odometry is integrated with the NOMINAL
wheel radius and track width (as a user would), the simulator's ideal detections get what the event front end
adds (a lag of 0.1-1 ms, correlated noise over consecutive windows, a smear along the image motion), PnP gives
the camera track, and ``plsgraph.pipeline.run_tracks`` runs the closed form and the refinement. No events are
simulated.

    PYTHONPATH=. .venv/bin/python scripts/measure_refinement_honesty.py [--n 30] [--duration 20] [--first 0]
        [--ideal-detections] [--set name=value ...] [--json out.json]

``--set`` passes refinement options (e.g. ``--set estimate_odometry_scale=False``) for ablations. Prints one
row per case, then the accuracy table (median / 95th percentile), the honesty table (share of (case, axis)
pairs with |error| <= 3 sigma, mean rotation NEES) and how often the refinement is worse than its seed.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import logging

import numpy as np

logging.disable(logging.WARNING)

AXES = ("roll", "pitch", "yaw", "x", "y", "td")


def frontend_detections(rec, rng: np.random.Generator, ideal: bool = False):
    """The simulator's detections with what an event front end adds (docs/refinement.md, "Honesty").

    * lag: an event window's detection shows the board ``lag`` (0.1-1 ms, log-uniform) earlier than its stamp;
    * correlated noise: each point's error is an AR(1) process over consecutive windows (correlation 0.8,
      0.25 px), plus a per-window common shift (AR(1), 0.1 px) and white noise 0.2 px;
    * smear: a per-window random fraction (AR(1), 2 % std) of the image motion over one 33 ms window, along it.
    """
    from plsgraph.core.tracks import Detections

    uv, inside = rec.project_truth()
    m, n = uv.shape[:2]
    if ideal:
        out = uv + rng.normal(0.0, 0.3, uv.shape)
        out[~inside] = np.nan
        return Detections(rec.cam_t, out, rec.board.points), 0.0
    lag = float(np.exp(rng.uniform(np.log(1e-4), np.log(1e-3))))
    t = rec.cam_t
    # Image velocity of every point from the truth (central differences on a 1 ms step).
    rec_uv = []
    for dt in (-5e-4, 5e-4):
        T_cb = rec.camera_poses_at(t + dt)
        from plsgraph.core.geometry import inv_T

        Tcb = inv_T(T_cb)
        pts = rec.board_true.points
        pc = np.einsum("mij,nj->mni", Tcb[:, :3, :3], pts) + Tcb[:, None, :3, 3]
        pc[..., 2] = np.maximum(pc[..., 2], 1e-3)
        rec_uv.append(rec.camera.project(pc.reshape(-1, 3)).reshape(m, n, 2))
    uv_dot = (rec_uv[1] - rec_uv[0]) / 1e-3

    def ar1(shape, rho, sigma):
        x = np.zeros(shape)
        e = rng.normal(0.0, sigma, shape)
        x[0] = e[0]
        for i in range(1, shape[0]):
            x[i] = rho * x[i - 1] + np.sqrt(1 - rho**2) * e[i]
        return x

    noise = ar1((m, n, 2), 0.8, 0.25) + ar1((m, 1, 2), 0.8, 0.1) + rng.normal(0.0, 0.2, (m, n, 2))
    smear = ar1((m, 1, 1), 0.8, 0.02) * (1.0 / 30.0)
    out = uv - lag * uv_dot + smear * uv_dot + noise
    out[~inside] = np.nan
    return Detections(rec.cam_t, out, rec.board.points), lag


def rotation_error_axes(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Error rotation about base x, y, z (rad): Log(R_est R_true^T) (left, base axes)."""
    from plsgraph.core.geometry import so3_log

    return so3_log(R_est @ R_true.T)


def one_case(i: int, duration: float, ideal_det: bool, refine_settings: dict, closed_form_only=False) -> dict:
    from plsgraph.core.geometry import rotation_error_deg
    from plsgraph.frontend.pose import camera_track_from_detections
    from plsgraph.odometry.wheels import base_track_from_wheels
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import run_tracks
    from plsgraph.result import calibration_result
    from plsgraph.sim.realism import draw_realism
    from plsgraph.sim.robot import simulate_robot

    rng = np.random.default_rng([i, 11])
    rec = simulate_robot("rich", duration=duration, seed=i, realism=draw_realism(rng))
    base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius_nominal,
                                  rec.track_width_nominal)
    det, lag = frontend_detections(rec, rng, ideal_det)
    track = camera_track_from_detections(det, rec.camera)
    opts = CalibrationOptions.build(board="acircles_4x11")
    t0 = time.perf_counter()
    import plsgraph.refine.graph as graph

    if refine_settings:  # ablation: run_refinement builds its RefinementOptions through this name
        base_options = getattr(graph, "_BASE_OPTIONS", graph.RefinementOptions)
        graph._BASE_OPTIONS = base_options
        graph.RefinementOptions = lambda **kw: base_options(**{**kw, **refine_settings})
    run = run_tracks(track, base, rec.camera, opts, refine=not closed_form_only,
                     truth={"T_base_cam": rec.T_base_cam, "td": rec.td})
    res = calibration_result(run)
    secs = time.perf_counter() - t0
    T_true = rec.T_base_cam
    cf = run.closed_form
    ref = run.refinement
    out: dict = {"case": i, "lag_ms": 1e3 * lag, "seconds": secs, "ok": res.ok,
                 "track_ratio": rec.track_width / rec.track_width_nominal,
                 "cf_rot_deg": float(rotation_error_deg(cf.R_base_cam, T_true[:3, :3])),
                 "cf_txy_mm": 1e3 * float(np.linalg.norm(np.asarray(cf.t_xy) - T_true[:2, 3])),
                 "cf_td_ms": 1e3 * (cf.td - rec.td)}
    if ref is None:
        return out
    e_rot = rotation_error_axes(ref.R_base_cam, T_true[:3, :3])
    e = np.r_[e_rot, ref.T_base_cam[:2, 3] - T_true[:2, 3], ref.td - rec.td]
    out.update({
        "converged": bool(ref.converged),
        "rot_deg": float(rotation_error_deg(ref.R_base_cam, T_true[:3, :3])),
        "txy_mm": 1e3 * float(np.linalg.norm(ref.T_base_cam[:2, 3] - T_true[:2, 3])),
        "td_ms": 1e3 * (ref.td - rec.td),
        "err": e.tolist(),
    })
    scale = getattr(ref, "odometry", None)
    if scale:
        out["radius_err_pct"] = 100 * (scale["wheel_radius_m"] / rec.wheel_radius - 1)
        out["track_err_pct"] = 100 * (scale["track_width_m"] / rec.track_width - 1)
    if ref.cov_base_axes is not None:
        C = ref.cov_base_axes
        idx = [0, 1, 2, 3, 4, 6]
        sig = np.sqrt(np.diag(C)[idx])
        out["sigma"] = sig.tolist()
        out["z"] = (e / sig).tolist()
        out["nees_rot"] = float(e_rot @ np.linalg.solve(C[:3, :3], e_rot))
    out["disagreement"] = dict(getattr(ref, "disagreement", {}) or {})
    return out


def summarize(rows: list[dict]) -> str:
    lines = []
    good = [r for r in rows if "rot_deg" in r]

    def q(key, p):
        v = np.array([abs(r[key]) for r in good if key in r])
        return float(np.percentile(v, p)) if v.size else float("nan")

    lines.append("| quantity | closed form median | refined median | refined p95 | target |")
    lines.append("|---|---|---|---|---|")
    cfv = {k: np.array([abs(r[k]) for r in good]) for k in ("cf_rot_deg", "cf_txy_mm", "cf_td_ms")}
    lines.append(f"| rotation (deg) | {np.median(cfv['cf_rot_deg']):.3f} | {q('rot_deg', 50):.3f} | "
                 f"{q('rot_deg', 95):.3f} | median <= 0.08, p95 <= 0.25 |")
    lines.append(f"| t_xy (mm) | {np.median(cfv['cf_txy_mm']):.1f} | {q('txy_mm', 50):.1f} | {q('txy_mm', 95):.1f} "
                 "| median <= 3 |")
    lines.append(f"| abs td (ms) | {np.median(cfv['cf_td_ms']):.2f} | {q('td_ms', 50):.2f} | {q('td_ms', 95):.2f} "
                 "| median <= 0.5 |")
    if any("radius_err_pct" in r for r in good):
        lines.append(f"| abs wheel radius error (%) | - | {q('radius_err_pct', 50):.2f} | "
                     f"{q('radius_err_pct', 95):.2f} | within 1 |")
        lines.append(f"| abs track width error (%) | - | {q('track_err_pct', 50):.2f} | "
                     f"{q('track_err_pct', 95):.2f} | within 2 |")
    worse_rot = np.mean([r["rot_deg"] > r["cf_rot_deg"] for r in good])
    worse_txy = np.mean([r["txy_mm"] > r["cf_txy_mm"] for r in good])
    worse_td = np.mean([abs(r["td_ms"]) > abs(r["cf_td_ms"]) for r in good])
    lines.append("")
    lines.append(f"refined worse than the closed form: rotation {100 * worse_rot:.0f} %, t_xy {100 * worse_txy:.0f} %, "
                 f"td {100 * worse_td:.0f} % of {len(good)} cases (target: rotation <= 10 %)")
    with_sig = [r for r in good if "z" in r]
    if with_sig:
        Z = np.abs(np.array([r["z"] for r in with_sig]))
        cover = (Z <= 3).mean(axis=0)
        lines.append("")
        lines.append("| | " + " | ".join(AXES) + " | all |")
        lines.append("|---|" + "---|" * (len(AXES) + 1))
        lines.append("| share abs(err) <= 3 sigma | " + " | ".join(f"{100 * c:.0f} %" for c in cover)
                     + f" | {100 * (Z <= 3).mean():.1f} % |")
        lines.append("| median abs(err)/sigma | " + " | ".join(f"{v:.2f}" for v in np.median(Z, axis=0)) + " | |")
        nees = np.array([r["nees_rot"] for r in with_sig])
        lines.append("")
        lines.append(f"mean rotation NEES {nees.mean():.2f} (median {np.median(nees):.2f}; target 1.5 .. 6); "
                     f"flagged not ok: {sum(not r['ok'] for r in good)} of {len(good)}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--ideal-detections", action="store_true", help="white 0.3 px noise, no lag (the simulator's)")
    ap.add_argument("--set", nargs="*", default=[], help="refinement options name=value (ablation)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args()
    settings = {}
    for kv in a.set:
        k, v = kv.split("=", 1)
        try:
            settings[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            settings[k] = v
    rows = []
    t0 = time.perf_counter()
    for i in range(a.first, a.first + a.n):
        try:
            r = one_case(i, a.duration, a.ideal_detections, settings)
        except Exception as exc:  # a failing case is a finding, not a crash of the study
            r = {"case": i, "error": f"{type(exc).__name__}: {exc}"}
        rows.append(r)
        if not a.quiet:
            if "rot_deg" in r:
                z = r.get("z")
                zs = "" if z is None else " z " + " ".join(f"{v:+.1f}" for v in z)
                extra = ""
                if "radius_err_pct" in r:
                    extra = f" r {r['radius_err_pct']:+.2f}% b {r['track_err_pct']:+.2f}%"
                print(f"case {i:3d}: rot {r['cf_rot_deg']:.3f}->{r['rot_deg']:.3f} deg  txy {r['cf_txy_mm']:.1f}->"
                      f"{r['txy_mm']:.1f} mm  td {r['cf_td_ms']:+.2f}->{r['td_ms']:+.2f} ms{extra}{zs}"
                      f"  ok={r['ok']} {r['seconds']:.1f}s", flush=True)
            else:
                print(f"case {i:3d}: {r.get('error', 'no refinement')}", flush=True)
    print()
    print(f"{a.n} cases, {a.duration:.0f} s rich motion, realism drawn, "
          f"{'ideal' if a.ideal_detections else 'front-end-like'} detections, options {settings or 'default'}; "
          f"{time.perf_counter() - t0:.0f} s")
    print()
    print(summarize(rows))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
