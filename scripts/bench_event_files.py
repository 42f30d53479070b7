"""Event-file decoding benchmark: Prophesee .raw (EVT 2.0 / 3.0) and AEDAT4, plsgraph against other decoders.

Run:  .venv/bin/python scripts/bench_event_files.py [--events 2000000] [--repeats 5]

Needs (for the comparisons; each is skipped when missing): expelliarmus (.raw), aedat and dv-processing
(AEDAT4; dv-processing also writes the AEDAT4 test file). Prints medians in M events/s, a check that the
decoders agree event for event, and the installed size of each package.

Synthetic events: uniform random pixels, 1 M events/s, sorted µs times (EVT 3.0 / 2.0 words as a sensor
writes them, without vector words; AEDAT4 written by dv-processing with its default LZ4 compression).
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from plsgraph.io import read_events
from plsgraph.io.event_codecs import encode_evt2, encode_evt3
from plsgraph.io.prophesee import read_raw_events


def median_rate(fn, n: int, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n / statistics.median(times) / 1e6


def installed_mb(dist: str) -> float | None:
    try:
        files = md.distribution(dist).files or []
    except md.PackageNotFoundError:
        return None
    return sum((f.size or 0) for f in files if f.size) / 1e6


def events(n: int, w: int, h: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, n, n))  # µs: 1 M events/s
    return t, rng.integers(0, w, n), rng.integers(0, h, n), rng.random(n) < 0.5


def bench_raw(tmp: Path, n: int, repeats: int) -> list[tuple]:
    rows = []
    t, x, y, p = events(n, 1280, 720)
    for enc, encode, word in (("evt3", encode_evt3, "EVT3"), ("evt2", encode_evt2, "EVT2")):
        body, _ = encode(t, x, y, p)
        path = tmp / f"bench_{enc}.raw"
        header = f"% evt {enc[-1]}.0\n% format {word};height=720;width=1280\n% geometry 1280x720\n% end\n"
        path.write_bytes(header.encode() + body)
        mb = path.stat().st_size / 1e6
        rows.append((f".raw {word}", mb, "plsgraph read_events (-> EventStream)",
                     median_rate(lambda path=path: read_events(path), n, repeats)))
        rows.append((f".raw {word}", mb, "plsgraph decoder only (read_raw_events)",
                     median_rate(lambda path=path: read_raw_events(path), n, repeats)))
        try:
            from expelliarmus import Wizard
        except ImportError:
            continue
        wiz = Wizard(encoding=enc, fpath=str(path))
        rows.append((f".raw {word}", mb, f"expelliarmus {md.version('expelliarmus')} Wizard.read",
                     median_rate(wiz.read, n, repeats)))
        a = wiz.read()
        ours = read_raw_events(path)
        same_xyp = (np.array_equal(a["x"], ours[1]) and np.array_equal(a["y"], ours[2])
                    and np.array_equal(a["p"] > 0, ours[3] > 0))
        dt = a["t"].astype(np.int64) - ours[0] // 1000
        print(f"{word}: x, y, p agree with expelliarmus: {same_xyp}; times equal for "
              f"{np.mean(dt == 0) * 100:.1f} % of events (max difference {np.abs(dt).max()} µs)")
    return rows


def bench_aedat4(tmp: Path, n: int, repeats: int) -> list[tuple]:
    try:
        import dv_processing as dv
    except ImportError:
        print("dv-processing not installed: no AEDAT4 file to measure")
        return []
    t, x, y, p = events(n, 346, 260, seed=1)
    t = t + 1_700_000_000_000_000
    path = tmp / "bench.aedat4"
    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.EventOnlyConfig("DAVIS346_bench", (346, 260)))
    for i0 in range(0, n, 10_000):
        store = dv.EventStore()
        for k in range(i0, min(n, i0 + 10_000)):
            store.push_back(int(t[k]), int(x[k]), int(y[k]), bool(p[k]))
        writer.writeEvents(store)
    del writer
    mb = path.stat().st_size / 1e6
    rows = []

    def with_aedat():
        import aedat

        return sum(pk["events"].size for pk in aedat.Decoder(str(path)) if "events" in pk)

    def with_dv():
        rec = dv.io.MonoCameraRecording(str(path))
        k = 0
        while rec.isRunning():
            b = rec.getNextEventBatch()
            if b is None:
                break
            k += b.numpy().size
        return k

    try:
        import aedat  # noqa: F401

        rows.append(("AEDAT4 (LZ4)", mb, f"aedat {md.version('aedat')} packets -> numpy",
                     median_rate(with_aedat, n, repeats)))
        rows.append(("AEDAT4 (LZ4)", mb, "plsgraph read_events (aedat -> EventStream)",
                     median_rate(lambda: read_events(path), n, repeats)))
        ev = read_events(path)
        print(f"AEDAT4: plsgraph (through aedat) equals the written events: "
              f"{np.array_equal(ev.t, t * 1000) and np.array_equal(ev.x, x) and np.array_equal(ev.p > 0, p)}")
    except ImportError:
        print("aedat not installed")
    rows.append(("AEDAT4 (LZ4)", mb, f"dv-processing {md.version('dv-processing')} batches -> numpy",
                 median_rate(with_dv, n, repeats)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rows = bench_raw(tmp, args.events, args.repeats) + bench_aedat4(tmp, args.events, args.repeats)
    print(f"\n{args.events:,} events, median of {args.repeats} runs\n")
    print("| file | MB | decoder | M events/s |\n|---|---|---|---|")
    for f, mb, who, rate in rows:
        print(f"| {f} | {mb:.1f} | {who} | {rate:.1f} |")
    print("\n| package | installed MB |\n|---|---|")
    for dist in ("aedat", "dv-processing", "expelliarmus"):
        size = installed_mb(dist)
        print(f"| {dist} | {'not installed' if size is None else f'{size:.1f}'} |")


if __name__ == "__main__":
    main()
