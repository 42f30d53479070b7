"""Accuracy of the GTSAM refinement against the closed form on simulated recordings, and what the
observability report says, for the rich / straight / spin motions over several seeds.

For each trial: simulate (plsgraph.sim.robot), wheel odometry -> BaseTrack, detections (0.3 px) -> PnP
camera track, closed form (plsgraph.calib.closed_form.calibrate_closed_form, PLS) -> seed, refine. Where the
closed form gives no rotation (straight, spin: it refuses degenerate motion) the seed is the truth
turned by 3 deg about a random axis with td off by 10 ms, and the table says so.

    .venv/bin/python scripts/measure_refinement.py [--duration 30] [--seeds 0 1 2 3] [--workers 2] [--slip 0.005]

Prints one row per trial and medians per motion (markdown), the numbers quoted in docs/refinement.md.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from plsgraph.refine.batch import refine_many


def trial(spec: tuple[str, float, int, float], seed: int) -> dict:
    """One simulated recording, closed form and refinement; returns the figures (runs in a worker)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from plsgraph.calib.closed_form import calibrate_closed_form
    from plsgraph.core.geometry import make_T, rotation_error_deg, so3_exp, so3_log
    from plsgraph.frontend.pose import camera_track_from_detections
    from plsgraph.odometry.wheels import base_track_from_wheels
    from plsgraph.refine.graph import refine
    from plsgraph.sim.robot import simulate_robot

    motion, duration, sim_seed, slip = spec
    rec = simulate_robot(motion, duration=duration, seed=sim_seed, slip=slip, realism="ideal")
    base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius, rec.track_width)
    track = camera_track_from_detections(rec.detections(0.3, seed=seed % 1000), rec.camera)
    R_true, t_true = rec.T_base_cam[:3, :3], rec.T_base_cam[:3, 3]
    cf = calibrate_closed_form(track, base)
    if cf.R_base_cam is not None:
        seed_kind = "closed form (pls)"
        R0 = cf.R_base_cam
        t0 = np.nan_to_num(cf.t_base_cam, nan=0.0) if cf.t_base_cam is not None else np.zeros(3)
        td0 = cf.td
    else:
        rng = np.random.default_rng(seed)
        axis = rng.normal(size=3)
        R0 = so3_exp(np.radians(3.0) * axis / np.linalg.norm(axis)) @ R_true
        t0, td0 = np.zeros(3), rec.td + 0.010
        seed_kind = "truth + 3 deg (closed form refused)"
    t_start = time.perf_counter()
    res = refine(track, base, rec.camera, make_T(R0, t0), td0)
    secs = time.perf_counter() - t_start
    d = np.degrees(so3_log(res.R_base_cam @ R_true.T))
    rep = res.observability
    out = {
        "motion": motion,
        "seed": sim_seed,
        "seed_kind": seed_kind,
        "converged": res.converged,
        "rot_err_seed_deg": float(rotation_error_deg(R0, R_true)),
        "rot_err_refined_deg": float(rotation_error_deg(res.R_base_cam, R_true)),
        "rot_err_axes_deg": d.round(4).tolist(),
        "td_err_seed_ms": 1e3 * (td0 - rec.td),
        "td_err_refined_ms": 1e3 * (res.td - rec.td),
        "txy_err_seed_m": float(np.linalg.norm(t0[:2] - t_true[:2])),
        "txy_err_refined_m": float(np.linalg.norm(res.T_base_cam[:2, 3] - t_true[:2])),
        "rms_px": res.rms_px_final,
        "seconds": secs,
        "unobservable": list(rep.unobservable) if rep else [],
        "weak": list(rep.weak) if rep else [],
    }
    if res.cov_base_axes is not None:
        out["sigma_rot_deg"] = res.sigma_rot_deg.round(4).tolist()
        out["sigma_td_ms"] = 1e3 * res.sigma_td
        out["td_z"] = (res.td - rec.td) / res.sigma_td
        out["rot_z"] = (np.abs(d) / res.sigma_rot_deg).round(2).tolist()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--motions", nargs="+", default=["rich", "straight", "spin"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--slip", type=float, default=0.005, help="wheel slip of the simulation (0.005 = 0.5 %%)")
    args = ap.parse_args()
    specs = [(m, args.duration, s, args.slip) for m in args.motions for s in args.seeds]
    t0 = time.perf_counter()
    results = refine_many(specs, trial, max_workers=args.workers, base_seed=2026)
    print(f"{len(specs)} trials of {args.duration:.0f} s (wheel slip {100 * args.slip:.2g} %) "
          f"in {time.perf_counter() - t0:.1f} s\n")
    print("| motion | seed | seed from | rot err seed / refined (deg) | err per axis roll,pitch,yaw (deg) "
          "| sigma per axis (deg) | td err seed / refined (ms) | sigma td (ms) | t_xy err seed / refined (m) "
          "| unobservable | weak | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for r in results:
        if not r.ok:
            print(f"| {specs[r.index][0]} | {specs[r.index][2]} | FAILED: {r.error_type}: {r.error} |")
            continue
        v = r.value
        rows.append(v)
        sig = v.get("sigma_rot_deg", ["-"] * 3)
        sig_td = f"{v['sigma_td_ms']:.2f}" if "sigma_td_ms" in v else "-"
        print(f"| {v['motion']} | {v['seed']} | {v['seed_kind']} | {v['rot_err_seed_deg']:.3f} / "
              f"{v['rot_err_refined_deg']:.3f} | {', '.join(f'{x:+.3f}' for x in v['rot_err_axes_deg'])} | "
              f"{', '.join(str(x) for x in sig)} | {v['td_err_seed_ms']:+.2f} / {v['td_err_refined_ms']:+.2f} | "
              f"{sig_td} | {v['txy_err_seed_m']:.3f} / {v['txy_err_refined_m']:.3f} | "
              f"{', '.join(v['unobservable'])} | {', '.join(v['weak'])} | {v['seconds']:.1f} |")
    print("\nMedians per motion:\n")
    print("| motion | n | rot err seed (deg) | rot err refined (deg) | abs td err seed (ms) | abs td err refined (ms) "
          "| t_xy err refined (m) | median abs(td err)/sigma |")
    print("|---|---|---|---|---|---|---|---|")
    for m in args.motions:
        sel = [v for v in rows if v["motion"] == m]
        if not sel:
            continue

        def med(key, f=lambda x: x, sel=sel):
            return float(np.median([f(v[key]) for v in sel if key in v]))

        tdz = med("td_z", abs) if any("td_z" in v for v in sel) else float("nan")
        print(f"| {m} | {len(sel)} | {med('rot_err_seed_deg'):.3f} | {med('rot_err_refined_deg'):.3f} | "
              f"{med('td_err_seed_ms', abs):.2f} | {med('td_err_refined_ms', abs):.2f} | "
              f"{med('txy_err_refined_m'):.3f} | {tdz:.2f} |")


if __name__ == "__main__":
    main()
