"""Event ingest benchmark: throughput per encoding, against generic / naive decoders, and peak memory.

Run:  .venv/bin/python scripts/bench_ingest.py [--events 2000000] [--repeats 3]

Prints medians. Synthetic recordings (random events at 1 M events/s on a 346 x 260 sensor, 10 ms packets)
are written to a temporary directory; the real DAVIS346 sample is read too when present.
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from plsgraph.core.events import EventStream
from plsgraph.io import iter_event_chunks, read_events, write_recording
from plsgraph.io.messages import parse_event_packet

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from realdata import SHARED_REAL_DIR  # noqa: E402

FORMATS = ("dvs", "libcaer_cmp", "evt3", "libcaer", "mono")


def simulate(n: int, seed: int = 0) -> EventStream:
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.sort(rng.integers(0, n, n)) * 1000  # 1 M events/s, whole µs
    return EventStream.from_arrays(t, rng.integers(0, 346, n), rng.integers(0, 260, n), rng.random(n) < 0.5, 346, 260)


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def generic_dvs(path: Path, max_msgs: int) -> tuple[int, float]:
    """mcap_ros2's generic decoder: one Python object per event, then arrays from them."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    t0 = time.perf_counter()
    n = 0
    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        for k, (_s, _c, _m, msg) in enumerate(r.iter_decoded_messages()):
            if k >= max_msgs:
                break
            evs = msg.events
            np.array([e.x for e in evs], np.uint16)
            np.array([e.y for e in evs], np.uint16)
            np.array([e.ts.sec * 1_000_000_000 + e.ts.nanosec for e in evs], np.int64)
            np.array([e.polarity for e in evs], bool)
            n += len(evs)
    return n, time.perf_counter() - t0


def naive_packet_decode(path: Path, max_msgs: int) -> tuple[int, float]:
    """A per-word Python loop over the packet payloads (libcaer_cmp / evt3 / libcaer / mono), for scale."""
    from mcap.reader import make_reader

    t0 = time.perf_counter()
    n = 0
    with open(path, "rb") as f:
        for k, (_s, _c, m) in enumerate(make_reader(f).iter_messages()):
            if k >= max_msgs:
                break
            hdr, blob = parse_event_packet(m.data)
            out = []
            if hdr.encoding in ("libcaer", "mono"):
                for d, ts in struct.iter_unpack("<II", blob):
                    out.append((ts, d & 0xFFFF, d >> 16, d & 1))
            else:
                hi = lo = coord = 0
                for (w,) in struct.iter_unpack("<H", blob):
                    c = w >> 12
                    if c in (0, 8):
                        hi = (w & 0xFFF) << 12
                    elif c in (1, 6):
                        lo = w & 0xFFF
                    elif c == 2 and hdr.encoding == "libcaer_cmp" or c == 0 and hdr.encoding == "evt3":
                        coord = w & 0x7FF
                    elif c == 3 and hdr.encoding == "libcaer_cmp" or c == 2 and hdr.encoding == "evt3":
                        out.append((hdr.time_base + (hi | lo) * 1000, coord, w & 0x7FF, (w >> 11) & 1))
            np.array(out, dtype=np.int64)
            n += len(out)
    return n, time.perf_counter() - t0


def peak_mib(fn) -> float:
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    n = args.events
    ev = simulate(n)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        print(f"# ingest throughput, {n:,} synthetic events (median of {args.repeats}); higher is better")
        cols = ("format", "file MB", "read_events Mev/s", "reference", "ref Mev/s", "ratio")
        print(f"{cols[0]:<12} {cols[1]:>8} {cols[2]:>18} {cols[3]:<28} {cols[4]:>10} {cols[5]:>7}")
        for fmt in FORMATS:
            p = tmp / f"{fmt}.mcap"
            write_recording(p, ev, None, None, None, event_format=fmt)
            got = read_events(p)
            assert len(got) == n and np.array_equal(got.x, ev.x), fmt
            dt = median_time(lambda p=p: read_events(p), args.repeats)
            rate = n / dt / 1e6
            if fmt == "dvs":
                m, dref = generic_dvs(p, 30)
                ref = "mcap_ros2 generic decoder"
            else:
                m, dref = naive_packet_decode(p, 10)
                ref = "per-word Python loop"
            rref = m / dref / 1e6
            size = p.stat().st_size / 1e6
            print(f"{fmt:<12} {size:>8.1f} {rate:>18.1f} {ref:<28} {rref:>10.3f} {rate / rref:>6.0f}x")
        real = SHARED_REAL_DIR / "davis346_tagboard.mcap"
        if real.exists():
            m = len(read_events(real))
            dt = median_time(lambda: read_events(real), args.repeats)
            print(f"real davis346_tagboard.mcap (libcaer_cmp, {m:,} events): {m / dt / 1e6:.1f} Mev/s")

        print("\n# peak traced memory (tracemalloc) while streaming iter_event_chunks, chunks consumed and dropped")
        print(f"{'events in file':>15} {'chunk_events':>13} {'peak MiB':>9}")
        sizes = (n // 2, n, 2 * n)
        for size in sizes:
            p = tmp / f"mem_{size}.mcap"
            write_recording(p, simulate(size, seed=size), None, None, None, event_format="libcaer_cmp")
            for chunk in (100_000, 1_000_000):

                def consume(p=p, chunk=chunk, size=size):
                    total = 0
                    for c in iter_event_chunks(p, chunk_events=chunk):
                        total += len(c)
                    assert total == size

                print(f"{size:>15,} {chunk:>13,} {peak_mib(consume):>9.1f}")
            print(f"{size:>15,} {'read_events':>13} {peak_mib(lambda p=p: read_events(p)):>9.1f}")


if __name__ == "__main__":
    main()
