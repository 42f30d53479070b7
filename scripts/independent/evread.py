"""Own reader for the generator's MCAP (numpy CDR decode of dvs_msgs/EventArray, JointState via mcap_ros2)."""
import numpy as np
from mcap.reader import make_reader

REC0 = np.dtype([("x", "<u2"), ("y", "<u2"), ("s", "<i4"), ("n", "<u4"), ("p", "u1")])
REC = np.dtype([("pad1", "u1"), ("x", "<u2"), ("y", "<u2"), ("pad2", "<u2"), ("s", "<i4"), ("n", "<u4"), ("p", "u1")])


def decode_event_array(b: bytes):
    o = 4 + 8
    ln = int(np.frombuffer(b, "<u4", 1, o)[0]); o += 4 + ln
    o = 4 + ((o - 4 + 3) // 4) * 4
    h, w, n = np.frombuffer(b, "<u4", 3, o); o += 12
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.int8)
    r0 = np.frombuffer(b, REC0, 1, o); o += 13
    r = np.frombuffer(b, REC, n - 1, o)
    t = np.concatenate([r0["s"].astype(np.int64) * 10**9 + r0["n"], r["s"].astype(np.int64) * 10**9 + r["n"]])
    x = np.concatenate([r0["x"], r["x"]]); y = np.concatenate([r0["y"], r["y"]])
    p = np.where(np.concatenate([r0["p"], r["p"]]) > 0, 1, -1).astype(np.int8)
    return t, x, y, p


def read_events(path, t0_ns=None, t1_ns=None):
    ts, xs, ys, ps = [], [], [], []
    with open(path, "rb") as f:
        rd = make_reader(f)
        for sch, ch, msg in rd.iter_messages(topics=["/dvs/events"], start_time=None if t0_ns is None else t0_ns - 20_000_000,
                                             end_time=None if t1_ns is None else t1_ns + 20_000_000):
            t, x, y, p = decode_event_array(msg.data)
            ts.append(t); xs.append(x); ys.append(y); ps.append(p)
    t, x, y, p = map(np.concatenate, (ts, xs, ys, ps))
    if t0_ns is not None:
        m = (t >= t0_ns) & (t < t1_ns)
        t, x, y, p = t[m], x[m], y[m], p[m]
    return t, x, y, p


def wheels_and_truth(base, tag):
    """The truth trajectory (npz), the truth YAML, and the recorded wheel-joint stamps (s, less 1.7e9) with the mean
    left and right wheel angles (rad) of recording ``tag`` in folder ``base``."""
    import yaml
    from mcap_ros2.reader import read_ros2_messages

    tr = dict(np.load(f"{base}/rec_{tag}.indep_traj.npz"))
    with open(f"{base}/rec_{tag}.indep_truth.yaml") as f:
        truth = yaml.safe_load(f)
    ts, pos = [], []
    for m in read_ros2_messages(f"{base}/rec_{tag}.mcap", topics=["/joint_states"]):
        ts.append(m.ros_msg.header.stamp.sec + m.ros_msg.header.stamp.nanosec * 1e-9 - 1.7e9)
        pos.append(m.ros_msg.position)
    ts, pos = np.array(ts), np.array(pos)
    return tr, truth, ts, pos[:, :2].mean(1), pos[:, 2:].mean(1)
