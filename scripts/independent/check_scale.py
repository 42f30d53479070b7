"""Least-squares turn and distance scale of the recorded wheel odometry vs the truth trajectory (0.5 s windows)."""
import os
import sys

import numpy as np
import yaml
from mcap_ros2.reader import read_ros2_messages

BASE = os.environ.get("BASE", "out/independent")
for seed in sys.argv[1:]:
    tr = dict(np.load(f"{BASE}/rec_{seed}.indep_traj.npz")); truth = yaml.safe_load(open(f"{BASE}/rec_{seed}.indep_truth.yaml"))
    ts, pos = [], []
    for m in read_ros2_messages(f"{BASE}/rec_{seed}.mcap", topics=["/joint_states"]):
        ts.append(m.ros_msg.header.stamp.sec + m.ros_msg.header.stamp.nanosec * 1e-9 - 1.7e9); pos.append(m.ros_msg.position)
    ts, pos = np.array(ts), np.array(pos)
    r, b = truth["wheel_radius_eff"], truth["track_width_eff"]
    ql, qr = pos[:, :2].mean(1), pos[:, 2:].mean(1)
    g = np.arange(ts[0], ts[-1], 0.5)
    QL, QR = np.interp(g, ts, ql), np.interp(g, ts, qr)
    th = np.interp(g, tr["tt"], tr["X"][:, 2]); x = np.interp(g, tr["tt"], tr["X"][:, 0]); y = np.interp(g, tr["tt"], tr["X"][:, 1])
    dth_o = r * np.diff(QR - QL) / b; dth_t = np.diff(th)
    ds_o = r * np.diff(QR + QL) / 2; ds_t = np.hypot(np.diff(x), np.diff(y)) * np.sign(ds_o)
    print(f"{seed}: truth-heading / odometry-heading (with truth b) = {np.dot(dth_o, dth_t)/np.dot(dth_o, dth_o):.4f};"
          f" distance ratio = {np.dot(ds_o, ds_t)/np.dot(ds_o, ds_o):.4f}; b_eff {b:.4f} r_eff {r:.4f}")
