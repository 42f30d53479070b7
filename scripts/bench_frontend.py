#!/usr/bin/env python3
"""Throughput of the whole event front end (surfaces + circle-grid detection + PnP at 30 Hz).

A simulated recording of the board moving in front of the camera (speed chosen so that it produces
more than the target rate) is brought to exactly the target event rate (default 2 million events/s)
by random thinning (or, if it produced fewer, by adding uniform noise events, which is harsh: a
detector sees 0.5 M noise events/s as snow over the whole image), and camera_track_from_events is
timed for each surface kind.
Prints medians over repeats of wall time and process CPU time (the machine may be shared: CPU time
is the fairer figure then; with workers > 1 only the parent's CPU time is counted, so read the wall
time there), the real-time factor (stream duration / processing time) and where the
time goes.

Usage: .venv/bin/python scripts/bench_frontend.py [--rate 2e6] [--duration 1.0] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from measure_frontend import board_motion, simulate_board_events  # noqa: E402

from plsgraph.core.board import load_board  # noqa: E402
from plsgraph.core.camera import davis346_default  # noqa: E402
from plsgraph.core.events import EventStream  # noqa: E402
from plsgraph.frontend.track import camera_track_from_events  # noqa: E402


def stream_at_rate(ev: EventStream, rate: float, seed: int = 0) -> EventStream:
    rng = np.random.default_rng(seed)
    dur = ev.duration_s
    want = int(round(rate * dur))
    if len(ev) >= want:
        keep = np.sort(rng.choice(len(ev), want, replace=False))
        return ev.slice_index(0, len(ev)) if want == len(ev) else EventStream(
            ev.t[keep], ev.x[keep], ev.y[keep], ev.p[keep], ev.width, ev.height
        )
    m = want - len(ev)
    t = np.r_[ev.t, rng.integers(ev.t_first, ev.t_last + 1, m)]
    x = np.r_[ev.x, rng.integers(0, ev.width, m)]
    y = np.r_[ev.y, rng.integers(0, ev.height, m)]
    p = np.r_[ev.p, rng.choice(np.array([-1, 1], np.int8), m)]
    o = np.argsort(t, kind="stable")
    return EventStream.from_arrays(t[o], x[o], y[o], p[o], ev.width, ev.height)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=2e6, help="events per second of the benchmark stream")
    ap.add_argument("--duration", type=float, default=1.0, help="seconds of simulated recording")
    ap.add_argument("--speed", type=float, default=1.5, help="motion speed factor (see measure_frontend)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kinds", default="count,time_surface,polarity_aware")
    ap.add_argument("--workers", default="1", help="comma-separated worker counts to time, e.g. 1,2")
    args = ap.parse_args()
    cam = davis346_default()
    board = load_board("acircles_4x11")
    t, poses = board_motion(board, args.speed, args.duration, 1e-3)
    c0 = time.perf_counter()
    sim = simulate_board_events(poses, t, cam, board)
    rate0 = len(sim) / sim.duration_s / 1e6
    print(f"simulated {len(sim)} events ({rate0:.2f} Mev/s) in {time.perf_counter() - c0:.1f} s")
    ev = stream_at_rate(sim, args.rate)
    dur = ev.duration_s
    print(f"benchmark stream: {len(ev)} events over {dur:.3f} s = {len(ev) / dur / 1e6:.2f} Mev/s; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'kind':<16} {'workers':>7} {'wall s':>7} {'cpu s':>7} {'x real (wall)':>13} {'x real (cpu)':>12} "
          f"{'Mev/s (cpu)':>11} {'poses':>6}  surfaces/detection/pnp share")
    for kind, workers in [(k, int(w)) for k in args.kinds.split(",") for w in args.workers.split(",")]:
        walls, cpus, parts = [], [], []
        for _ in range(args.repeats):
            w0, p0 = time.perf_counter(), time.process_time()
            tr = camera_track_from_events(ev, cam, board, 30.0, kind, workers=workers)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - p0)
            parts.append([tr.info["seconds"].get(k, 0.0) for k in ("surfaces", "detection", "pnp")])
        w, c = float(np.median(walls)), float(np.median(cpus))
        sh = np.median(np.array(parts), axis=0)
        sh = sh / max(sh.sum(), 1e-12)
        print(f"{kind:<16} {workers:>7} {w:>7.3f} {c:>7.3f} {dur / w:>13.1f} {dur / c:>12.1f} "
              f"{len(ev) / c / 1e6:>11.2f} {len(tr):>6}  {sh[0]:.2f}/{sh[1]:.2f}/{sh[2]:.2f}")


if __name__ == "__main__":
    main()
