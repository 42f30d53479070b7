"""End-to-end time of ``plsgraph calibrate`` on simulated recordings of growing length.

For each duration (default 10 s and 60 s) this simulates one "rich" recording (evt3 events, board
acircles_4x11_a2), then calibrates it ``--repeats`` times, each time in a fresh Python process so that the
peak RSS (getrusage ru_maxrss) belongs to that one calibration and not to the simulator or a previous run.
It prints medians: whole calibrate wall time, each stage of report["timing_s"], the remainder (writing
calibration.yaml, report.json, report.html and its PNGs), wall time / recording duration, peak RSS, and the
errors against the simulation truth.

Since calibrate streams the events through the front end (its "read" stage reads only the other topics, and the
"frontend" stage includes decoding the events), the ingest rate is measured apart: a separate fresh process
decodes the whole recording, events included, with plsgraph.io.recording.read_recording, once per repeat. The
front-end rate is events / "frontend" stage time (decoding + detection + PnP).

    .venv/bin/python scripts/bench_calibrate.py                       # 10 s and 60 s, 3 repeats
    .venv/bin/python scripts/bench_calibrate.py --durations 10 --repeats 1 --keep /tmp/bench

Only the calibration is timed; simulating the recording is reported separately and is not part of it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STAGES = ("read", "odometry", "frontend", "closed_form", "refinement")
BOARD = "acircles_4x11_a2"
TRUTH_KEYS = ("refined.rot_err_deg", "refined.t_xy_err_m", "refined.td_err_ms",
              "closed_form.pls.rot_err_deg", "closed_form.t_xy_err_m", "closed_form.td_err_ms")


def _worker(log: Path, truth: Path, out: Path) -> None:
    """One calibration in this (fresh) process; prints one JSON line with the figures."""
    from plsgraph.api import calibrate_to_dir
    from plsgraph.options import CalibrationOptions

    opts = CalibrationOptions.build(board=BOARD, truth=truth)
    t0 = time.perf_counter()
    res = calibrate_to_dir(log, out, opts, force=True)
    wall = time.perf_counter() - t0
    rep = res["report"]
    # ru_maxrss is in KiB on Linux (bytes on macOS).
    rss_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if sys.platform == "darwin":
        rss_kib //= 1024
    print(json.dumps({
        "ok": bool(res["ok"]),
        "wall_s": wall,
        "timing_s": rep.get("timing_s", {}),
        "events": (rep.get("recording_info") or {}).get("events"),
        "duration_s": (rep.get("recording_info") or {}).get("duration_s"),
        "camera_frames": (rep.get("counts") or {}).get("camera_frames"),
        "truth_errors": rep.get("truth_errors", {}),
        "problems": rep.get("problems", []),
        "peak_rss_mib": rss_kib / 1024.0,
    }))


def _ingest_worker(log: Path) -> None:
    """Decode the whole recording (events included) in this fresh process; one JSON line."""
    from plsgraph.io.recording import read_recording

    t0 = time.perf_counter()
    rec = read_recording(log)
    dt = time.perf_counter() - t0
    rss_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if sys.platform == "darwin":
        rss_kib //= 1024
    print(json.dumps({"ingest_s": dt, "events": 0 if rec.events is None else len(rec.events),
                      "peak_rss_mib": rss_kib / 1024.0}))


def _simulate(duration: float, folder: Path, seed: int) -> tuple[Path, Path, float]:
    log = folder / f"rich_{duration:g}s.mcap"
    cmd = [sys.executable, "-c", "import sys; from plsgraph.cli.main import main; sys.exit(main())", "simulate",
           "--ideal", "--motion", "rich", "--duration", f"{duration:g}", "--seed", str(seed), "--contrast", "0.45",
           "--event-format", "evt3", "--board", BOARD, "--out", str(log), "--force"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"simulating {log} failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    for line in proc.stderr.strip().splitlines():
        print(f"   simulate: {line}")
    return log, log.with_name(log.stem + ".truth.yaml"), time.perf_counter() - t0


def _calibrate_once(log: Path, truth: Path, out: Path) -> dict | str:
    """The worker's figures, or the reason it failed (its last stderr line)."""
    return _run_worker([sys.executable, __file__, "--_worker", str(log), str(truth), str(out)])


