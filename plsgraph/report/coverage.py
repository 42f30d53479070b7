"""Detection coverage for the HTML report: per-window outcomes over time and event frames with the grid drawn.

The front end keeps every window's outcome (``camera_track.info["window_outcomes"]``: the windows' end times
and, per window, the detector that found the board or the reason nothing was found). :func:`fig_coverage` draws
them as a strip over time, :func:`fig_event_frames` a few event frames (count images of one window) with the
detected circles and their order drawn on them; both are figures of :data:`plsgraph.report.figures.FIGURES`
(drawn with the others, in the figure worker when there is one). :func:`coverage_table` is the HTML table of
counts, cheap enough for the report page itself.

A window without a detection while the robot stood still is no failure of the detector: a still camera before a
still board sees no change and makes no events. :func:`window_outcomes` relabels such windows ``robot_still``,
from the odometry around each window (on the odometry's clock, through the calibrated time offset), and
:func:`coverage_summary` counts the board's windows found while the robot moved, which is what a recording can be
judged by (report.json ``coverage``).
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
    "not_searched_while_lost": (0.7, 0.7, 0.7),
    "grid_not_found": (0.84, 0.15, 0.16),
    "inconsistent_order": (1.0, 0.5, 0.05),
    "ambiguous_labels": (0.58, 0.4, 0.74),
    "too_few_points": (0.55, 0.34, 0.29),
    "same_stamp": (0.5, 0.5, 0.5),
    "no_pose": (0.35, 0.35, 0.35),
    "robot_still": (0.93, 0.93, 0.75),
    "no_odometry": (0.97, 0.97, 0.97),
}

#: A window counts as one of a still robot when, over STILL_HALF_S either side of it, the base moved less than
#: STILL_MOVE_M and turned less than STILL_TURN_RAD (about 0.6 px/s of image motion of a board 1.5 m away at
#: 300 px focal length; an encoder's one-tick dither stays under both).
STILL_HALF_S = 0.25
STILL_MOVE_M = 1e-3
STILL_TURN_RAD = 1e-3


#: Outcomes that are detections (the detector that found the board).
DETECTED = ("rims", "blobs", "image")
#: The outcome of a window passed over while the board was lost (plsgraph.frontend.track.LOST_SEARCH_STRIDE).
NOT_SEARCHED = "not_searched_while_lost"
#: Outcomes of a board found and then refused: kept as they are while the robot stands still too.
REFUSED = ("jumped_from_track", "inconsistent_with_neighbours", "same_stamp", "ambiguous_labels", "inconsistent_order",
           "mirrored_order", "no_pose")


def odometry_covers(t_odometry: np.ndarray, base_track: Any) -> np.ndarray:
    """Per time (odometry clock, s): whether it lies inside the odometry's span."""
    t = np.asarray(t_odometry, dtype=float)
    if base_track is None or len(base_track) < 2 or t.size == 0:
        return np.zeros(t.size, dtype=bool)
    tb = np.asarray(base_track.t, dtype=float)
    return (t >= tb[0]) & (t <= tb[-1])


def robot_still(t_odometry: np.ndarray, base_track: Any) -> np.ndarray:
    """Per time (odometry clock, s): whether the base stood still over STILL_HALF_S either side of it. Times whose
    neighbourhood is not inside the odometry's span are not still (nothing says so)."""
    t = np.asarray(t_odometry, dtype=float)
    still = np.zeros(t.size, dtype=bool)
    if base_track is None or len(base_track) < 2 or t.size == 0:
        return still
    tb = np.asarray(base_track.t, dtype=float)
    a, b = t - STILL_HALF_S, t + STILL_HALF_S
    inside = (a >= tb[0]) & (b <= tb[-1])
    if not np.any(inside):
        return still
    # Over a stretch: the largest departure of any sample inside it from its first pose (a robot that drives away
    # and back is not still), and the same for the heading.
    T = np.asarray(base_track.T_world_base, dtype=float)
    xy = T[:, :2, 3]
    yaw = np.unwrap(np.arctan2(T[:, 1, 0], T[:, 0, 0]))
    i0 = np.searchsorted(tb, a[inside], side="left")
    i1 = np.searchsorted(tb, b[inside], side="right")
    ok = np.zeros(i0.size, dtype=bool)
    for n, (j0, j1) in enumerate(zip(i0, i1, strict=True)):
        j0 = max(j0 - 1, 0)  # the sample just before the stretch: a robot that set off inside it moved
        j1 = min(j1 + 1, tb.size)
        d = np.linalg.norm(xy[j0:j1] - xy[j0], axis=1).max(initial=0.0)
        w = np.abs(yaw[j0:j1] - yaw[j0]).max(initial=0.0)
        ok[n] = d < STILL_MOVE_M and w < STILL_TURN_RAD
    still[inside] = ok
    return still


