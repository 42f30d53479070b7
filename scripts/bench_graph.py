"""Benchmark of the GTSAM refinement: time per solve (including marginals) for 10 s, 60 s and 300 s recordings.

Simulated "rich" recordings, 30 Hz detections of the 44-point board, 50 Hz wheel odometry, knots at
10 Hz (the default). BLAS threads are limited to one and the process is pinned to one core; prints
medians over --repeat runs of the wall time and of the process CPU time (on a busy machine the CPU
time is the fairer figure; "marginals" is the final covariance only, the observability checks are in
the total).

    .venv/bin/python scripts/bench_graph.py [--durations 10 60 300] [--repeat 3] [--knot-rate 10]
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from plsgraph.core.geometry import make_T, rotation_error_deg, so3_exp  # noqa: E402
from plsgraph.frontend.pose import camera_track_from_detections  # noqa: E402
from plsgraph.odometry.wheels import base_track_from_wheels  # noqa: E402
from plsgraph.refine.graph import RefinementOptions, refine  # noqa: E402
from plsgraph.sim.robot import simulate_robot  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 60.0, 300.0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--knot-rate", type=float, default=10.0, help="knot rate in Hz; 0 = every odometry sample")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
        core = "pinned to one core"
    except (AttributeError, OSError):
        core = "not pinned"
    opt = RefinementOptions(knot_rate_hz=args.knot_rate or None)
    print(f"refinement benchmark ({core}, knots {args.knot_rate or 'all'} Hz, median of {args.repeat})")
    print(f"{'duration':>8} {'frames':>6} {'knots':>5} {'iters':>5} {'wall s':>7} {'cpu s':>6} {'optimize s':>10} "
          f"{'marginals s':>11} {'rot err deg':>11}")
    for dur in args.durations:
        rec = simulate_robot("rich", duration=dur, seed=args.seed, realism="ideal")
        base = base_track_from_wheels(rec.wheel_t, rec.wheel_left, rec.wheel_right, rec.wheel_radius, rec.track_width)
        track = camera_track_from_detections(rec.detections(0.3), rec.camera)
        seed_T = make_T(so3_exp(np.radians([1.0, -1.5, 2.0])) @ rec.T_base_cam[:3, :3], np.zeros(3))
        runs = []
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            res = refine(track, base, rec.camera, seed_T, rec.td + 0.005, opt)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            runs.append((wall, cpu, res.timing["optimize_s"], res.timing["marginals_s"]))
        med = np.median(np.array(runs), axis=0)
        err = rotation_error_deg(res.R_base_cam, rec.T_base_cam[:3, :3])
        print(f"{dur:8.0f} {res.n_frames:6d} {res.knot_t.size:5d} {res.iterations:5d} {med[0]:7.2f} {med[1]:6.2f} "
              f"{med[2]:10.2f} {med[3]:11.2f} {err:11.3f}")


if __name__ == "__main__":
    main()
