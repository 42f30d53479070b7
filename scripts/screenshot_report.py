#!/usr/bin/env python3
"""Screenshot a plsgraph report.html with headless Chromium (to check the page as a person sees it).

    scripts/screenshot_report.py OUT/report.html [--png report.png] [--width 1200] [--height 2400]

Skips with a message (exit 0) when no Chromium is installed (``apt-get install -y chromium``).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

CANDIDATES = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    for c in CANDIDATES:
        p = c if Path(c).is_file() else shutil.which(c)
        if p:
            return str(p)
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("report", type=Path)
    ap.add_argument("--png", type=Path, help="output PNG (default: report.png beside the report)")
    ap.add_argument("--width", type=int, default=1200)
    ap.add_argument("--height", type=int, default=2400)
    args = ap.parse_args(argv)
    if not args.report.is_file():
        print(f"no such report: {args.report}", file=sys.stderr)
        return 2
    exe = find_chromium()
    if exe is None:
        print("skipped: no Chromium found (tried " + ", ".join(CANDIDATES) + "); apt-get install -y chromium")
        return 0
    png = (args.png or args.report.with_name("report.png")).resolve()
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", f"--screenshot={png}",
           f"--window-size={args.width},{args.height}", args.report.resolve().as_uri()]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        print("chromium did not finish within 120 s", file=sys.stderr)
        return 1
    if proc.returncode != 0 or not png.is_file():
        print(f"chromium failed ({proc.returncode}): {proc.stderr.strip()[-500:]}", file=sys.stderr)
        return 1
    print(f"written: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
