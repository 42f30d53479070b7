"""Gaps in a recording: where the odometry or the events stop for a while (dropped messages, a damaged file).

Odometry is never interpolated across a gap the robot moved across: its path there is unknown (a wheel-joint
track integrates the whole gap as one arc). A short gap in odometry whose net motion is known (cumulative wheel
angles, odometry poses) is bridged: the whole recording is kept, no camera frame near the gap is used, and the
refinement's odometry edge across it carries only a loose position (docs/odometry_and_time_offset.md, "Gaps in
the wheel messages"). Otherwise the calibration uses the longest stretch of the recording without such a gap, if it
is long enough, and says what it cut; a gap during which the robot stood still is harmless and kept. Event gaps
leave holes in the camera track; the detections whose windows reach into one are dropped (a window that saw only
part of its events places the board wrongly).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from .core.tracks import PER_FRAME_INFO, BaseTrack, CameraTrack, gap_indices
from .errors import InsufficientDataError

GAP_MOTION_M = 0.005  # a gap the base moved more than this across (or turned GAP_MOTION_DEG) cuts the motion
GAP_MOTION_DEG = 0.5

#: No events for this long is a gap in the event stream (a live sensor in front of a board never pauses so long
#: while the robot moves; dropped packets or a damaged chunk do).
EVENT_GAP_S = 0.2
#: Odometry gaps up to this long are bridged when the motion across them is known as a whole (see the module's
#: text); a longer one is cut. Over a second of driving the path's shape is unknown enough that the edge would
#: carry little but the heading.
MAX_BRIDGE_S = 1.0
#: The stretch kept after cutting at gaps must be at least this long (the closed form needs 3 s of velocity pairs
#: for every td within +-0.5 s, i.e. 4 s, plus the detection holes;
#: and the refinement turning in both directions) ...
MIN_SEGMENT_S = 5.0
#: ... and hold at least this many camera frames with the board.
MIN_SEGMENT_FRAMES = 30


def motion_gaps(track: BaseTrack) -> list[tuple[float, float]]:
    """The odometry gaps (t_start, t_end) across which the base moved more than GAP_MOTION_M or GAP_MOTION_DEG."""

    out = []
    for a, b in np.asarray(track.info.get("gaps", np.zeros((0, 2))), dtype=float).reshape(-1, 2):
        i = int(np.searchsorted(track.t, a))
        j = int(np.searchsorted(track.t, b))
        if i >= len(track) or j >= len(track):
            continue
        Ta, Tb = track.T_world_base[i], track.T_world_base[j]
        moved = np.linalg.norm(Tb[:2, 3] - Ta[:2, 3])
        turned = abs(np.degrees(np.arctan2(Tb[1, 0], Tb[0, 0]) - np.arctan2(Ta[1, 0], Ta[0, 0])))
        turned = min(turned, 360.0 - turned)
        if moved > GAP_MOTION_M or turned > GAP_MOTION_DEG:
            out.append((float(a), float(b)))
    return out


def bridgeable(track: BaseTrack, gaps: list[tuple[float, float]]) -> bool:
    """Whether every one of ``gaps`` can be bridged: the track knows its net motion across gaps (cumulative wheel
    angles or odometry poses), each is at most MAX_BRIDGE_S long, and no jump (a reset that adds no motion) lies in
    one or on its closing step, where it would have taken the gap's motion with it."""
    if not gaps or not track.info.get("net_motion_known", False):
        return False
    jumps = np.asarray(track.info.get("jumps", np.zeros(0)), dtype=float).ravel()
    step = float(np.median(np.diff(track.t))) if len(track) > 1 else 0.0
    for a, b in gaps:
        if b - a > MAX_BRIDGE_S:
            return False
        if jumps.size and np.any((jumps >= a) & (jumps <= b + step)):
            return False
    return True


def bridged_gaps(track: BaseTrack) -> np.ndarray:
    """The track's bridged odometry gaps (k, 2) (empty when none were bridged)."""
    return np.asarray(track.info.get("bridged_gaps", np.zeros((0, 2))), dtype=float).reshape(-1, 2)


def event_gaps(t_ns: np.ndarray, prev_last_ns: int | None, gap_s: float = EVENT_GAP_S) -> list[tuple[int, int]]:
    """Gaps (start, end in ns) in one chunk of sorted event times, including the step from the previous chunk."""
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size == 0:
        return []
    if prev_last_ns is not None:
        t = np.r_[np.int64(prev_last_ns), t]
    lim = int(gap_s * 1e9)
    d = np.diff(t)
    k = np.flatnonzero(d > lim)
    return [(int(t[i]), int(t[i + 1])) for i in k]


def _slice_base(track: BaseTrack, i0: int, i1: int) -> BaseTrack:
    gaps = np.asarray(track.info.get("gaps", np.zeros((0, 2))), dtype=float).reshape(-1, 2)
    t0, t1 = track.t[i0], track.t[i1 - 1]
    keep = (gaps[:, 0] >= t0) & (gaps[:, 1] <= t1)
    jumps = np.asarray(track.info.get("jumps", np.zeros(0))).ravel()
    info = dict(track.info, gaps=gaps[keep], jumps=jumps[(jumps >= t0) & (jumps <= t1)],
                warnings=[w for w in track.info.get("warnings", []) if "gap" not in w])
    return BaseTrack(track.t[i0:i1], track.T_world_base[i0:i1], track.v[i0:i1], track.omega[i0:i1], info=info)


