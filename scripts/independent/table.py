import contextlib
import io
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import compare

tags = sys.argv[1:]
print("| rec | lvl | ev/s | detected, used / truth in-view (windows) | exit | first problem / notable warning | rot err deg (z roll/pitch/yaw) | x, y err mm (z) | td err ms (z) | r err mm (z) | track err mm (z) |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for t in tags:
    with contextlib.redirect_stdout(io.StringIO()):
        r = compare.score(t, quiet=True)
    if "error" in r:
        print(f"| {t} | {r['level']} | {r['ev_s']/1e3:.0f}k | - | {r['exit']} | {r['log_lines'][:1]} | - | - | - | - | - |"); continue
    def z(v):
        return "-" if v is None else f"{v:+.1f}"

    first = (r["problems"][:1] or [w for w in r["warnings"] if "gap" in w or "reset" in w or "settle" in w][:1] or [""])[0][:90]
    print(f"| {t} | {r['level']} | {r['ev_s']/1e3:.0f}k | {r['det']} used {r['frames']} / {r['in_view']} ({r['windows']}) | {r['exit']} | {first} | "
          f"{r['rot_err']:.2f} ({z(r['rpy_z'][0])}/{z(r['rpy_z'][1])}/{z(r['rpy_z'][2])}) | "
          f"{r['xy_err_mm'][0]:+.0f} ({z(r['xy_z'][0])}), {r['xy_err_mm'][1]:+.1f} ({z(r['xy_z'][1])}) | "
          f"{r['td_err_ms']:+.1f} ({z(r['td_z'])}) | {1e3*(r['r_est']-r['r_true']):+.1f} ({z(r['r_z'])}) | "
          f"{1e3*(r['b_est']-r['b_true']):+.0f} ({z(r['b_z'])}) |")
