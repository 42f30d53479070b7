"""End-to-end time of ``plsgraph calibrate`` on simulated recordings: the real-time factor and where the time goes.

For each duration (default 10 s and 60 s) this simulates one "rich" recording (evt3 events, board acircles_4x11_a2,
the ideal sensor unless --realistic), then calibrates it ``--repeats`` times, each time in a fresh Python process (as
``plsgraph calibrate --truth ... --force`` does, figures included), so that the process's wall time includes starting
Python and importing the package, and its peak RSS (getrusage ru_maxrss) belongs to that one calibration.

It prints medians: the whole process's wall time and the real-time factor (wall / recording duration; below 1 is
faster than real time), and where the time goes: start-up (Python, importing plsgraph), each stage of
report["timing_s"] (read, odometry, frontend, pairing, closed form, refinement), the figures (the time they held the
calibration up: drawing them, or waiting for the process that draws them), the rest (writing calibration.yaml,
report.json and the robot files) and ending the process. Also peak RSS, the errors against the simulation truth, and
the start-up of ``plsgraph --help`` and ``plsgraph inspect`` of the recording.

Since calibrate streams the events through the front end (its "read" stage reads only the other topics, and the
"frontend" stage includes decoding the events), the decoding rate is measured apart: a separate fresh process
decodes the whole recording, events included, with plsgraph.io.recording.read_recording, once per repeat.

``--baseline DIR`` times a second checkout (another commit's work tree) on the same recordings in the same run,
alternating (this tree, then DIR, for each repeat), and prints its figures beside this tree's with the ratio (this /
baseline; the wall ratio is the median of the ratios of each pair of runs, which holds up best when the machine's
speed drifts). Each side imports its own ``plsgraph`` (its folder goes first on PYTHONPATH).

    .venv/bin/python scripts/bench_calibrate.py                       # 10 s and 60 s, 3 repeats
    .venv/bin/python scripts/bench_calibrate.py --durations 20 --repeats 3 --baseline ../plsgraph-before
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

STAGES = ("read", "odometry", "frontend", "pairing", "closed_form", "refinement", "figures")
BOARD = "acircles_4x11_a2"
TRUTH_KEYS = ("refined.rot_err_deg", "refined.t_xy_err_m", "refined.td_err_ms",
              "closed_form.pls.rot_err_deg", "closed_form.t_xy_err_m", "closed_form.td_err_ms")
SCRIPT = str(Path(__file__).resolve())
THIS_TREE = Path(SCRIPT).parent.parent
# The plsgraph command as its console script runs it (older trees have main only).
CLI = ("import sys; import plsgraph.cli.main as m; "
       "m.run() if hasattr(m, 'run') else sys.exit(m.main())")


def _peak_rss_mib() -> float:
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    return (rss / 1024.0 if sys.platform == "darwin" else rss) / 1024.0


def _worker(log: Path, truth: Path, out: Path) -> None:
    """One calibration in this (fresh) process; prints one JSON line with the figures."""
    t_start = time.perf_counter()
    from plsgraph.cli import main as cli

    if hasattr(cli, "single_threaded_blas"):  # as the command sets up its process (older trees do not)
        cli.single_threaded_blas()
    from plsgraph.report import figure_worker

    if hasattr(figure_worker, "look_ahead"):
        figure_worker.look_ahead()
    from plsgraph.api import calibrate_to_dir
    from plsgraph.options import CalibrationOptions

    t0 = time.perf_counter()
    opts = CalibrationOptions.build(board=BOARD, truth=truth)
    res = calibrate_to_dir(log, out, opts, force=True)
    wall = time.perf_counter() - t0
    rep = res["report"]
    print(json.dumps({
        "ok": bool(res["ok"]),
        "import_s": t0 - t_start,
        "wall_s": wall,
        "timing_s": rep.get("timing_s", {}),
        "events": (rep.get("recording_info") or {}).get("events"),
        "duration_s": (rep.get("recording_info") or {}).get("duration_s"),
        "camera_frames": (rep.get("counts") or {}).get("camera_frames"),
        "truth_errors": rep.get("truth_errors", {}),
        "problems": rep.get("problems", []),
        "peak_rss_mib": _peak_rss_mib(),
        "t_done": time.time(),  # when the work was done: the parent measures ending the process from here
    }), flush=True)
    try:  # end as the plsgraph command ends (trees from before it ended at once tear the interpreter down)
        from plsgraph.cli.main import end_process
    except ImportError:
        return
    end_process(0)


def _ingest_worker(log: Path) -> None:
    """Decode the whole recording (events included) in this fresh process; one JSON line."""
    from plsgraph.io.recording import read_recording

    t0 = time.perf_counter()
    rec = read_recording(log)
    dt = time.perf_counter() - t0
    print(json.dumps({"ingest_s": dt, "events": 0 if rec.events is None else len(rec.events),
                      "peak_rss_mib": _peak_rss_mib()}))


def _env(tree: Path) -> dict[str, str]:
    """The environment for a process that must import ``tree``'s plsgraph. Each such process also runs in ``tree``:
    ``python -c`` puts the working folder first on the path, ahead of PYTHONPATH, so run from another checkout it
    would import that one's plsgraph (as an older tree's figure worker did, and then failed on this tree's jobs)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tree), *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    return env


