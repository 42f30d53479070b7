"""Throughput of each event representation (events/s, one core) on a DAVIS346-sized synthetic stream, and
speed of the event simulator.

Usage: .venv/bin/python scripts/bench_surfaces.py [--events 2000000] [--repeats 7] [--sim-seconds 2] [--no-sim]
       [--detect]
Prints medians over repeats. The surface stream is uniform random in space and time (the worst case for
cache locality); real streams cluster on edges. The simulator runs a DAVIS346 (346 x 260, preset intrinsics)
looking at the 4 x 11 circle board from 1 m while translating at 0.3 m/s and yawing at 0.4 rad/s, like the
robot does; it reports render rate, events/s of simulation and the real-time factor (wall time / simulated
time, < 1 is faster than real time). ``--detect`` also runs plsgraph.frontend.detect's circle-grid detector on each
representation of that simulated stream at 30 instants and reports the detection rate and the median
distance of the detected centres to the true projections at the surface's reference time.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from plsgraph.core.board import load_board  # noqa: E402
from plsgraph.core.camera import davis346_default  # noqa: E402
from plsgraph.core.events import EventStream  # noqa: E402
from plsgraph.core.geometry import make_T, so3_exp  # noqa: E402
from plsgraph.frontend import surfaces as S  # noqa: E402
from plsgraph.sim.events import EventSimParams, render_times, simulate_events  # noqa: E402
from plsgraph.sim.render import BoardRenderer  # noqa: E402

cv2.setNumThreads(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--sim-seconds", type=float, default=2.0)
    ap.add_argument("--sim-repeats", type=int, default=3)
    ap.add_argument("--no-sim", action="store_true")
    ap.add_argument("--detect", action="store_true")
    args = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f} (other processes on this machine slow every figure)")
    bench_surfaces(args)
    if not args.no_sim:
        bench_simulator(args)
    if args.detect:
        bench_detection(args)


def bench_surfaces(args: argparse.Namespace) -> None:
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


def robot_like_trajectory(duration: float, rate: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    board = load_board("acircles_4x11")
    c = board.points.mean(axis=0)
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    # Camera 1 m in front of the board, moving sideways and yawing back and forth (a sine, so it stays in view).
    x = 0.3 * duration / (2 * np.pi) * np.sin(2 * np.pi * t / duration)
    yaw = 0.4 * duration / (2 * np.pi) * np.sin(2 * np.pi * t / duration + 1.0)
    T = np.stack([make_T(so3_exp([0.0, a, 0.0]), c + [xi, 0.0, -1.0]) for xi, a in zip(x, yaw, strict=True)])
    return t + 1.7e9, T


def bench_simulator(args: argparse.Namespace) -> None:
    cam, board = davis346_default(), load_board("acircles_4x11")
    t, T = robot_like_trajectory(args.sim_seconds)
    params = EventSimParams()
    r = BoardRenderer(cam, board, params.render)
    r.log_intensity(T[0])
    dts = []
    for k in range(20):
        t0 = time.perf_counter()
        r.log_intensity(T[k])
        dts.append(time.perf_counter() - t0)
    n_render = render_times(t, T, cam, params).size
    walls, n_ev = [], 0
    for _ in range(args.sim_repeats):
        t0 = time.perf_counter()
        ev = simulate_events(t, T, cam, board, params, seed=0)
        walls.append(time.perf_counter() - t0)
        n_ev = len(ev)
    wall = float(np.median(walls))
    sim_s = t[-1] - t[0]
    print(f"\nsimulator: {cam.width} x {cam.height}, {sim_s:.1f} s simulated, median of {args.sim_repeats}")
    print(f"  one render (log intensity)   {np.median(dts) * 1e3:8.2f} ms")
    print(f"  renders (adaptive)           {n_render:8d}   ({n_render / sim_s:.0f} Hz)")
    print(f"  events                       {n_ev:8d}   ({n_ev / sim_s / 1e6:.2f} Mev/s of sensor time)")
    print(f"  wall time                    {wall:8.2f} s")
    print(f"  simulation speed             {n_ev / wall / 1e6:8.2f} Mev/s")
    print(f"  real-time factor             {wall / sim_s:8.2f}   (wall / simulated)")


def bench_detection(args: argparse.Namespace) -> None:
    from plsgraph.core.geometry import interpolate_poses, inv_T, transform_points
    from plsgraph.frontend.detect import detect_circle_grid

    cam, board = davis346_default(), load_board("acircles_4x11")
    t, T = robot_like_trajectory(args.sim_seconds)
    ev = simulate_events(t, T, cam, board, EventSimParams(), seed=0)
    tq = np.linspace(t[0] + 0.1, t[-1] - 0.01, 30)
    truth = interpolate_poses(tq, t, T)
    rims = dict(foreground="rims", rim_threshold=0.2)
    cases = {
        "leaky tau 50 ms": ("leaky", dict(tau_s=0.05), dict(foreground="dark")),
        "leaky tau 20 ms": ("leaky", dict(tau_s=0.02), dict(foreground="dark")),
        "time_surface any 30 ms": ("time_surface", dict(tau_s=0.03), rims),
        "polarity_aware 20 ms": ("polarity_aware", dict(window_ns=20_000_000), rims),
        "polarity_aware 10 ms": ("polarity_aware", dict(window_ns=10_000_000), rims),
        "count 20 ms": ("count", dict(window_ns=20_000_000), dict(foreground="rims")),
    }
    print(f"\ncircle-grid detection on simulated events ({len(ev)} events, {tq.size} instants)")
    print(f"{'representation':<26}{'detected':>10}{'median err px':>16}")
    for name, (kind, sp, dp) in cases.items():
        ok, errs = 0, []
        for tt, Tq in zip(tq, truth, strict=True):
            det = detect_circle_grid(S.surface_at(ev, int(round(tt * 1e9)), kind, **sp), board, cam, **dp)
            if det.ok:
                ok += 1
                uv = cam.project(transform_points(inv_T(Tq), board.points))
                errs.append(np.nanmedian(np.linalg.norm(det.uv - uv, axis=1)))
        err = f"{np.median(errs):.2f}" if errs else "-"
        print(f"{name:<26}{ok:>7}/{tq.size:<2}{err:>16}")


if __name__ == "__main__":
    main()
