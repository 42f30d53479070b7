"""Check the generator's truth: project the board circles with the truth poses onto accumulated events."""
import math
import os
import sys

import cv2
import numpy as np
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import evread
import gen


def pose_at(tr, t_world):
    tt, X = tr["tt"], tr["X"]
    return np.array([np.interp(t_world, tt, X[:, k]) for k in range(3)])

def project(tr, t_cam_rel):
    x = pose_at(tr, t_cam_rel + float(tr["td"]))
    c, s = math.cos(x[2]), math.sin(x[2])
    T_wb = np.array([[c, -s, 0, x[0]], [s, c, 0, x[1]], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    if "vib" in tr:  # harsh recordings: base roll/pitch unknown to odometry
        tw = t_cam_rel + float(tr["td"])
        T_wb = T_wb @ gen.vib_matrix([np.interp(tw, tr["tt"], tr["vib"][:, k]) for k in range(2)])
    T_cb = np.linalg.inv(T_wb @ tr["T_base_cam"]) @ tr["T_world_board"]
    uv, _ = cv2.projectPoints(gen.board_points(), cv2.Rodrigues(T_cb[:3, :3])[0], T_cb[:3, 3], tr["K"], tr["D"])
    return uv.reshape(-1, 2)

def main(seed, instants, half=0.004, base=os.environ.get("BASE", "out/independent")):
    rec = f"{base}/rec_{seed}.mcap"
    tr = dict(np.load(f"{base}/rec_{seed}.indep_traj.npz"))
    ep = int(tr["epoch_ns"])
    tiles = []
    for tc in instants:
        t, x, y, p = evread.read_events(rec, ep + int((tc - half) * 1e9), ep + int((tc + half) * 1e9))
        img = np.zeros((gen.H, gen.W), np.float32)
        np.add.at(img, (y.astype(int), x.astype(int)), 1)
        g = np.clip(img / max(1, np.percentile(img[img > 0], 95)) * 255, 0, 255).astype(np.uint8)
        col = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
        col = cv2.resize(col, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        uv = project(tr, tc)
        for k, (u, v) in enumerate(uv):
            cv2.circle(col, (int(round(2 * u + 0.5)), int(round(2 * v + 0.5))), 2, (0, 0, 255) if k else (0, 255, 0), -1)
        # wrong-sign td check: project with -td too (blue) to see the difference
        tr2 = dict(tr); tr2["td"] = -float(tr["td"])
        for u, v in project(tr2, tc):
            cv2.circle(col, (int(round(2 * u + 0.5)), int(round(2 * v + 0.5))), 1, (255, 128, 0), -1)
        cv2.putText(col, f"seed {seed} t_cam={tc:.2f}s", (5, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 255, 255), 1)
        tiles.append(col)
    out = np.concatenate([np.concatenate(tiles[i:i + 2], 1) for i in range(0, len(tiles), 2)], 0)
    cv2.imwrite(f"{base}/check_{seed}.png", out)

def in_view_windows(seed, rate=30.0, base=os.environ.get("BASE", "out/independent")):
    tr = dict(np.load(f"{base}/rec_{seed}.indep_traj.npz"))
    truth = yaml.safe_load(open(f"{base}/rec_{seed}.indep_truth.yaml"))
    dur = truth["duration_s"]
    edges = np.arange(0, dur + 1e-9, 1 / rate)
    p = {"T_base_cam": tr["T_base_cam"], "K": tr["K"], "D": tr["D"]}
    X = np.stack([pose_at(tr, e + float(tr["td"])) for e in edges])
    vib = None
    if "vib" in tr:
        vib = np.stack([[np.interp(e + float(tr["td"]), tr["tt"], tr["vib"][:, k]) for k in range(2)] for e in edges])
    v = gen.board_in_view(p, tr["T_world_board"], X, vib=vib)
    win = v[:-1] & v[1:]
    return int(win.sum()), len(win)

if __name__ == "__main__":
    import os
    seed = sys.argv[1]  # "11" or "h101"
    base = os.environ.get("BASE", "out/independent")
    main(seed, [float(a) for a in sys.argv[2:]], base=base)
    print("in-view windows", in_view_windows(seed, base=base))
