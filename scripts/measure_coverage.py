#!/usr/bin/env python3
"""Front-end coverage on the study's recordings, by how fast the board moves across the image, for the default
front end and for variants of its settings, in one run (the figures of docs/frontend.md).

    scripts/measure_coverage.py --runs 0 2 3 5 6 12 21 25 --variant hot_off:MASK_HOT_PIXELS=False

Each run index draws the same recording as ``scripts/study.py`` (same seed, realism and td), written once to
``--cache`` and reused. A variant is ``label:NAME=VALUE[;NAME=VALUE...]`` with NAME a module constant of
``plsgraph.frontend.track`` (e.g. ``WINDOW_LADDER=(1.0,0.5,0.25,0.125,2.0,4.0)``) or, prefixed with its module's
name, of another front-end module (``detect.TRACK_BEFORE_LABEL=False``); every variant and the
defaults run on each recording in turn, so a busy machine slows all of them alike. Printed per setting: coverage
(share of the 30 Hz windows with the whole board in view that have a detection; "slow" below 20 px/s), wrong
labels (median point error over 5 px), median centre error (all detections; those of slow boards), and the
front end's seconds; each run's JSON line also has ``by_speed``, [found, in-view windows] per image-speed bin
(SPEED_BINS, px/s).
"""

from __future__ import annotations

import argparse
import ast
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import study  # noqa: E402

SLOW_PX_S = 20.0
#: Image speed bins (px/s) of the per-bin coverage ``by_speed``: [found, in-view windows] per bin.
SPEED_BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 5.0), (5.0, 20.0), (20.0, np.inf))


def recording(index: int, cache: Path, duration: float) -> Path:
    """The study's recording ``index`` (base seed 0) in ``cache``: rec.mcap, its truth file and the simulator."""
    from plsgraph.api import simulate_recording
    from plsgraph.io.writer import write_recording, write_truth

    d = cache / f"run{index:03d}_{duration:g}s"
    if (d / "sim.pkl").exists():
        return d
    d.mkdir(parents=True, exist_ok=True)
    seed = int(np.random.SeedSequence([0, index]).generate_state(1)[0] % (2**31))
    rng = np.random.default_rng(seed)
    realism = study._realism("drawn", None, rng)
    td = float(rng.uniform(-0.1, 0.1))
    rec = simulate_recording("rich", duration, seed, td, study.BOARD, realism=realism)
    write_recording(d / "rec.mcap", rec.events, rec.joints, None, rec.sim.camera, truth=None, event_format="evt3",
                    overwrite=True)
    write_truth(d / "rec.mcap", rec.truth)
    with open(d / "sim.part", "wb") as f:
        pickle.dump((rec.sim, rec.epoch_ns, dict(rec.truth)), f)
    (d / "sim.part").rename(d / "sim.pkl")
    return d


def parse_variant(text: str) -> tuple[str, dict]:
    label, _, body = text.partition(":")
    if not body:
        raise SystemExit(f"--variant: expected label:NAME=VALUE[;...], got {text!r}")
    out = {}
    for item in body.split(";"):
        name, _, value = item.partition("=")
        out[name.strip()] = ast.literal_eval(value.strip())
    return label, out


