import os
import sys

import numpy as np
import yaml
from mcap_ros2.reader import read_ros2_messages

BASE = os.environ.get("BASE", "out/independent")
seed = sys.argv[1]
tr = dict(np.load(f"{BASE}/rec_{seed}.indep_traj.npz")); truth = yaml.safe_load(open(f"{BASE}/rec_{seed}.indep_truth.yaml"))
ts, pos = [], []
for m in read_ros2_messages(f"{BASE}/rec_{seed}.mcap", topics=["/joint_states"]):
    ts.append(m.ros_msg.header.stamp.sec + m.ros_msg.header.stamp.nanosec * 1e-9 - 1.7e9); pos.append(m.ros_msg.position)
ts, pos = np.array(ts), np.array(pos)
r, b = truth["wheel_radius_eff"], truth["track_width_eff"]
ql, qr = pos[:, :2].mean(1), pos[:, 2:].mean(1)
ds = r * (np.diff(ql) + np.diff(qr)) / 2; dth = r * (np.diff(qr) - np.diff(ql)) / b
x0 = np.array([np.interp(ts[0], tr["tt"], tr["X"][:, k]) for k in range(3)])
th = x0[2] + np.concatenate([[0], np.cumsum(dth)])
xy = x0[:2] + np.concatenate([[[0, 0]], np.cumsum(np.stack([ds * np.cos(th[:-1] + dth / 2), ds * np.sin(th[:-1] + dth / 2)], 1), 0)])
Xt = np.stack([np.interp(ts, tr["tt"], tr["X"][:, k]) for k in range(3)], 1)
print(f"seed {seed}: heading drift end {np.degrees(th[-1]-Xt[-1,2]):.2f} deg, pos err end {np.hypot(*(xy[-1]-Xt[-1,:2])):.3f} m, path len {np.abs(ds).sum():.2f} m, total |dtheta| {np.degrees(np.abs(np.diff(Xt[:,2])).sum()):.0f} deg")
print("  r_eff", r, "b_eff", b)