def _simulate(duration: float, folder: Path, seed: int, realistic: bool,
              contrast: float = 0.45) -> tuple[Path, Path, float]:
    log = folder / f"rich_{duration:g}s_c{contrast:g}.mcap"
    cmd = [sys.executable, "-c", CLI, "simulate", *([] if realistic else ["--ideal"]), "--motion", "rich",
           "--duration", f"{duration:g}", "--seed", str(seed), "--contrast", f"{contrast:g}", "--event-format", "evt3",
           "--board", BOARD, "--out", str(log), "--force"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_env(THIS_TREE), cwd=THIS_TREE)
    if proc.returncode != 0:
        raise SystemExit(f"simulating {log} failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    for line in proc.stderr.strip().splitlines():
        print(f"   simulate: {line}")
    return log, log.with_name(log.stem + ".truth.yaml"), time.perf_counter() - t0


def _run_worker(cmd: list[str], tree: Path) -> dict | str:
    """The worker's JSON line with the process's wall time (``process_s``) and the time it took to end after its
    work (``exit_s``), or the reason it failed (its last stderr line)."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_env(tree), cwd=tree)
    t_end, process_s = time.time(), time.perf_counter() - t0
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or ["(no message)"]
        return f"exit {proc.returncode}: {lines[-1]}"
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    r["process_s"] = process_s
    if "t_done" in r:
        r["exit_s"] = max(0.0, t_end - r.pop("t_done"))
    return r


def _time_command(args: list[str], tree: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", CLI, *args], capture_output=True, env=_env(tree), cwd=tree)
    return time.perf_counter() - t0


def _median(values: list[float]) -> float:
    values = [v for v in values if v == v]
    return statistics.median(values) if values else float("nan")


def _one_run(log: Path, truth: Path, out: Path, tree: Path) -> dict | str:
    r = _run_worker([sys.executable, SCRIPT, "--_worker", str(log), str(truth), str(out)], tree)
    if isinstance(r, str):
        return r
    timing = r["timing_s"]
    timing.setdefault("figures", float("nan"))  # a tree from before the figures were timed: they are in the rest
    r["rest_s"] = r["wall_s"] - sum(v for s in STAGES if (v := timing.get(s, 0.0)) == v)
    r["startup_s"] = r["process_s"] - r["wall_s"] - r.get("exit_s", 0.0)  # Python, the script, importing plsgraph
    ing = _run_worker([sys.executable, SCRIPT, "--_ingest", str(log)], tree)
    r["ingest"] = ing if isinstance(ing, dict) else {"ingest_s": float("nan"), "peak_rss_mib": float("nan"),
                                                    "events": 0}
    r["help_s"] = _time_command(["--help"], tree)
    r["inspect_s"] = _time_command(["inspect", str(log)], tree)
    return r


def _summary(runs: list[dict], duration: float, size_mib: float) -> dict:
    rec_s = runs[0]["duration_s"] or duration
    events = runs[0]["events"] or runs[0]["ingest"]["events"] or 0
    med = {s: _median([r["timing_s"].get(s, float("nan")) for r in runs]) for s in STAGES}
    ingest_s = _median([r["ingest"]["ingest_s"] for r in runs])
    process = _median([r["process_s"] for r in runs])
    return {
        "duration_s": rec_s,
        "file_mib": size_mib,
        "events": events,
        "camera_frames": runs[0]["camera_frames"],
        "process_s": process,
        "process_min_s": min(r["process_s"] for r in runs),
        "process_max_s": max(r["process_s"] for r in runs),
        "realtime_factor": process / rec_s,
        "wall_s": _median([r["wall_s"] for r in runs]),
        "startup_s": _median([r["startup_s"] for r in runs]),
        "import_s": _median([r["import_s"] for r in runs]),
        "stages_s": med,
        "rest_s": _median([r["rest_s"] for r in runs]),
        "exit_s": _median([r.get("exit_s", float("nan")) for r in runs]),
        "ingest_s": ingest_s,
        "ingest_rss_mib": _median([r["ingest"]["peak_rss_mib"] for r in runs]),
        "ingest_mev_s": events / ingest_s / 1e6 if ingest_s > 0 else float("nan"),
        "frontend_mev_s": events / med["frontend"] / 1e6 if med["frontend"] > 0 else float("nan"),
        "peak_rss_mib": _median([r["peak_rss_mib"] for r in runs]),
        "help_s": _median([r["help_s"] for r in runs]),
        "inspect_s": _median([r["inspect_s"] for r in runs]),
        "truth_errors": {k: _median([r["truth_errors"][k] for r in runs if r["truth_errors"].get(k) is not None])
                         for k in TRUTH_KEYS},
        "ok": all(r["ok"] for r in runs),
        "problems": sorted({p for r in runs for p in r["problems"]}),
        "repeats": len(runs),
    }


def _bench_one(duration: float, folder: Path, repeats: int, seed: int, realistic: bool,
               baseline: Path | None, contrast: float = 0.45) -> dict | None:
    log, truth, sim_s = _simulate(duration, folder, seed, realistic, contrast)
    size_mib = log.stat().st_size / 2**20
    print(f"\n== {duration:g} s rich recording: {log.name}, {size_mib:.1f} MiB (simulated in {sim_s:.1f} s)",
          flush=True)
    sides = {"this": THIS_TREE, **({"baseline": baseline} if baseline is not None else {})}
    runs: dict[str, list[dict]] = {k: [] for k in sides}
    for i in range(repeats):
        for name, tree in sides.items():
            r = _one_run(log, truth, folder / f"calib_{duration:g}s_{name}", tree)
            if isinstance(r, str):
                print(f"   {name}: calibration failed, {r}; no figures for {duration:g} s", flush=True)
                return None
            print(f"   run {i + 1}/{repeats} {name}: calibrate process {r['process_s']:.2f} s wall "
                  f"(calibration {r['wall_s']:.2f} s), peak RSS {r['peak_rss_mib']:.0f} MiB, ok={r['ok']}; "
                  f"decode-only pass {r['ingest']['ingest_s']:.2f} s", flush=True)
            runs[name].append(r)
    out = {name: _summary(rs, duration, size_mib) for name, rs in runs.items()}
    if baseline is not None:
        out["wall_ratio"] = _median([a["process_s"] / b["process_s"] for a, b in zip(runs["this"], runs["baseline"],
                                                                                      strict=True)])
    return out


def _fmt(v: float, spec: str = ".2f") -> str:
    return "-" if v != v else format(v, spec)


def _rows(r: dict) -> list[tuple[str, str]]:
    st = r["stages_s"]
    names = {"read": "read (all topics but the events)", "frontend": "front end (decode + detect + PnP)",
             "closed_form": "closed form", "figures": "figures (holding the calibration up)"}
    rows = [
        ("file size (MiB)", f"{r['file_mib']:.1f}"),
        ("events", f"{r['events']:,}"),
        ("camera frames detected", str(r["camera_frames"])),
        ("calibrate, whole process, median (s)", _fmt(r["process_s"])),
        ("  min .. max (s)", f"{r['process_min_s']:.2f} .. {r['process_max_s']:.2f}"),
        ("real-time factor (wall / recording)", _fmt(r["realtime_factor"], ".3f")),
        ("  i.e. times faster than real time", _fmt(1.0 / r["realtime_factor"], ".2f")),
        ("  start-up: Python, importing plsgraph (s)", _fmt(r["startup_s"])),
        ("    of which importing plsgraph.api (s)", _fmt(r["import_s"])),
    ]
    rows += [(f"  {names.get(s, s.replace('_', ' '))} (s)", _fmt(st[s])) for s in STAGES]
    rows += [
        ("  files and the rest (s)", _fmt(r["rest_s"])),
        ("  ending the process (s)", _fmt(r["exit_s"])),
        ("decode-only pass (s)", _fmt(r["ingest_s"])),
        ("decoding, decode-only (M events/s)", _fmt(r["ingest_mev_s"])),
        ("front end incl. decoding (M events/s)", _fmt(r["frontend_mev_s"])),
        ("peak RSS, calibrate (MiB)", f"{r['peak_rss_mib']:.0f}"),
        ("peak RSS, decode-only pass (MiB)", f"{r['ingest_rss_mib']:.0f}"),
        ("plsgraph --help, whole process (s)", _fmt(r["help_s"])),
        ("plsgraph inspect, whole process (s)", _fmt(r["inspect_s"])),
    ]
    rows += [(k, _fmt(r["truth_errors"][k], ".4g")) for k in TRUTH_KEYS]
    rows.append(("result ok (not flagged)", str(r["ok"])))
    return rows


def _print_table(results: list[dict], baseline: Path | None) -> None:
    cols: list[str] = []
    per_col: list[list[str]] = []
    names: list[str] = []
    for res in results:
        this = _rows(res["this"])
        names = [n for n, _ in this]
        d = f"{res['this']['duration_s']:.1f} s"
        cols.append(d if baseline is None else f"{d}, this tree")
        per_col.append([v for _, v in this])
        if baseline is not None:
            base = _rows(res["baseline"])
            cols.append(f"{d}, baseline")
            per_col.append([v for _, v in base])
            ratio = []
            for (_, a), (_, b) in zip(this, base, strict=True):
                try:
                    ratio.append(f"{float(a.replace(',', '')) / float(b.replace(',', '')):.3f}")
                except (ValueError, ZeroDivisionError):
                    ratio.append("")
            ratio[names.index("calibrate, whole process, median (s)")] = f"{res['wall_ratio']:.3f} (pairs)"
            cols.append("this / baseline")
            per_col.append(ratio)
    w0 = max(len(n) for n in names)
    w = [max(len(c), *(len(v) for v in vals)) for c, vals in zip(cols, per_col, strict=True)]
    print("\n| " + "quantity".ljust(w0) + " | " + " | ".join(c.rjust(w[i]) for i, c in enumerate(cols)) + " |")
    print("|" + "-" * (w0 + 2) + "|" + "|".join("-" * (x + 2) for x in w) + "|")
    for j, name in enumerate(names):
        print("| " + name.ljust(w0) + " | " + " | ".join(per_col[i][j].rjust(w[i]) for i in range(len(cols))) + " |")
    for res in results:
        for side in ("this", "baseline"):
            for p in res.get(side, {}).get("problems", []):
                print(f"flagged ({side}, {res['this']['duration_s']:.1f} s): {p}")


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
    ap.add_argument("--contrast", type=float, default=0.45, help="the simulated sensor's contrast threshold: lower "
                    "gives more events (with --realistic, 20 s: 0.45, the default, 4.6 M events; 0.375, 6.7 M; 0.35, "
                    "8.3 M, 416 k events/s; 0.25, 20 M)")
    ap.add_argument("--realistic", action="store_true", help="simulate the realistic sensor (noise, more events) "
                    "instead of the ideal one")
    ap.add_argument("--baseline", type=Path, help="a second checkout (e.g. the previous commit's work tree) timed "
                    "alternately on the same recordings, with ratios")
    ap.add_argument("--keep", type=Path, help="keep recordings and outputs in this folder (default: temp, deleted)")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON to this file")
    args = ap.parse_args()
    if args.repeats < 1 or any(d <= 0 for d in args.durations):
        ap.error("--repeats must be >= 1 and durations > 0")
    if args.baseline is not None:
        args.baseline = args.baseline.resolve()
        if not (args.baseline / "plsgraph" / "__init__.py").is_file():
            ap.error(f"--baseline {args.baseline} holds no plsgraph package")
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        folder = args.keep.resolve()  # the timed processes run in their tree's folder
    else:
        folder = Path(tempfile.mkdtemp(prefix="bench_calibrate_"))
    load = os.getloadavg()
    print(f"bench_calibrate: durations {args.durations}, repeats {args.repeats}, {os.cpu_count()} CPUs, "
          f"{'realistic' if args.realistic else 'ideal'} sensor, this tree {THIS_TREE}"
          + (f", baseline {args.baseline}" if args.baseline else "")
          + f"; load average at start {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    try:
        results = [r for d in args.durations
                   if (r := _bench_one(d, folder, args.repeats, args.seed, args.realistic, args.baseline,
                                       args.contrast)) is not None]
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    if not results:
        print("no recording calibrated; nothing to report")
        return 1
    _print_table(results, args.baseline)
    load = os.getloadavg()
    print(f"\nload average at end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (other jobs on the machine inflate times)")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
