#!/usr/bin/env python
"""Time per closed-form solve for n = 1e2, 1e4, 1e6 samples (median of repeats), on one core.

Usage: .venv/bin/python scripts/bench_closedform.py [--repeats 7]
"""

from __future__ import annotations

import os

# One core: pin the BLAS thread pools before numpy is imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from plsgraph.calib.solvers import excitation, hand_eye, solve  # noqa: E402
from plsgraph.core.geometry import inv_T, random_rotation_zyx, se3_exp  # noqa: E402

CASES = {
    "pls (default)": lambda X, Y, w: solve(X, Y, "pls"),
    "pls (paper=True)": lambda X, Y, w: solve(X, Y, "pls", paper=True),
    "pls (weighted)": lambda X, Y, w: solve(X, Y, "pls", weights=w),
    "cca": lambda X, Y, w: solve(X, Y, "cca"),
    "procrustes": lambda X, Y, w: solve(X, Y, "procrustes"),
    "excitation": lambda X, Y, w: excitation(X),
}


def median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    R = random_rotation_zyx(rng)
    sizes = [100, 10_000, 1_000_000]
    print(f"median time per call, {args.repeats} repeats, one BLAS thread")
    print(f"{'method':<20s}" + "".join(f"{'n=' + format(n, '.0e'):>14s}" for n in sizes))
    data = {}
    for n in sizes:
        X = rng.normal(size=(n, 3)) * [1.0, 0.6, 0.3] + [0.5, 0.0, 0.0]
        data[n] = (X, X @ R.T + rng.normal(scale=0.05, size=(n, 3)), rng.uniform(0.5, 1.5, n))
    for name, fn in CASES.items():
        cells = []
        for n in sizes:
            X, Y, w = data[n]
            t = median_time(lambda fn=fn, X=X, Y=Y, w=w: fn(X, Y, w), args.repeats if n > 10_000 else 50)
            cells.append(f"{t * 1e3:11.3f} ms")
        print(f"{name:<20s}" + "".join(f"{c:>14s}" for c in cells))
    # Hand-eye goes through OpenCV on pose pairs; its cost grows with the square of the (capped) pose count.
    for n in (20, 60):
        Twb = se3_exp(rng.normal(size=(n, 6)))
        X = se3_exp(rng.normal(size=6))
        Tbc = inv_T(se3_exp(rng.normal(size=6))) @ Twb @ X
        for m in ("andreff", "tsai"):
            t = median_time(lambda Twb=Twb, Tbc=Tbc, m=m: hand_eye(Twb, Tbc, m), args.repeats)
            print(f"hand_eye {m:<10s} {n:3d} poses: {t * 1e3:8.3f} ms")


if __name__ == "__main__":
    main()
