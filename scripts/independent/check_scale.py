"""Least-squares turn and distance scale of the recorded wheel odometry vs the truth trajectory (0.5 s windows)."""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from evread import wheels_and_truth  # noqa: E402

BASE = os.environ.get("BASE", "out/independent")
for seed in sys.argv[1:]:
    tr, truth, ts, ql, qr = wheels_and_truth(BASE, seed)
    r, b = truth["wheel_radius_eff"], truth["track_width_eff"]
    g = np.arange(ts[0], ts[-1], 0.5)
    QL, QR = np.interp(g, ts, ql), np.interp(g, ts, qr)
    th = np.interp(g, tr["tt"], tr["X"][:, 2]); x = np.interp(g, tr["tt"], tr["X"][:, 0]); y = np.interp(g, tr["tt"], tr["X"][:, 1])
    dth_o = r * np.diff(QR - QL) / b; dth_t = np.diff(th)
    ds_o = r * np.diff(QR + QL) / 2; ds_t = np.hypot(np.diff(x), np.diff(y)) * np.sign(ds_o)
    print(f"{seed}: truth-heading / odometry-heading (with truth b) = {np.dot(dth_o, dth_t)/np.dot(dth_o, dth_o):.4f};"
          f" distance ratio = {np.dot(ds_o, ds_t)/np.dot(ds_o, ds_o):.4f}; b_eff {b:.4f} r_eff {r:.4f}")