def measure(d: Path, settings: dict) -> dict:
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, build_tracks

    targets = {k: _setting(k) for k in settings}
    saved = {k: getattr(m, name) for k, (m, name) in targets.items()}
    for k, v in settings.items():
        setattr(*targets[k], v)
    try:
        with open(d / "sim.pkl", "rb") as f:
            sim, epoch_ns, truth = pickle.load(f)
        opts = CalibrationOptions.build(board=study.BOARD, wheel_radius=truth["wheel_radius_nominal"],
                                        track_width=truth["track_width_nominal"], frontend_workers=1)
        run = Run(d / "rec.mcap", opts)
        t0 = time.perf_counter()
        build_tracks(run)
        seconds = time.perf_counter() - t0
    finally:
        for k, v in saved.items():
            setattr(*targets[k], v)
    ct = run.camera_track
    wo = ct.info["window_outcomes"]
    t = np.asarray(wo["t"]) - epoch_ns * 1e-9
    found = np.isin(np.asarray(wo["outcome"]), ["rims", "blobs", "image"])
    in_view = study._board_in_view(sim, t)
    speed = _speed(sim, t)
    td = np.asarray(ct.detections.t) - epoch_ns * 1e-9
    err = np.nanmedian(np.linalg.norm(np.asarray(ct.detections.uv) - study._true_pixels(sim, td), axis=-1), axis=1)
    wrong = err > study.WRONG_PX
    slow_det = _speed(sim, td) < SLOW_PX_S
    bins = {}
    for lo, hi in SPEED_BINS:
        sel = in_view & (speed >= lo) & (speed < hi)
        bins[f"{lo:g}-{hi:g}"] = [int(found[sel].sum()), int(sel.sum())]
    return {"seconds": seconds, "coverage": float(found[in_view].mean()), "by_speed": bins,
            "coverage_slow": _mean(found[in_view & (speed < SLOW_PX_S)]),
            "coverage_fast": _mean(found[in_view & (speed >= SLOW_PX_S)]),
            "slow_share": _mean(speed[in_view] < SLOW_PX_S), "detections": int(len(err)), "wrong": int(wrong.sum()),
            "centre_px": float(np.median(err[~wrong])) if (~wrong).any() else None,
            "centre_px_slow": float(np.median(err[~wrong & slow_det])) if (~wrong & slow_det).any() else None,
            "hot_pixels": ct.info.get("hot_pixels")}


def _setting(name: str):
    """(module, constant) of a variant's NAME: a constant of plsgraph.frontend.track, or of another front-end
    module when prefixed with its name (``detect.TRACK_BEFORE_LABEL``)."""
    import importlib

    module, _, const = name.rpartition(".")
    m = importlib.import_module(f"plsgraph.frontend.{module or 'track'}")
    if not hasattr(m, const):
        raise SystemExit(f"{m.__name__} has no setting {const}")
    return m, const


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if x.size else None


def _speed(sim, t: np.ndarray) -> np.ndarray:
    """Median image speed of the board's points (px/s) at camera times ``t``."""
    t2 = np.minimum(t + 0.01, sim.truth_base.t[-1] - sim.td - 1e-4)
    d = np.linalg.norm(study._true_pixels(sim, t2) - study._true_pixels(sim, t), axis=-1)
    return np.median(d, axis=1) / np.maximum(t2 - t, 1e-4)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, nargs="+", default=list(range(8)))
    ap.add_argument("--variant", action="append", default=[], help="label:NAME=VALUE[;NAME=VALUE...]")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--cache", type=Path, default=REPO / "out" / "coverage_cache")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    args = ap.parse_args()
    settings = [("defaults", {})] + [parse_variant(v) for v in args.variant]
    rows = []
    for i in args.runs:
        d = recording(i, args.cache, args.duration)
        for label, s in settings:
            r = {"run": i, "setting": label, **measure(d, s)}
            rows.append(r)
            print(json.dumps(r), flush=True)
    print()
    print("| setting | coverage median (runs) | slow boards | fast boards | wrong | centre px | slow centre px | "
          "front end s (median) |")
    print("|---|---|---|---|---|---|---|---|")
    for label, _ in settings:
        rs = [r for r in rows if r["setting"] == label]

        def med(key, rs=rs):
            v = [r[key] for r in rs if r[key] is not None]
            return float(np.median(v)) if v else float("nan")

        print(f"| {label} | {med('coverage'):.2f} | {med('coverage_slow'):.2f} | {med('coverage_fast'):.2f} | "
              f"{sum(r['wrong'] for r in rs)} of {sum(r['detections'] for r in rs)} | {med('centre_px'):.3f} | "
              f"{med('centre_px_slow'):.3f} | {med('seconds'):.1f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