def _odometry_offset_s(run: Any) -> float:
    """Camera clock -> odometry clock: the coarse clock shift plus the calibrated td (refined, else closed form)."""
    td = 0.0
    ref, cf = getattr(run, "refinement", None), getattr(run, "closed_form", None)
    if ref is not None and getattr(ref, "converged", False) and np.isfinite(getattr(ref, "td", np.nan)):
        td = float(ref.td)
    elif cf is not None and getattr(cf, "td", None) is not None and np.isfinite(cf.td):
        td = float(cf.td)
    return float(getattr(run, "clock_offset_s", 0.0) or 0.0) + td


#: The outcome of a window missed where the odometry says nothing of the robot (outside its span, or on another clock
#: not aligned yet): neither a still robot's nor one of a moving robot.
NO_ODOMETRY = "no_odometry"


def clocks_unknown(run: Any) -> bool:
    """Whether the odometry is on a clock the camera's was never aligned with: a second file (or ``--clock-align
    always``) and the run ended before the pairing aligned them. Its times then say nothing of the windows'."""
    info = getattr(run, "recording_info", None) or {}
    if info.get("clock") is not None:  # the pairing aligned the clocks (or took them as the same)
        return False
    inputs = getattr(getattr(run, "options", None), "inputs", None)
    if inputs is None or inputs.clock_offset is not None or inputs.clock_align == "never":
        return False  # the user gave the clocks' difference, or said they are one clock
    return inputs.odometry_file is not None or inputs.clock_align == "always"


def window_outcomes(info: dict, run: Any = None) -> np.ndarray:
    """Every window's outcome (as the front end gave it), with the windows missed while the robot stood still
    (``run``'s odometry says so) relabelled ``robot_still``, and those missed where the odometry does not reach
    :data:`NO_ODOMETRY`."""
    wo = info.get("window_outcomes")
    if not wo or len(wo["outcome"]) == 0:
        return np.zeros(0, dtype=str)
    outcome = np.asarray(wo["outcome"], dtype=object)
    base = getattr(run, "base_track", None)
    if base is not None and not clocks_unknown(run):
        t = np.asarray(wo["t"], dtype=float) + _odometry_offset_s(run)
        missed = ~np.isin(outcome, DETECTED + REFUSED)
        outcome[robot_still(t, base) & missed] = "robot_still"
        outcome[~odometry_covers(t, base) & missed] = NO_ODOMETRY
    return outcome.astype(str)


def outcome_counts(info: dict, run: Any = None) -> dict[str, int]:
    """Windows per outcome (only outcomes that occur); with ``run``, missed windows of a still robot are counted
    as ``robot_still``."""
    outcome = window_outcomes(info, run)
    if outcome.size == 0:
        return {}
    names, counts = np.unique(outcome, return_counts=True)
    return {str(n): int(c) for n, c in zip(names, counts, strict=True)}


def coverage_summary(info: dict, run: Any = None) -> dict | None:
    """report.json's ``coverage``: windows, windows with the board found, windows missed while the robot stood
    still, windows missed where the odometry says nothing (``no_odometry``), ``found_fraction_robot_moving`` = found /
    (windows - those missed while still - those without odometry; None when no window is left), plus the counts per
    outcome."""
    counts = outcome_counts(info, run)
    if not counts:
        return None
    windows = sum(counts.values())
    found = sum(v for k, v in counts.items() if k in DETECTED)
    still = counts.get("robot_still", 0)
    unknown = counts.get(NO_ODOMETRY, 0)
    moving = windows - still - unknown
    apart = run is not None and getattr(run, "base_track", None) is not None and clocks_unknown(run)
    out = {"windows": windows, "found": found, "robot_still": still, NO_ODOMETRY: unknown,
           "found_fraction": found / windows,
           "found_fraction_robot_moving": found / moving if moving and not apart else None,
           "by_outcome": dict(sorted(counts.items(), key=lambda kv: -kv[1]))}
    if apart:  # the windows' outcomes are the front end's own: nothing is known of the robot's motion then
        out["clocks_not_aligned"] = True
    return out


