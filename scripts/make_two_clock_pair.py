#!/usr/bin/env python3
"""Split a recording into an events file and an odometry file on another clock, as DV / Metavision set-ups have.

    scripts/make_two_clock_pair.py data/sample/rich_sample.mcap --out pair --clock-difference 3725.4 [--raw]

Writes into OUT:
  events.mcap        the events and CameraInfo, stamps unchanged (camera clock)
  odometry.mcap      the wheel joint states (and odometry) with every stamp + clock difference, and CameraInfo
                     (--wheels swapped / left_reversed / right_reversed writes the wheels mis-wired)
  sensor.raw         with --raw: the events as a Prophesee EVT 3.0 file, on a sensor clock that starts at the
                     first event (µs), as a Metavision camera writes it
  *.truth.yaml       beside each events file, when the recording has a truth file: T_base_cam and the total
                     offset td (t_odom = t_cam + td) that the pair must give
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from plsgraph.io import read_recording, write_recording
from plsgraph.io.event_codecs import encode_evt3
from plsgraph.io.recording import JointStates, OdometryMsgs
from plsgraph.io.writer import read_truth, truth_path, write_truth


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--clock-difference", type=float, default=3725.4,
                    help="seconds added to the odometry stamps (default: %(default)s)")
    ap.add_argument("--raw", action="store_true", help="also write sensor.raw (EVT 3.0, sensor clock)")
    ap.add_argument("--wheels", default="as_given", choices=["as_given", "swapped", "left_reversed", "right_reversed"],
                    help="write the wheel joints mis-wired this way (default: as recorded)")
    args = ap.parse_args(argv)
    rec = read_recording(args.recording)
    if rec.events is None or rec.camera is None or (rec.joints is None and rec.odometry is None):
        print(f"{args.recording} needs events, CameraInfo and joints or odometry", file=sys.stderr)
        return 2
    shift_ns = int(round(args.clock_difference * 1e9))
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    write_recording(out / "events.mcap", rec.events, None, None, rec.camera, event_format="evt3", overwrite=True)
    joints = odo = None
    if rec.joints is not None:
        j = rec.joints
        lc, rc = j.wheel_columns()
        pos, vel = j.position.copy(), j.velocity.copy()
        if args.wheels == "swapped":
            pos[:, lc + rc], vel[:, lc + rc] = j.position[:, rc + lc], j.velocity[:, rc + lc]
        elif args.wheels != "as_given":
            cols = lc if args.wheels == "left_reversed" else rc
            pos[:, cols], vel[:, cols] = -pos[:, cols], -vel[:, cols]
        joints = JointStates(j.t + shift_ns, j.names, pos, vel)
    if rec.odometry is not None:
        o = rec.odometry
        odo = OdometryMsgs(o.t + shift_ns, o.position, o.orientation, o.linear, o.angular, o.frame_id,
                           o.child_frame_id)
    write_recording(out / "odometry.mcap", None, joints, odo, rec.camera, overwrite=True)
    written = [out / "events.mcap", out / "odometry.mcap"]
    t_first_ns = int(rec.events.t[0])
    if args.raw:
        ev = rec.events
        t_us = (ev.t - t_first_ns) // 1000  # the sensor's own clock: µs since its start
        body, _ = encode_evt3(t_us, ev.x.astype(np.int64), ev.y.astype(np.int64), ev.p > 0)
        header = (f"% camera_integrator_name Prophesee\n% evt 3.0\n% format EVT3;height={ev.height};width={ev.width}\n"
                  f"% geometry {ev.width}x{ev.height}\n% end\n").encode()
        (out / "sensor.raw").write_bytes(header + body)
        written.append(out / "sensor.raw")
    if truth_path(args.recording).exists():
        truth = read_truth(args.recording)
        td = float(truth["td"])
        write_truth(out / "events.mcap", dict(truth, td=td + args.clock_difference,
                                              clock_difference_s=args.clock_difference))
        written.append(truth_path(out / "events.mcap"))
        if args.raw:
            # t_odom = t_orig + td + shift and t_orig = t_raw + t_first: one big number, kept exact in ns first.
            total_ns = t_first_ns + shift_ns + int(round(td * 1e9))
            write_truth(out / "sensor.raw", dict(truth, td=total_ns * 1e-9, clock_difference_s=args.clock_difference,
                                                 raw_clock_origin_ns=t_first_ns))
            written.append(truth_path(out / "sensor.raw"))
    for p in written:
        print(f"written: {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
