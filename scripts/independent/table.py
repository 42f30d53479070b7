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
    first = (r["problems"][:1] or [w for w in r["warnings"] if "gap" in w or "reset" in w or "settle" in w][:1] or [""])[0][:90]
    print(f"| {t} | {r['level']} | {r['ev_s']/1e3:.0f}k | {r['det']} used {r['frames']} / {r['in_view']} ({r['windows']}) | {r['exit']} | {first} | "
          f"{r['rot_err']:.2f} ({r['rpy_z'][0]:+.1f}/{r['rpy_z'][1]:+.1f}/{r['rpy_z'][2]:+.1f}) | "
          f"{r['xy_err_mm'][0]:+.0f} ({r['xy_z'][0]:+.1f}), {r['xy_err_mm'][1]:+.1f} ({r['xy_z'][1]:+.1f}) | "
          f"{r['td_err_ms']:+.1f} ({r['td_z']:+.1f}) | {1e3*(r['r_est']-r['r_true']):+.1f} ({r['r_z']:+.1f}) | "
          f"{1e3*(r['b_est']-r['b_true']):+.0f} ({r['b_z']:+.1f}) |")
