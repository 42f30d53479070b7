"""Detection coverage for the HTML report: per-window outcomes over time and event frames with the grid drawn.

The front end keeps every window's outcome (``camera_track.info["window_outcomes"]``: the windows' end times
and, per window, the detector that found the board or the reason nothing was found). :func:`coverage_sections`
draws them as a strip over time with a table of counts, and renders a few event frames (count images of one
window) with the detected circles and their order drawn on them. It returns HTML
snippets for report.html; PNGs go next to it. A failure is the caller's to log: figures never cost the numbers.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

#: Colours (RGB 0-1) per outcome; reasons not listed are grey.
_COLOURS = {
    "rims": (0.17, 0.63, 0.17),
    "blobs": (0.45, 0.78, 0.30),
    "image": (0.12, 0.47, 0.71),
    "circles_too_small_for_rims": (0.9, 0.7, 0.1),
    "too_few_events": (0.8, 0.8, 0.8),
    "grid_not_found": (0.84, 0.15, 0.16),
    "inconsistent_order": (1.0, 0.5, 0.05),
    "ambiguous_labels": (0.58, 0.4, 0.74),
    "too_few_points": (0.55, 0.34, 0.29),
    "time_not_increasing": (0.5, 0.5, 0.5),
}


#: Outcomes that are detections (the detector that found the board).
DETECTED = ("rims", "blobs", "image")


def outcome_counts(info: dict) -> dict[str, int]:
    """Windows per outcome (only outcomes that occur)."""
    wo = info.get("window_outcomes")
    if not wo or len(wo["outcome"]) == 0:
        return {}
    names, counts = np.unique(np.asarray(wo["outcome"], dtype=str), return_counts=True)
    return {str(n): int(c) for n, c in zip(names, counts, strict=True)}


def _fig_coverage(info: dict, out: Path) -> str | None:
    wo = info.get("window_outcomes")
    if not wo or len(wo["outcome"]) == 0:
        return None
    from .figures import _plt, _save

    plt = _plt()
    t = np.asarray(wo["t"], dtype=float)
    t = t - t[0]
    outcome = np.asarray(wo["outcome"], dtype=str)
    names = sorted(set(outcome.tolist()), key=lambda n: (n not in DETECTED, n))
    code = np.array([names.index(o) for o in outcome], dtype=int)
    fig, ax = plt.subplots(figsize=(8.0, 1.9))
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    for i, name in enumerate(names):
        sel = code == i
        if np.any(sel):
            ax.bar(t[sel], 1.0, width=dt, color=_COLOURS.get(name, (0.6, 0.6, 0.6)), align="edge",
                   label=f"{name} ({np.count_nonzero(sel)})", linewidth=0)
    ax.set_yticks([])
    ax.set_xlim(t[0], t[-1] + dt)
    ax.set_xlabel("time in the recording (s)")
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.02), ncol=4, fontsize=7, frameon=False)
    fig.tight_layout()
    return _save(plt, fig, out, "coverage.png")


def _event_frames(run: Any, out: Path, n_frames: int = 3) -> list[str]:
    """Count images of a few detected windows with the detected circles drawn, as PNG names."""
    import cv2

    from ..io.events_reader import read_events

    track = run.camera_track
    det = track.detections
    if det is None or len(det) == 0:
        return []
    window_s = float(track.info.get("window_s") or 1.0 / 30.0)
    picks = np.unique(np.linspace(0, len(det) - 1, n_frames).round().astype(int))
    names = []
    for j, i in enumerate(picks):
        # Detections are on the odometry clock when the camera track was shifted there; events are not.
        t_ns = int(round((float(det.t[i]) - float(getattr(run, "clock_offset_s", 0.0) or 0.0)) * 1e9))
        half = int(window_s * 0.5e9)
        ev = read_events(run.log_path, None, t_ns - half, t_ns + half)
        if len(ev) == 0:
            continue
        img = np.zeros((ev.height, ev.width), np.float32)
        np.add.at(img, (ev.y.astype(int), ev.x.astype(int)), 1.0)
        hi = max(1.0, float(np.percentile(img[img > 0], 95)))
        g = (np.clip(img / hi, 0, 1) * 255).astype(np.uint8)
        s = 3
        big = cv2.resize(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
        uv = np.asarray(det.uv[i], dtype=float)
        seen = np.all(np.isfinite(uv), axis=1)
        pts = [(int(round((u + 0.5) * s)), int(round((v + 0.5) * s))) for u, v in uv[seen]]
        for a, b in zip(pts[:-1], pts[1:], strict=False):  # the order, as the board numbers its circles
            cv2.line(big, a, b, (0, 200, 255), 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(big, p, 4, (0, 255, 0), 1, cv2.LINE_AA)
        if pts:
            cv2.circle(big, pts[0], 6, (0, 0, 255), 2, cv2.LINE_AA)  # the board's first circle
        name = f"event_frame_{j}.png"
        cv2.imwrite(str(out / name), big)
        names.append(name)
    return names


def coverage_sections(run: Any, out: Path) -> list[tuple[str, str]]:
    """Report sections (title, HTML) for the front end's coverage; writes coverage.png and event frames."""
    track = getattr(run, "camera_track", None)
    if track is None:
        return []
    info = track.info
    counts = outcome_counts(info)
    parts = []
    fig = _fig_coverage(info, out)
    if fig:
        parts.append(f"<img src='{html.escape(fig)}' alt='detection coverage'>")
    if counts:
        total = sum(counts.values())
        found = sum(v for k, v in counts.items() if k in DETECTED)
        rows = "".join(f"<tr><td>{'found by ' if k in DETECTED else 'missed: '}{html.escape(k)}</td><td>{v}</td>"
                       f"<td>{100.0 * v / total:.1f} %</td></tr>"
                       for k, v in sorted(counts.items(), key=lambda kv: (kv[0] not in DETECTED, -kv[1])))
        parts.append(f"<p>The board was found in {found} of {total} windows ({100.0 * found / total:.0f} %). "
                     "Windows without events from the board (a robot standing still) cannot show it.</p>")
        parts.append(f"<table><tr><th>window outcome</th><th>windows</th><th>share</th></tr>{rows}</table>")
    sections = [("Detection coverage", "\n".join(parts))] if parts else []
    frames = _event_frames(run, out)
    if frames:
        sections.append(("Event frames with the detected grid", "<p>Events of one window at three detections; "
                         "green: detected circles, joined in the board's order (red: the first).</p>"
                         + "".join(f"<img src='{html.escape(f)}' alt='event frame'>" for f in frames)))
    return sections