def fig_coverage(run: Any, out: Path, truth_T: Any = None) -> str | None:
    """coverage.png: every window's outcome as a strip over time."""
    track = getattr(run, "camera_track", None)
    info = {} if track is None else track.info
    wo = info.get("window_outcomes")
    if not wo or len(wo["outcome"]) == 0:
        return None
    from .figures import DPI, _plt, _save

    plt = _plt()
    t = np.asarray(wo["t"], dtype=float)
    t = t - t[0]
    outcome = window_outcomes(info, run)
    names = sorted(set(outcome.tolist()), key=lambda n: (n not in DETECTED, n))
    code = np.array([names.index(o) for o in outcome], dtype=int)
    from matplotlib.patches import Patch

    fig, ax = plt.subplots(figsize=(8.0, 1.9), dpi=DPI)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    # Runs of windows with one outcome are drawn as one bar each (a bar per window took a second for 600 windows).
    start = np.flatnonzero(np.r_[True, code[1:] != code[:-1]])
    end = np.r_[start[1:], code.size]
    handles = []
    for i, name in enumerate(names):
        runs = np.flatnonzero(code[start] == i)
        if runs.size == 0:
            continue
        colour = _COLOURS.get(name, (0.6, 0.6, 0.6))
        a, b = start[runs], end[runs] - 1
        ax.broken_barh(list(zip(t[a], t[b] - t[a] + dt, strict=True)), (0.0, 1.0), facecolors=colour, linewidth=0)
        handles.append(Patch(facecolor=colour, label=f"{name} ({np.count_nonzero(code == i)})"))
    ax.set_ylim(0.0, 1.0)
    ax.set_yticks([])
    ax.set_xlim(t[0], t[-1] + dt)
    ax.set_xlabel("time in the recording (s)")
    ax.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 1.02), ncol=4, fontsize=7, frameon=False)
    return _save(plt, fig, out, "coverage.png")


def fig_event_frames(run: Any, out: Path, truth_T: Any = None, n_frames: int = 3) -> str | None:
    """event_frames.png: the count images of a few detected windows side by side, the detected circles drawn on
    them and joined in the board's order (the first circle red). The windows are those the streaming front end kept
    (Run.event_frames) nearest the first, middle and last detection; without them (tracks given to the API) the
    first, middle and last detection's windows are read from the recording."""
    import cv2

    track = getattr(run, "camera_track", None)
    log_path = getattr(run, "log_path", None)
    det = None if track is None else track.detections
    if det is None or len(det) == 0:
        return None
    window_s = float(track.info.get("window_s") or 1.0 / 30.0)
    picks = np.unique(np.linspace(0, len(det) - 1, n_frames).round().astype(int))
    # Detections are on the odometry clock when the camera track was shifted there; events are not.
    shift = float(getattr(run, "clock_offset_s", 0.0) or 0.0)
    half = int(window_s * 0.5e9)
    mids = np.array([int(round((float(t) - shift) * 1e9)) for t in det.t], dtype=np.int64)
    # The windows the front end kept, each pick's nearest if near enough; the others read from the recording.
    tol_ns = max(1_000_000_000, int(0.1 * (int(mids[-1]) - int(mids[0]))))
    chosen = _kept_frames(getattr(run, "event_frames", None), mids, picks, tol_ns)
    readable = log_path is not None and Path(log_path).is_file()
    if any(c is None for c in chosen) and readable:
        missing = [int(p) for p, c in zip(picks, chosen, strict=True) if c is None]
        read = _window_counts(log_path, [(int(mids[i]) - half, int(mids[i]) + half) for i in missing])
        got = dict(zip(missing, read, strict=True))
        chosen = [c if c is not None else (p, got[int(p)]) for p, c in zip(picks, chosen, strict=True)]
    chosen = [c for c in chosen if c is not None]
    if not chosen:
        return None  # tracks given without their recording
    picks, frames = [c[0] for c in chosen], [c[1] for c in chosen]
    tiles = []
    for i, img in zip(picks, frames, strict=True):
        if img is None:
            continue
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
    if not cv2.imwrite(str(out / "event_frames.png"), row):  # OpenCV says nothing else (a full disk, a bad folder)
        (out / "event_frames.png").unlink(missing_ok=True)
        raise OSError(f"event_frames.png could not be written into {out}")
    return "event_frames.png"


