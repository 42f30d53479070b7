"""Throughput of each event representation (events/s, one core) on a DAVIS346-sized synthetic stream.

Usage: .venv/bin/python scripts/bench_surfaces.py [--events 2000000] [--repeats 7]
Prints the median over repeats. The stream is uniform random in space and time (the worst case for
cache locality); real streams cluster on edges and run faster.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from plsgraph import surfaces as S  # noqa: E402
from plsgraph.events import EventStream  # noqa: E402

cv2.setNumThreads(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n, w, h = args.events, 346, 260
    t = np.sort(rng.integers(0, 100_000_000, n))
    s = EventStream.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n), w, h)
    cases = {
        "count": lambda: S.count_image(s),
        "polarity_sum": lambda: S.count_image(s, signed=True),
        "time_surface(on)": lambda: S.time_surface(s, tau_s=0.03, polarity="on"),
        "time_surface(any)": lambda: S.time_surface(s, tau_s=0.03, polarity="any"),
        "polarity_aware(pixel)": lambda: S.polarity_aware_surface(s),
        "polarity_aware(stream)": lambda: S.polarity_aware_surface(s, previous="stream"),
        "leaky": lambda: S.leaky_integrator(s, tau_s=0.05),
    }
    print(f"{n} events, {w} x {h} sensor, median of {args.repeats} repeats, numpy {np.__version__}")
    print(f"{'representation':<24}{'ms':>10}{'Mev/s':>10}")
    for name, f in cases.items():
        f()  # warm-up
        dts = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            f()
            dts.append(time.perf_counter() - t0)
        dt = float(np.median(dts))
        print(f"{name:<24}{dt * 1e3:>10.1f}{n / dt / 1e6:>10.1f}")


if __name__ == "__main__":
    main()