def _run_worker(cmd: list[str]) -> dict | str:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or ["(no message)"]
        return f"exit {proc.returncode}: {lines[-1]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def _bench_one(duration: float, folder: Path, repeats: int, seed: int) -> dict | None:
    log, truth, sim_s = _simulate(duration, folder, seed)
    size_mib = log.stat().st_size / 2**20
    print(f"\n== {duration:g} s rich recording: {log.name}, {size_mib:.1f} MiB (simulated in {sim_s:.1f} s)",
          flush=True)
    runs = []
    for i in range(repeats):
        r = _calibrate_once(log, truth, folder / f"calib_{duration:g}s")
        if isinstance(r, str):
            print(f"   calibration failed, {r}; no figures for {duration:g} s", flush=True)
            return None
        stage_sum = sum(r["timing_s"].get(s, 0.0) for s in STAGES)
        r["timing_s"]["write_and_rest"] = r["wall_s"] - stage_sum
        ing = _run_worker([sys.executable, __file__, "--_ingest", str(log)])
        if isinstance(ing, str):
            print(f"   ingest pass failed, {ing}", flush=True)
            ing = {"ingest_s": float("nan"), "peak_rss_mib": float("nan"), "events": 0}
        r["ingest"] = ing
        print(f"   run {i + 1}/{repeats}: calibrate {r['wall_s']:.2f} s wall, peak RSS {r['peak_rss_mib']:.0f} MiB, "
              f"ok={r['ok']}; decode-only pass {ing['ingest_s']:.2f} s, peak RSS {ing['peak_rss_mib']:.0f} MiB",
              flush=True)
        runs.append(r)
    med = {s: _median([r["timing_s"].get(s, float("nan")) for r in runs]) for s in (*STAGES, "write_and_rest")}
    rec_s = runs[0]["duration_s"] or duration
    events = runs[0]["events"] or runs[0]["ingest"]["events"] or 0
    ingest_s = _median([r["ingest"]["ingest_s"] for r in runs])
    wall = _median([r["wall_s"] for r in runs])
    return {
        "duration_s": rec_s,
        "file_mib": size_mib,
        "events": events,
        "camera_frames": runs[0]["camera_frames"],
        "wall_s": wall,
        "wall_min_s": min(r["wall_s"] for r in runs),
        "wall_max_s": max(r["wall_s"] for r in runs),
        "stages_s": med,
        "ingest_s": ingest_s,
        "ingest_rss_mib": _median([r["ingest"]["peak_rss_mib"] for r in runs]),
        "ingest_mev_s": events / ingest_s / 1e6 if ingest_s > 0 else float("nan"),
        "frontend_mev_s": events / med["frontend"] / 1e6 if med["frontend"] > 0 else float("nan"),
        "realtime_ratio": wall / rec_s,
        "peak_rss_mib": _median([r["peak_rss_mib"] for r in runs]),
        "truth_errors": {k: _median([r["truth_errors"][k] for r in runs if r["truth_errors"].get(k) is not None])
                         for k in TRUTH_KEYS},
        "ok": all(r["ok"] for r in runs),
        "problems": sorted({p for r in runs for p in r["problems"]}),
        "repeats": len(runs),
    }


def _print_table(results: list[dict]) -> None:
    cols = [f"{r['duration_s']:.1f} s" for r in results]
    rows: list[tuple[str, list[str]]] = [
        ("file size (MiB)", [f"{r['file_mib']:.1f}" for r in results]),
        ("events", [f"{r['events']:,}" for r in results]),
        ("camera frames detected", [str(r["camera_frames"]) for r in results]),
        ("calibrate wall, median (s)", [f"{r['wall_s']:.2f}" for r in results]),
        ("  min .. max (s)", [f"{r['wall_min_s']:.2f} .. {r['wall_max_s']:.2f}" for r in results]),
    ]
    names = {"read": "read (all but events)", "frontend": "frontend (decode+detect+PnP)"}
    rows += [(f"  {names.get(s, s)} (s)", [f"{r['stages_s'][s]:.2f}" for r in results]) for s in STAGES]
    rows += [
        ("  writing files/figures + rest (s)", [f"{r['stages_s']['write_and_rest']:.2f}" for r in results]),
        ("decode-only pass (s)", [f"{r['ingest_s']:.2f}" for r in results]),
        ("ingest, decode-only (M events/s)", [f"{r['ingest_mev_s']:.2f}" for r in results]),
        ("front end incl. decode (M events/s)", [f"{r['frontend_mev_s']:.2f}" for r in results]),
        ("wall / recording duration", [f"{r['realtime_ratio']:.2f}" for r in results]),
        ("peak RSS, calibrate (MiB)", [f"{r['peak_rss_mib']:.0f}" for r in results]),
        ("peak RSS, decode-only pass (MiB)", [f"{r['ingest_rss_mib']:.0f}" for r in results]),
    ]
    rows += [(f"{k}", [f"{r['truth_errors'][k]:.4g}" for r in results]) for k in TRUTH_KEYS]
    rows.append(("result ok (not flagged)", [str(r["ok"]) for r in results]))
    w0 = max(len(n) for n, _ in rows)
    w = [max(len(c), *(len(v[i]) for _, v in rows)) for i, c in enumerate(cols)]
    print("\n| " + "quantity".ljust(w0) + " | " + " | ".join(c.rjust(w[i]) for i, c in enumerate(cols)) + " |")
    print("|" + "-" * (w0 + 2) + "|" + "|".join("-" * (x + 2) for x in w) + "|")
    for name, vals in rows:
        print("| " + name.ljust(w0) + " | " + " | ".join(v.rjust(w[i]) for i, v in enumerate(vals)) + " |")
    for r in results:
        for p in r["problems"]:
            print(f"flagged ({r['duration_s']:.1f} s): {p}")


def main() -> int:
    if len(sys.argv) == 3 and sys.argv[1] == "--_ingest":
        _ingest_worker(Path(sys.argv[2]))
        return 0
    if len(sys.argv) == 5 and sys.argv[1] == "--_worker":
        _worker(Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--durations", type=float, nargs="+", default=[10.0, 60.0], help="recording lengths in s")
    ap.add_argument("--repeats", type=int, default=3, help="calibrations per recording (median reported)")
    ap.add_argument("--seed", type=int, default=3, help="simulation seed (default: %(default)s)")
    ap.add_argument("--keep", type=Path, help="keep recordings and outputs in this folder (default: temp, deleted)")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON to this file")
    args = ap.parse_args()
    if args.repeats < 1 or any(d <= 0 for d in args.durations):
        ap.error("--repeats must be >= 1 and durations > 0")
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        folder = args.keep
    else:
        folder = Path(tempfile.mkdtemp(prefix="bench_calibrate_"))
    load = os.getloadavg()
    print(f"bench_calibrate: durations {args.durations}, repeats {args.repeats}, {os.cpu_count()} CPUs, "
          f"load average at start {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    try:
        results = [r for d in args.durations if (r := _bench_one(d, folder, args.repeats, args.seed)) is not None]
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    if not results:
        print("no recording calibrated; nothing to report")
        return 1
    _print_table(results)
    load = os.getloadavg()
    print(f"\nload average at end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (other jobs on the machine inflate times)")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
