import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from evread import wheels_and_truth  # noqa: E402

BASE = os.environ.get("BASE", "out/independent")
seed = sys.argv[1]
tr, truth, ts, ql, qr = wheels_and_truth(BASE, seed)
r, b = truth["wheel_radius_eff"], truth["track_width_eff"]
ds = r * (np.diff(ql) + np.diff(qr)) / 2; dth = r * (np.diff(qr) - np.diff(ql)) / b
x0 = np.array([np.interp(ts[0], tr["tt"], tr["X"][:, k]) for k in range(3)])
th = x0[2] + np.concatenate([[0], np.cumsum(dth)])
xy = x0[:2] + np.concatenate([[[0, 0]], np.cumsum(np.stack([ds * np.cos(th[:-1] + dth / 2), ds * np.sin(th[:-1] + dth / 2)], 1), 0)])
Xt = np.stack([np.interp(ts, tr["tt"], tr["X"][:, k]) for k in range(3)], 1)
print(f"seed {seed}: heading drift end {np.degrees(th[-1]-Xt[-1,2]):.2f} deg, pos err end {np.hypot(*(xy[-1]-Xt[-1,:2])):.3f} m, path len {np.abs(ds).sum():.2f} m, total |dtheta| {np.degrees(np.abs(np.diff(Xt[:,2])).sum()):.0f} deg")
print("  r_eff", r, "b_eff", b)
