"""The lens distortion check (plsgraph.calib.lens) on the tracks a study kept (``scripts/study.py --save-tracks DIR``):
one line per run (the camera model's and the views' k1, k2, the shift at the board's outer image radius with its
jackknife sigma) and a summary (runs, how many disagree, how many lie beyond 3 jackknife sigmas, median and largest
|shift|). On the study's recordings the camera model is exact, so every disagreement is a false alarm.

    .venv/bin/python scripts/lens_check_tracks.py out/tracks_r11_s0
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tracks", type=Path, help="a --save-tracks folder (runNNN.pkl)")
    a = ap.parse_args()
    from plsgraph.calib.lens import distortion_from_views

    rows = []
    files = sorted(a.tracks.glob("run*.pkl"))
    if not files:
        ap.error(f"no run*.pkl in {a.tracks}")
    for f in files:
        with open(f, "rb") as fh:
            run = pickle.loads(pickle.load(fh)["run"])
        det = None if run.camera_track is None else run.camera_track.detections
        check = None if det is None else distortion_from_views(det.uv, det.board_points, run.camera)
        if check is None:
            print(f"{f.name}: no check (too few views)")
            continue
        z = check.shift_px / max(check.shift_sigma_px, 1e-12)
        rows.append((check.shift_px, z, check.significant))
        print(f"{f.name}: k1, k2 {check.given[0]:+.3f} {check.given[1]:+.3f} -> views {check.views[0]:+.3f} "
              f"{check.views[1]:+.3f}; shift {check.shift_px:+.3f} +- {check.shift_sigma_px:.3f} px (z {z:+.1f}) at "
              f"r {check.radius:.2f}; disagrees: {check.significant}")
    if rows:
        r = np.array(rows, dtype=float)
        beyond = int(np.sum(abs(r[:, 1]) > 3))
        print(f"runs {len(r)}; disagree {int(r[:, 2].sum())}; beyond 3 jackknife sigmas {beyond}; "
              f"|shift| median {np.median(abs(r[:, 0])):.3f} px, largest {np.max(abs(r[:, 0])):.3f} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