def _kept_frames(kept: list | None, mids: np.ndarray, picks: np.ndarray, tol_ns: int) -> list[tuple | None]:
    """For each of ``picks`` (indices into the detections, ``mids`` their windows' mids on the events' clock), a count
    image the front end kept (``kept``: (mid ns, image), see Run.event_frames) of a detection still in the track, the
    one nearest the pick within ``tol_ns`` and not given to another pick: (that detection's index, its image as
    float32); None where there is none (the pick's own window is then read from the recording)."""
    if not kept:
        return [None] * len(picks)
    at = {}
    for mid, img in kept:
        i = int(np.argmin(np.abs(mids - mid)))
        if abs(int(mids[i]) - mid) <= 1000:  # the same detection (to rounding: the track may have been shifted)
            at[i] = img
    out: list[tuple | None] = []
    used: set[int] = set()
    for p in picks:
        free = [i for i in at if i not in used and abs(int(mids[i]) - int(mids[p])) <= tol_ns]
        if not free:
            out.append(None)
            continue
        i = min(free, key=lambda i: abs(int(mids[i]) - int(mids[p])))
        used.add(i)
        out.append((i, at[i].astype(np.float32)))
    return out


def _window_counts(log_path: Any, windows: list[tuple[int, int]]) -> list[np.ndarray | None]:
    """Count images of the events in each time window [t0, t1) (ns), in one pass over the recording's events (None
    for a window without events)."""
    from ..io.events_reader import iter_event_chunks

    imgs: list[np.ndarray | None] = [None] * len(windows)
    lo, hi = min(w[0] for w in windows), max(w[1] for w in windows)
    for ch in iter_event_chunks(log_path, None, t0=lo, t1=hi):
        for k, (a, b) in enumerate(windows):
            i0, i1 = np.searchsorted(ch.t, [a, b], side="left")
            if i1 <= i0:
                continue
            if imgs[k] is None:
                imgs[k] = np.zeros((ch.height, ch.width), np.float32)
            np.add.at(imgs[k], (ch.y[i0:i1].astype(int), ch.x[i0:i1].astype(int)), 1.0)
    return imgs


def coverage_table(info: dict, run: Any = None) -> str | None:
    """HTML: how many windows found the board, by which detector, and why the others did not (with ``run``, the
    windows missed while the robot stood still on a line of their own)."""
    cov = coverage_summary(info, run)
    if cov is None:
        return None
    counts, total, found = cov["by_outcome"], cov["windows"], cov["found"]

    def label(k: str) -> str:
        if k in DETECTED:
            return f"found by {html.escape(k)}"
        if k == NOT_SEARCHED:
            return "not searched: the board was lost (only every few windows are searched then)"
        if k == NO_ODOMETRY:
            return "not found, where the odometry says nothing of the robot (outside its span or clock)"
        return "not found: the robot stood still" if k == "robot_still" else f"missed: {html.escape(k)}"

    rows = "".join(f"<tr><td>{label(k)}</td><td>{v}</td><td>{100.0 * v / total:.1f} %</td></tr>"
                   for k, v in sorted(counts.items(), key=lambda kv: (kv[0] not in DETECTED, kv[0] == NOT_SEARCHED,
                                                                      -kv[1])))
    moving = ""
    if cov["robot_still"]:
        moving = f" The robot stood still in {cov['robot_still']} of them (no motion, no events)."
    if cov.get(NO_ODOMETRY):
        moving += (f" In {cov[NO_ODOMETRY]} windows without the board the odometry says nothing of the robot (they "
                   "lie outside its span, or on a clock not yet aligned with it).")
    if moving and cov["found_fraction_robot_moving"] is not None:
        moving += (f" Of the windows in which it moved, {100.0 * cov['found_fraction_robot_moving']:.0f} % found the "
                   "board.")
    return (f"<p>The board was found in {found} of {total} windows ({100.0 * found / total:.0f} %).{moving} "
            "Windows without events from the board cannot show it. The figures "
            "'detection coverage' and 'event frames' below show when and what the detector saw.</p>"
            f"<table><tr><th>window outcome</th><th>windows</th><th>share</th></tr>{rows}</table>")
