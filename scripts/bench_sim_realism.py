"""Cost and character of a realistic simulated recording (docs/simulation.md).

Prints the table of effects (parameter, unit, default, ideal, study range) and, for a few seeds, the time to
simulate the robot and the events of a ``--duration`` s realistic recording on one core, its event rate, the
share of camera frames with the whole board in view and the events of an ideal recording of the same seed.

    .venv/bin/python scripts/bench_sim_realism.py --duration 20 --seeds 1
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

from plsgraph.sim.realism import field_specs  # noqa: E402
from plsgraph.sim.robot import simulate_robot  # noqa: E402


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, tuple):
        return " .. ".join(_fmt(x) for x in v)
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--no-ideal", action="store_true", help="skip the ideal recording of each seed")
    args = ap.parse_args()

    print("| effect | parameter | unit | default | ideal | study range (draw) |")
    print("|---|---|---|---|---|---|")
    for r in field_specs():
        rng = f"{_fmt(r['range'])} ({r['draw']})" if r["range"] is not None else "-"
        print(f"| {r['effect']} | {r['group']}.{r['name']} | {r['unit']} | {_fmt(r['default'])} | "
              f"{_fmt(r['ideal'])} | {rng} |")
    print()
    for seed in range(args.seeds):
        t0 = time.perf_counter()
        rec = simulate_robot("rich", duration=args.duration, seed=seed)
        t1 = time.perf_counter()
        ev = rec.events(seed=seed)
        t2 = time.perf_counter()
        line = (f"seed {seed}: realistic {args.duration:g} s: robot {t1 - t0:.2f} s, events {t2 - t1:.1f} s, "
                f"{len(ev) / 1e6:.2f} M events ({len(ev) / args.duration / 1e6:.2f} M/s), "
                f"board fully in view in {100 * rec.info['visible_fraction']:.0f} % of frames")
        if not args.no_ideal:
            ideal = simulate_robot("rich", duration=args.duration, seed=seed, realism="ideal")
            t3 = time.perf_counter()
            ev_i = ideal.events(seed=seed)
            line += f"; ideal: events {time.perf_counter() - t3:.1f} s, {len(ev_i) / 1e6:.2f} M events"
        print(line, flush=True)


if __name__ == "__main__":
    main()
