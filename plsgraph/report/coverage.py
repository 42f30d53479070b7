"""Detection coverage for the HTML report: per-window outcomes over time and event frames with the grid drawn.

The front end keeps every window's outcome (``camera_track.info["window_outcomes"]``: the windows' end times
and, per window, the detector that found the board or the reason nothing was found). :func:`fig_coverage` draws
them as a strip over time, :func:`fig_event_frames` a few event frames (count images of one window) with the
detected circles and their order drawn on them; both are figures of :data:`plsgraph.report.figures.FIGURES`
(drawn with the others, in the figure worker when there is one). :func:`coverage_table` is the HTML table of
counts, cheap enough for the report page itself.
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
    "same_stamp": (0.5, 0.5, 0.5),
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


def fig_coverage(run: Any, out: Path, truth_T: Any = None) -> str | None:
    """coverage.png: every window's outcome as a strip over time."""
    track = getattr(run, "camera_track", None)
    info = {} if track is None else track.info
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


def fig_event_frames(run: Any, out: Path, truth_T: Any = None, n_frames: int = 3) -> str | None:
    """event_frames.png: the count images of a few detected windows side by side, the detected circles drawn on
    them and joined in the board's order (the first circle red)."""
    import cv2

    from ..io.events_reader import read_events

    track = getattr(run, "camera_track", None)
    log_path = getattr(run, "log_path", None)
    det = None if track is None else track.detections
    if det is None or len(det) == 0 or log_path is None or not Path(log_path).is_file():
        return None  # no detections, or tracks given without their recording
    window_s = float(track.info.get("window_s") or 1.0 / 30.0)
    picks = np.unique(np.linspace(0, len(det) - 1, n_frames).round().astype(int))
    tiles = []
    for i in picks:
        # Detections are on the odometry clock when the camera track was shifted there; events are not.
        t_ns = int(round((float(det.t[i]) - float(getattr(run, "clock_offset_s", 0.0) or 0.0)) * 1e9))
        half = int(window_s * 0.5e9)
        ev = read_events(log_path, None, t_ns - half, t_ns + half)
        if len(ev) == 0:
            continue
        img = np.zeros((ev.height, ev.width), np.float32)
        np.add.at(img, (ev.y.astype(int), ev.x.astype(int)), 1.0)
        hi = max(1.0, float(np.percentile(img[img > 0], 95)))
        g = (np.clip(img / hi, 0, 1) * 255).astype(np.uint8)
        s = 2
        big = cv2.resize(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), None, fx=s, fy=s, interpolation=cv2.INTER_NEAREST)
        uv = np.asarray(det.uv[i], dtype=float)
        seen = np.all(np.isfinite(uv), axis=1)
        pts = [(int(round((u + 0.5) * s)), int(round((v + 0.5) * s))) for u, v in uv[seen]]
        for a, b in zip(pts[:-1], pts[1:], strict=False):  # the order, as the board numbers its circles
            cv2.line(big, a, b, (0, 200, 255), 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(big, p, 3, (0, 255, 0), 1, cv2.LINE_AA)
        if pts:
            cv2.circle(big, pts[0], 5, (0, 0, 255), 2, cv2.LINE_AA)  # the board's first circle
        tiles.append(big)
    if not tiles:
        return None
    gap = np.full((tiles[0].shape[0], 6, 3), 255, np.uint8)
    row = tiles[0]
    for tile in tiles[1:]:
        row = np.hstack([row, gap, tile])
    cv2.imwrite(str(out / "event_frames.png"), row)
    return "event_frames.png"


def coverage_table(info: dict) -> str | None:
    """HTML: how many windows found the board, by which detector, and why the others did not."""
    counts = outcome_counts(info)
    if not counts:
        return None
    total = sum(counts.values())
    found = sum(v for k, v in counts.items() if k in DETECTED)
    rows = "".join(f"<tr><td>{'found by ' if k in DETECTED else 'missed: '}{html.escape(k)}</td><td>{v}</td>"
                   f"<td>{100.0 * v / total:.1f} %</td></tr>"
                   for k, v in sorted(counts.items(), key=lambda kv: (kv[0] not in DETECTED, -kv[1])))
    return (f"<p>The board was found in {found} of {total} windows ({100.0 * found / total:.0f} %). "
            "Windows without events from the board (a robot standing still) cannot show it. The figures "
            "'detection coverage' and 'event frames' below show when and what the detector saw.</p>"
            f"<table><tr><th>window outcome</th><th>windows</th><th>share</th></tr>{rows}</table>")