def _slice_camera(track: CameraTrack, keep: np.ndarray) -> CameraTrack:
    det = track.detections
    info = track.info
    if det is not None:
        dmask = np.isin(det.t, track.t[keep]) if len(det) != len(track) else keep
        # The per-detection lists follow the detections (the refinement's span and detector filters read them by
        # detection; left long, they would be skipped).
        info = dict(info)
        for key in PER_FRAME_INFO:
            if key in info and len(info[key]) == len(det):
                info[key] = [x for x, k in zip(info[key], dmask, strict=True) if k]
        det = det.subset(dmask)
    return replace(track, t=track.t[keep], T_board_cam=track.T_board_cam[keep],
                   cov=None if track.cov is None else track.cov[keep],
                   rms_px=None if track.rms_px is None else track.rms_px[keep], detections=det, info=info)


def cut_at_gaps(run: Any) -> None:
    """Restrict the run's tracks to the longest stretch without an odometry gap the robot moved across, and drop
    camera frames whose detection window reaches into an event gap. Says what was cut (warnings, discarded);
    raises InsufficientDataError when too little is left."""
    base, cam = run.base_track, run.camera_track
    if base is None or cam is None:
        return
    window = float(cam.info.get("window_s", 0.05) or 0.05)
    ev_gaps = [(a * 1e-9, b * 1e-9) for a, b in run.recording_info.get("event_gaps_ns", [])]
    if ev_gaps:
        bad = np.zeros(len(cam), dtype=bool)
        for a, b in ev_gaps:
            bad |= (cam.t > a) & (cam.t < b + window)
        longest = max(ev_gaps, key=lambda g: g[1] - g[0])
        run.warn(f"{len(ev_gaps)} gap(s) in the event stream (longest {longest[1] - longest[0]:.2f} s at "
                 f"t={longest[0]:.2f} s): events were lost there"
                 + (f"; {int(bad.sum())} detection(s) whose window reaches into one were dropped" if bad.any() else ""))
        run.discarded["event_gaps"] = [[round(a, 4), round(b, 4)] for a, b in ev_gaps]
        if bad.any():
            run.discarded["frames_in_event_gaps"] = int(bad.sum())
            cam = _slice_camera(cam, ~bad)
    gaps = motion_gaps(base)
    if gaps and bridgeable(base, gaps):
        desc = ", ".join(f"{b - a:.2f} s at t={a:.2f} s" for a, b in gaps)
        run.discarded["odometry_gaps_bridged"] = [[round(a, 4), round(b, 4)] for a, b in gaps]
        run.warn(
            f"the odometry has {len(gaps)} gap(s) the robot moved across ({desc}); bridged: the wheels' net motion "
            "across each is known, its path is not, so no camera frame near one is used and the refinement takes "
            "only the heading and a loose position across it"
        )
        base = replace(base, info=dict(base.info, bridged_gaps=np.array(gaps, dtype=float).reshape(-1, 2)))
    elif gaps:
        # Segments between gaps, as index ranges [i0, i1) of the odometry; one sample on each side of a gap is
        # dropped too (its velocity was averaged over the gap step).
        cuts = [int(np.searchsorted(base.t, a)) for a, _ in gaps]
        bounds = [0] + [c for k in cuts for c in (k, k + 1)] + [len(base)]
        segs = [(bounds[2 * i] + (i > 0), bounds[2 * i + 1] - (i < len(gaps))) for i in range(len(gaps) + 1)]
        segs = [(i0, i1) for i0, i1 in segs if i1 - i0 >= 2]
        i0, i1 = max(segs, key=lambda s: base.t[s[1] - 1] - base.t[s[0]]) if segs else (0, 0)
        kept = (base.t[i0], base.t[i1 - 1]) if i1 > i0 else (0.0, 0.0)
        in_seg = (cam.t >= kept[0]) & (cam.t <= kept[1])
        desc = ", ".join(f"{b - a:.2f} s at t={a:.2f} s" for a, b in gaps)
        run.discarded["odometry_gaps_crossed_by_motion"] = [[round(a, 4), round(b, 4)] for a, b in gaps]
        run.discarded["kept_segment_s"] = [round(float(kept[0]), 4), round(float(kept[1]), 4)]
        run.discarded["frames_outside_kept_segment"] = int((~in_seg).sum())
        span = kept[1] - kept[0]
        if span < MIN_SEGMENT_S or in_seg.sum() < MIN_SEGMENT_FRAMES:
            raise InsufficientDataError(
                f"the odometry has {len(gaps)} gap(s) the robot moved across ({desc}); the longest stretch without "
                f"one is {span:.2f} s with {int(in_seg.sum())} camera frames (need {MIN_SEGMENT_S:g} s and "
                f"{MIN_SEGMENT_FRAMES}): record again without dropped messages"
            )
        run.warn(
            f"the odometry has {len(gaps)} gap(s) the robot moved across ({desc}); its path there is unknown, so "
            f"only the longest stretch without one was used: t={kept[0]:.2f}..{kept[1]:.2f} s ({span:.1f} s, "
            f"{int(in_seg.sum())} of {len(cam)} camera frames)"
        )
        base = _slice_base(base, i0, i1)
        cam = _slice_camera(cam, in_seg)
    run.base_track, run.camera_track = base, cam


__all__ = ["EVENT_GAP_S", "MAX_BRIDGE_S", "MIN_SEGMENT_S", "bridgeable", "bridged_gaps", "cut_at_gaps", "event_gaps",
           "gap_indices", "motion_gaps"]
