#!/usr/bin/env python3
"""The front end alone on the recordings a study kept: coverage, wrong labels, centre error, time.

    scripts/study.py --n 6 --duration 12 --keep --out /tmp/fe_dev --seed 11      # once: the recordings
    scripts/measure_detection.py --study /tmp/fe_dev --seed 11                    # then, after every change

For every kept recording (``OUT/recordings/*/runNNN.mcap``) the events are read once and cached as .npz next to
it; the truth geometry is rebuilt from the run's seed exactly as ``scripts/study.py`` draws it (the robot is
simulated again, the events are not). The front end runs as the pipeline runs it (streamed in spans,
``camera_track_from_event_chunks`` with the given surface), and is scored with the study's own metric
(``study._frontend_metrics``): share of the in-view 30 Hz windows with a detection, detections whose median
point error exceeds 5 px (wrong labels), the median point error of the others, and the front end's seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))


def _events(mcap: Path):
    from plsgraph.core.events import EventStream
    from plsgraph.io.events_reader import read_events

    cache = mcap.with_suffix(".events.npz")
    if cache.exists():
        z = np.load(cache)
        return EventStream(z["t"], z["x"], z["y"], z["p"], int(z["w"]), int(z["h"]))
    ev = read_events(mcap)
    np.savez(cache, t=ev.t, x=ev.x, y=ev.y, p=ev.p, w=ev.width, h=ev.height)
    return ev


def _truth(index: int, base_seed: int, duration: float):
    """The run's SimRecording without events (robot, camera, board), as study.run_one draws it."""
    from study import BOARD, _realism

    from plsgraph.core.board import load_board
    from plsgraph.sim.robot import simulate_robot

    seed = int(np.random.SeedSequence([base_seed, index]).generate_state(1)[0] % (2**31))
    rng = np.random.default_rng(seed)
    realism = _realism("drawn", None, rng)
    td = float(rng.uniform(-0.1, 0.1))
    return simulate_robot(motion="rich", duration=duration, seed=seed, td=td, board=load_board(BOARD),
                          realism=realism), realism


class _Rec:
    def __init__(self, sim, events, epoch_ns):
        self.sim, self.events, self.epoch_ns = sim, events, epoch_ns


class _Run:
    def __init__(self, track):
        self.camera_track = track


def measure(mcap: Path, index: int, base_seed: int, duration: float, kind: str, **options) -> dict:
    from study import _frontend_metrics

    from plsgraph.api import SIM_EPOCH_NS
    from plsgraph.errors import InsufficientDataError
    from plsgraph.frontend.track import camera_track_from_event_chunks

    ev = _events(mcap)
    sim, realism = _truth(index, base_seed, duration)
    chunk = 1_000_000
    chunks = (ev.slice_index(i, min(len(ev), i + chunk)) for i in range(0, len(ev), chunk))
    t0 = time.perf_counter()
    track = None
    try:
        track = camera_track_from_event_chunks(chunks, sim.camera, sim.board, rate_hz=30.0, kind=kind, **options)
        info = track.info
    except InsufficientDataError as exc:
        info = {"skipped": str(exc)}
    secs = time.perf_counter() - t0
    row = {"index": index, "events": len(ev), "rate_mev_s": len(ev) / max(1e-9, (ev.t_last - ev.t_first) * 1e-9) / 1e6,
           "seconds": round(secs, 2), "board_distance_m": realism.scene.board_distance_m}
    row.update(_frontend_metrics(_Rec(sim, ev, SIM_EPOCH_NS), _Run(track)))
    row["skipped"] = info.get("skipped")
    row["frontend_seconds"] = info.get("seconds")
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--study", type=Path, required=True, help="a study's --out with --keep")
    ap.add_argument("--seed", type=int, default=0, help="the study's --seed")
    ap.add_argument("--duration", type=float, default=12.0, help="the study's --duration")
    ap.add_argument("--kind", default="count", help="surface kind (default: the pipeline's)")
    ap.add_argument("--only", default=None, help="comma-separated run indices")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    a = ap.parse_args(argv)
    mcaps = sorted(a.study.glob("recordings/*/run*.mcap"))
    rows = []
    only = None if a.only is None else {int(s) for s in a.only.split(",")}
    for m in mcaps:
        idx = int(m.stem[3:])
        if only is not None and idx not in only:
            continue
        r = measure(m, idx, a.seed, a.duration, a.kind)
        rows.append(r)
        ce = r.get("centre_err_px_median")
        print(f"run {idx:3d} {r['board_distance_m']:.2f} m {r['rate_mev_s']:.2f} Mev/s: in view "
              f"{r['windows_in_view']:4d}/{r['windows']:4d} detected {r['detected_fraction']:.3f} "
              f"wrong {r['wrong_detections']}/{r['detections']} centre {'-' if ce is None else f'{ce:.3f}'} px "
              f"{r['seconds']:.1f} s  {r['skipped']}", flush=True)
    if rows:
        fr = [r["detected_fraction"] for r in rows]
        dets = sum(r["detections"] for r in rows)
        wrong = sum(r["wrong_detections"] for r in rows)
        ce = [r["centre_err_px_median"] for r in rows if r["centre_err_px_median"] is not None]
        print(f"median detected {np.median(fr):.3f}  p10 {np.percentile(fr, 10):.3f}  wrong {wrong}/{dets}  "
              f"centre {np.median(ce) if ce else float('nan'):.3f} px  seconds {sum(r['seconds'] for r in rows):.1f}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
