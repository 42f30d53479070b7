"""Score plsgraph calibrations against the generator's truth.
usage: compare.py TAG [TAG ...]   (TAG: 11 -> rec_11.mcap/out_11, h101 -> rec_h101.mcap/out_h101)
env OUT_SUFFIX / BASE to point at other output dirs."""
import json
import os
import re
import sys

import numpy as np
import yaml
from scipy.spatial.transform import Rotation as Rot

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check import in_view_windows

BASE = os.environ.get("BASE", "out/independent")


def cal_log_summary(path):
    if not os.path.exists(path):
        return None, []
    txt = open(path).read().splitlines()
    code = None
    for l in txt:
        m = re.match(r"exit=(\d+)", l)
        if m:
            code = int(m.group(1))
    lines = [l.strip() for l in txt if re.search(r"WARNING|ERROR|PROBLEM|problem|flag|refus|fail", l, re.I)]
    return code, lines


def _z(err, sigma):
    """err / sigma, or None where the result gives no sigma (a flagged result that withholds its covariance)."""
    return None if sigma is None or not sigma else err / sigma


def score(tag, out=None, log=None, quiet=False):
    tru = yaml.safe_load(open(f"{BASE}/rec_{tag}.indep_truth.yaml"))
    out = out or f"{BASE}/out_{tag}"
    code, lines = cal_log_summary(log or f"{BASE}/cal_{tag}.log")
    res = {"tag": tag, "level": tru.get("harsh", {}).get("level", 0), "exit": code, "ev_s": tru["events_per_s"],
           "log_lines": lines}
    iv, nw = in_view_windows(tag, base=BASE)
    res["in_view"], res["windows_truth"] = iv, nw
    if not os.path.exists(f"{out}/report.json"):
        res["error"] = "no report.json"
        if not quiet:
            print(tag, res)
        return res
    rep = json.load(open(f"{out}/report.json"))
    cal = rep["calibration"]
    Tt, Te = np.array(tru["T_base_cam"]), np.array(cal["T_base_cam"])
    dR = np.degrees(Rot.from_matrix(Te[:3, :3] @ Tt[:3, :3].T).as_rotvec())  # base-frame error est vs truth
    sig = {o["name"]: o["sigma"] for o in cal["observability"]}
    st = {o["name"]: o["status"] for o in cal["observability"]}
    e_xy = Te[:2, 3] - Tt[:2, 3]
    e_td = (cal["time_offset_s"] - tru["td_s"]) * 1e3
    od = cal["odometry"]
    res.update(ok=rep["ok"], problems=rep["problems"], warnings=rep["warnings"],
               frames=rep["counts"]["camera_frames"], windows=rep["coverage"]["windows"],
               found=rep["coverage"].get("found"), det=rep.get("discarded", {}).get("frontend_detected", rep["counts"]["camera_frames"]), by_outcome=rep["coverage"].get("by_outcome"),
               rot_err=float(np.linalg.norm(dR)), rpy_err=dR.tolist(),
               rpy_z=[_z(dR[0], sig["roll"]), _z(dR[1], sig["pitch"]), _z(dR[2], sig["yaw"])],
               rpy_sig=[sig["roll"], sig["pitch"], sig["yaw"]],
               xy_err_mm=(e_xy * 1e3).tolist(), xy_z=[_z(e_xy[0], sig["x"]), _z(e_xy[1], sig["y"])],
               xy_sig_mm=[None if sig["x"] is None else sig["x"] * 1e3, None if sig["y"] is None else sig["y"] * 1e3],
               td_true_ms=tru["td_s"] * 1e3, td_est_ms=cal["time_offset_s"] * 1e3, td_err_ms=e_td,
               td_sig_ms=sig["td"], td_z=_z(e_td, sig["td"]),
               r_est=od["wheel_radius_m"], r_sig=od["wheel_radius_sigma_m"], r_true=tru["wheel_radius_eff"],
               b_est=od["track_width_m"], b_sig=od["track_width_sigma_m"], b_true=tru["track_width_eff"],
               status=st, rms=rep.get("refinement", {}).get("rms_px") if isinstance(rep.get("refinement"), dict) else None)
    res["r_z"] = _z(res["r_est"] - res["r_true"], res["r_sig"])
    res["b_z"] = _z(res["b_est"] - res["b_true"], res["b_sig"])
    zs = [abs(z) for z in res["rpy_z"] + res["xy_z"] + [res["td_z"], res["r_z"], res["b_z"]] if z is not None]
    res["max_abs_z"] = max(zs) if zs else None
    h = tru.get("harsh", {})
    res["latency_ms"] = [h.get("tau_board_white_ms"), h.get("tau_board_black_ms")]
    if not quiet:
        print(f"== {tag} (level {res['level']}, exit {code}, ok={rep['ok']}) ev/s {res['ev_s']:.0f}")
        print(f"   frames detected {res['frames']} / plsgraph windows {res['windows']}; truth in-view windows {iv}/{nw}; coverage {res['by_outcome']}")
        print(f"   problems: {rep['problems']}")
        for w in rep["warnings"]:
            print(f"   warning: {w[:220]}")
        def f(v, fmt="+.1f", k=1.0):
            return "-" if v is None else format(v * k, fmt)

        zr, zx = res["rpy_z"], res["xy_z"]
        print(f"   rot err {res['rot_err']:.3f} deg; roll {dR[0]:+.3f} (z {f(zr[0])}, sig {f(sig['roll'], '.3f')}) "
              f"pitch {dR[1]:+.3f} (z {f(zr[1])}, sig {f(sig['pitch'], '.3f')}) yaw {dR[2]:+.3f} (z {f(zr[2])}, "
              f"sig {f(sig['yaw'], '.3f')})")
        print(f"   x err {e_xy[0]*1e3:+.1f} mm (z {f(zx[0])}, sig {f(sig['x'], '.1f', 1e3)})  y err {e_xy[1]*1e3:+.1f} mm "
              f"(z {f(zx[1])}, sig {f(sig['y'], '.1f', 1e3)})  z status {st['z']}")
        print(f"   td true {res['td_true_ms']:.2f} est {res['td_est_ms']:.2f} err {e_td:+.2f} ms (z {f(res['td_z'])}, "
              f"sig {f(sig['td'], '.2f')}); pixel latency white/black {res['latency_ms']}")
        print(f"   wheel r {res['r_est']:.4f}+-{f(res['r_sig'], '.4f')} (truth {res['r_true']:.4f}, z {f(res['r_z'])}); "
              f"track {res['b_est']:.4f}+-{f(res['b_sig'], '.4f')} (truth {res['b_true']:.4f}, z {f(res['b_z'])})")
        print(f"   max |z| {f(res['max_abs_z'], '.1f')}")
    return res


if __name__ == "__main__":
    allres = [score(t) for t in sys.argv[1:]]
    json.dump(allres, open(os.environ.get("JSON_OUT", "/dev/null"), "w"), indent=1, default=str)
