"""The event front end: event surfaces at a fixed rate -> board detection -> PnP -> camera track.

For each window the events just before the query time t_k are turned into an image
(:mod:`plsgraph.frontend.surfaces`), the board is detected in it (:mod:`plsgraph.frontend.detect`) and the pose is
solved by PnP (:mod:`plsgraph.frontend.pose`). What is counted in ``track.info``:

* ``windows``: windows tried; ``detected``: windows with a verified board detection;
  ``poses``: windows that produced a pose;
* ``skipped``: reason -> count over all windows that gave no pose: ``too_few_events`` (nothing
  moved), the detector's reasons (``grid_not_found``, ``inconsistent_order``, ``mirrored_order``,
  ``ambiguous_labels``, ``too_few_points``, ``empty_image``), ``time_not_increasing`` and PnP's
  (``pnp_failed``, ``rms_above_threshold``);
* ``detected_at_window_fraction``, ``seconds`` (surfaces, detection, PnP), ``warnings``.

Circle grids are found as rims (:func:`plsgraph.frontend.detect.detect_circle_grid` with
``foreground="rims"``): each kind's image is binarized at a level that keeps the pixels with recent
events (:func:`_rim_image`) and the circles' insides are the holes. After a detection the next
window is searched around the board first and its circles are labelled by their constant-velocity
predictions (:func:`plsgraph.frontend.detect.track_circle_grid`, which refuses anything a one-circle shift
could explain); the full lattice search runs otherwise.

Detection time stamps. A surface built from the events of (t_k - W, t_k] shows the board where
it was while those events happened, not where it is at t_k. With ``timestamp="events"`` (default)
each detection is stamped with the mean time of the events that formed the detected rims: those
inside the detected points' bounding box grown by half a spacing and young enough to be above the
rim level (for the decaying kinds: younger than tau). Detections read off a leaky integrator as an
intensity image are stamped t_k. For a circle moving at constant speed the inside that
stayed free of events is centred where the circle was at the middle of that span.
``timestamp="query"`` stamps t_k, or ``"window_centre"`` the middle of the span the rims show
(t_k - W / 2 for counts, t_k - tau / 2 for decaying kinds).

Fast motion smears a circle's rim over its whole inside within a full window; a window without a
detection is therefore retried on the most recent half, quarter and eighth of its span
(:data:`WINDOW_LADDER`); ``info["detected_at_window_fraction"]`` counts which span worked.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable

import cv2
import numpy as np

from ..core.board import Board
from ..core.camera import CameraModel
from ..core.events import EventStream
from ..core.tracks import CameraTrack, Detections
from ..errors import InputError, InsufficientDataError
from . import noise, surfaces
from .detect import (
    REASON_OK,
    board_is_symmetric,
    detect_aprilgrid,
    detect_circle_grid,
    make_aruco_detector,
)
from .pose import camera_track_from_detections

log = logging.getLogger(__name__)

#: Short names accepted for ``kind`` in addition to :data:`plsgraph.frontend.surfaces.KINDS`.
KIND_ALIASES = {"polarity": "polarity_aware", "classic": "time_surface", "ts": "time_surface"}
TIMESTAMPS = ("events", "query", "window_centre")

#: Default surface parameters per kind: the paper's values where it gives them.
DEFAULT_PARAMS: dict[str, dict] = {
    "count": {},
    "polarity_sum": {},
    "time_surface": {"tau_s": 0.03},
    "polarity_aware": {"alpha": 0.1, "blur_ksize": 5, "blur_sigma": 0.7},
    "leaky": {"tau_s": 0.05},
}


def resolve_kind(kind: str) -> str:
    k = KIND_ALIASES.get(kind, kind)
    if k not in surfaces.KINDS:
        raise InputError(f"front end: unknown surface kind {kind!r}; use one of {', '.join(surfaces.KINDS)} "
                         f"(or {', '.join(KIND_ALIASES)})")
    return k


def _rim_image(img: np.ndarray, kind: str, params: dict, age_s: float) -> tuple[np.ndarray, float]:
    """The activity image and the level above which a pixel counts as part of a rim.

    Counts and signed sums: any event (the surface is built from the events of the last ``age_s``
    only). Decaying kinds: events younger than ``age_s``, i.e. a level exp(-age / tau) (times the
    contrast step for the leaky integrator), so that old, smeared rims do not close the circles'
    insides. Polarity-aware surface: the paper's 5 x 5 blur spreads a one-pixel rim to about 0.57 at
    its centre line and an isolated event to about 0.32; 0.25 keeps rims.
    """
    if kind == "count":
        return img, 0.5
    if kind == "polarity_sum":
        return np.abs(img), 0.5
    if kind == "polarity_aware":
        return np.abs(img), 0.25
    unit = 1.0 if kind == "time_surface" else float(params.get("contrast", 0.2))
    return np.abs(img), unit * float(np.exp(-age_s / float(params["tau_s"])))


def _active_age_s(kind: str, params: dict, window_s: float) -> float:
    """Nominal age of the oldest events a rim image shows: tau for decaying kinds, else the window."""
    if kind in ("time_surface", "leaky") and params.get("tau_s"):
        return float(params["tau_s"])
    return window_s


#: Spans tried, as multiples of the nominal rim age (one frame period for counts). Fast motion smears a
#: circle's rim over its whole inside within a full window (shorter spans: half, quarter, eighth); slow motion
#: leaves only a few events on each rim (longer spans, up to 16 periods, built from noise-filtered events).
#: Each window starts with the span that the event rate around the board asks for (see ``_span_order``).
WINDOW_LADDER = (1.0, 0.5, 0.25, 0.125, 2.0, 4.0, 8.0, 16.0)
#: At most this many spans are tried per window: the ones closest to the span the event rate asks for.
MAX_SPANS_PER_WINDOW = 4
#: Spans longer than a period are searched over the whole image (no region from a previous detection) only
#: when they hold fewer events than this: slow motion, where they are needed, fires few.
MAX_LONG_SPAN_EVENTS = 60_000
#: Windows after the last detection during which the board is still searched for around where it was.
KEEP_ROI_WINDOWS = 15
#: Predicted motion per window, in neighbour spacings, beyond which circles are not labelled by prediction.
MAX_PREDICTED_STEP = 0.4
#: Per-window outcome codes kept in ``info["window_outcomes"]["code"]`` (int8); index into this tuple.
OUTCOMES = ("detected", "held_still", "too_few_events", "grid_not_found", "inconsistent_order", "mirrored_order",
            "ambiguous_labels", "too_few_points", "empty_image", "time_not_increasing")
_CODE = {name: np.int8(i) for i, name in enumerate(OUTCOMES)}
#: A board whose surroundings fire fewer (noise-filtered) events than this share of the rate at its last
#: detection has not moved: the window keeps the last detection (``held_still``) when no span finds the board.
STILL_RATE_FRACTION = 0.05


def _span_order(frac_wanted: float) -> list[int]:
    """Ladder indices sorted by closeness (in log scale) to the span wanted, shorter first on ties."""
    lw = np.log2(max(min(frac_wanted, WINDOW_LADDER[-1]), min(WINDOW_LADDER)))
    return sorted(range(len(WINDOW_LADDER)), key=lambda i: (abs(np.log2(WINDOW_LADDER[i]) - lw), WINDOW_LADDER[i]))


def _select(ev: EventStream, keep: np.ndarray) -> EventStream:
    return EventStream(ev.t[keep], ev.x[keep], ev.y[keep], ev.p[keep], ev.width, ev.height)


def _supported_events(ev: EventStream) -> int:
    """Events whose pixel has two active 8-neighbours in the same span: edges, not isolated noise (an image-level
    background-activity filter, cheap enough to run on every window)."""
    if len(ev) == 0:
        return 0
    pix = ev.y.astype(np.int64) * ev.width + ev.x.astype(np.int64)
    img = np.bincount(pix, minlength=ev.width * ev.height).reshape(ev.height, ev.width)
    active = (img > 0).astype(np.uint8)
    nb = cv2.boxFilter(active, cv2.CV_16U, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT) - active
    return int(np.sum(img[nb >= 2]))


def _in_roi(ev: EventStream, roi: tuple[int, int, int, int] | None) -> np.ndarray | slice:
    if roi is None:
        return slice(None)
    x0, y0, x1, y1 = roi
    return (ev.x >= x0) & (ev.x < x1) & (ev.y >= y0) & (ev.y < y1)


def _complete_by_homography(uv: np.ndarray, board: Board) -> np.ndarray:
    """``uv`` with the unseen points filled in by the homography of the seen ones (for predictions only)."""
    seen = np.all(np.isfinite(uv), axis=1)
    if seen.all() or np.count_nonzero(seen) < 4:
        return uv
    H, _ = cv2.findHomography(board.points[seen, :2], uv[seen], 0)
    if H is None:
        return uv
    ph = np.c_[board.points[:, :2], np.ones(board.n_points)] @ H.T
    out = uv.copy()
    out[~seen] = ph[~seen, :2] / ph[~seen, 2:]
    return out


def _roi_around(uv: np.ndarray, width: int, height: int) -> tuple[int, int, int, int] | None:
    """Search region for the next window: the detection's bounding box grown by half its size (the board
    moves less than that in one frame period at any speed the rim detector can follow)."""
    q = uv[np.all(np.isfinite(uv), axis=1)]
    if q.shape[0] < 2:
        return None
    lo, hi = q.min(axis=0), q.max(axis=0)
    pad = 0.5 * (hi - lo) + 10.0
    x0, y0 = np.floor(lo - pad).astype(int)
    x1, y1 = np.ceil(hi + pad).astype(int)
    return max(0, x0), max(0, y0), min(width, x1), min(height, y1)


def _event_time(events: EventStream, uv: np.ndarray, t_ref_ns: int, max_age_s: float) -> float | None:
    """Mean time (s) of the events that formed the detected rims: those young enough to show in the rim
    image and inside the detected points' bounding box grown by half the point spacing (all rims inside
    it belong to the pattern; the paper margin keeps the board's outer edge outside)."""
    q = uv[np.all(np.isfinite(uv), axis=1)]
    if q.shape[0] < 2:
        return None
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    r = 0.5 * float(np.median(d.min(axis=1)))
    (x0, y0), (x1, y1) = q.min(axis=0) - r, q.max(axis=0) + r
    i0 = int(np.searchsorted(events.t, t_ref_ns - int(max_age_s * 1e9), side="left"))
    x, y, t = events.x[i0:], events.y[i0:], events.t[i0:]
    sel = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    if not np.any(sel):
        return None
    return float(t_ref_ns * 1e-9 - np.mean((t_ref_ns - t[sel]).astype(np.float64)) * 1e-9)


class _WindowJob:
    """The per-window work (surface, detection, time stamp) over a range of windows."""

    def __init__(self, stream, camera, board, kind, params, window_s, min_events, timestamp, tag_layout, border_bits,
                 tag_blur, noise_mask=None, ba_dt_s=0.005, hold_still=True):
        self.stream, self.camera, self.board, self.kind, self.params = stream, camera, board, kind, params
        self.window_s, self.min_events, self.timestamp, self.tag_layout = window_s, min_events, timestamp, tag_layout
        self.border_bits, self.tag_blur = border_bits, float(tag_blur)
        self.noise_mask = noise_mask if noise_mask is not None and np.any(noise_mask) else None
        self.ba_dt_s, self.hold_still = ba_dt_s, bool(hold_still)
        self.state: dict | None = None
        self.period_s = 0.0

    def run(self, t_query: np.ndarray, i0s: np.ndarray, i1s: np.ndarray, progress=None):
        # OpenCV's internal threads cost more than they save on images this small (connected components:
        # 3x the CPU time with 2 threads); parallelism comes from ``workers`` instead.
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            return self._run(t_query, i0s, i1s, progress)
        finally:
            cv2.setNumThreads(threads)

    def _clean(self, ev: EventStream, roi=None, ba: bool = False) -> EventStream:
        """Events off hot / flickering pixels (and inside ``roi``), optionally background-activity filtered."""
        keep = None
        if self.noise_mask is not None:
            keep = ~self.noise_mask[ev.y, ev.x]
        if roi is not None:
            r = _in_roi(ev, roi)
            keep = r if keep is None else keep & r
        if keep is not None:
            ev = _select(ev, keep)
        if ba and self.ba_dt_s and len(ev):
            ev = _select(ev, noise.background_activity_filter(ev, self.ba_dt_s))
        return ev

    def _hold_backwards(self, t_query, t_out, uv_out, k_out, codes, skipped, age0) -> None:
        """Before the first detection of the recording: windows in which nothing moved around where the board
        was first found (walking back from it) show the board there too. A recording often starts standing still,
        and an event camera sees nothing of a still board."""
        k0 = k_out[0]
        uv0 = uv_out[0]
        roi = _roi_around(uv0, self.stream.width, self.stream.height)
        tq0 = int(t_query[k0])
        ref = len(self._clean(self.stream.slice_time(tq0 - int(age0 * 1e9), tq0 + 1), roi)) / max(age0, 1e-9)
        still_n = STILL_RATE_FRACTION * ref * age0
        ref_all = _supported_events(self._clean(self.stream.slice_time(tq0 - int(age0 * 1e9), tq0 + 1)))
        held = []
        for k in range(k0 - 1, -1, -1):
            if codes[k] == _CODE["too_few_events"] and self.stream.slice_time(
                    int(t_query[k]) - int(age0 * 1e9), int(t_query[k]) + 1).t.size == 0:
                break  # a gap in the stream: nothing is known about it
            near = self._clean(self.stream.slice_time(int(t_query[k]) - int(age0 * 1e9), int(t_query[k]) + 1), roi)
            whole = self._clean(self.stream.slice_time(int(t_query[k]) - int(age0 * 1e9), int(t_query[k]) + 1))
            if not (_supported_events(near) < still_n and _supported_events(whole) < STILL_RATE_FRACTION * ref_all):
                break
            held.append(k)
        if not held:
            return
        held = held[::-1]
        period = self.period_s
        t_new = [t_query[k] * 1e-9 - 0.5 * period for k in held]
        if t_new[-1] >= t_out[0]:
            held, t_new = held[:-1], t_new[:-1]
        for k in held:
            reason = OUTCOMES[codes[k]]
            if reason in skipped:
                skipped[reason] -= 1
                if skipped[reason] == 0:
                    del skipped[reason]
            codes[k] = _CODE["held_still"]
        t_out[:0] = t_new
        uv_out[:0] = [uv0] * len(held)
        k_out[:0] = held

    def _detect(self, img, kind, params, age, roi, predicted):
        board = self.board
        as_image = False
        det = None
        if kind == "leaky":
            # The leaky integrator approximates log intensity (circles dark) once the board has moved by more
            # than a circle within tau; try it as an image first. Such a detection shows the circles where
            # they are now: it is stamped with the query time.
            det = detect_circle_grid(img, board, self.camera, foreground="dark")
            as_image = det.reason == REASON_OK
        if det is None or det.reason != REASON_OK:
            rim, level = _rim_image(img, kind, params, age)
            det = None
            if roi is not None:
                # Look where the board was a moment ago first: fewer pixels and less clutter, and the circles
                # can be labelled by their predicted positions.
                det = detect_circle_grid(rim, board, self.camera, foreground="rims", rim_threshold=level, roi=roi,
                                         predicted_uv=predicted)
            if det is None or det.reason != REASON_OK:
                det = detect_circle_grid(rim, board, self.camera, foreground="rims", rim_threshold=level)
        return det, as_image

    def _run(self, t_query: np.ndarray, i0s: np.ndarray, i1s: np.ndarray, progress=None):
        stream, board, kind, params = self.stream, self.board, self.kind, self.params
        aruco = make_aruco_detector(self.border_bits) if board.pattern == "aprilgrid" else None
        circles = board.pattern == "asymmetric_circles"
        skipped: Counter[str] = Counter()
        retries: Counter[int] = Counter()
        secs = {"surfaces": 0.0, "detection": 0.0}
        t_out, uv_out, k_out = [], [], []
        codes = np.full(t_query.size, _CODE["too_few_events"], dtype=np.int8)
        n_events = 0
        # Tracking state, carried over from the previous span of a streamed recording: region of interest,
        # predicted circles, the last detection (query time, stamp, all circles), the last detection's labels
        # and the noise-filtered event rate (1/s) around the board when it was last found.
        st = dict(self.state or {})
        roi, predicted, prev = st.get("roi"), st.get("predicted"), st.get("prev")
        last_uv, ref_rate, last_good = st.get("last_uv"), st.get("ref_rate"), st.get("last_good", 0)
        lost = st.get("lost", 0)  # windows since the last detection
        ref_all = st.get("ref_all")  # the same as ref_rate over the whole image (supported events only)
        as_image = False
        period_s = self.period_s
        age0 = _active_age_s(kind, params, self.window_s)
        decaying = kind in ("time_surface", "leaky")
        for k, (tq, i0, i1) in enumerate(zip(t_query, i0s, i1s, strict=True)):
            if progress is not None:
                progress(k, t_query.size)
            if i1 - i0 < (1 if last_uv is not None else self.min_events):
                # Not even sensor noise: the stream has a gap here (a still camera keeps firing noise events; while
                # a board is followed, a quiet window may still be a still board and is judged below).
                skipped["too_few_events"] += 1
                roi = predicted = last_uv = None
                continue
            ev = stream.slice_index(int(i0), int(i1))
            n_events += int(i1 - i0)
            c0 = time.perf_counter()
            # Event rate around the board (or in the whole image) decides the span to start with.
            near = self._clean(ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1), roi)
            rate_now = len(near) / max(age0, 1e-9)
            secs["surfaces"] += time.perf_counter() - c0
            if circles:
                wanted = WINDOW_LADDER[last_good]
                if ref_rate is not None and rate_now > 0:
                    wanted = WINDOW_LADDER[last_good] * ref_rate / rate_now
                order = _span_order(wanted)
                if wanted <= 1.0:  # events enough for a period or less: long spans (costly to filter) cannot help
                    order = [j for j in order if WINDOW_LADDER[j] <= 1.0]
                order = order[:MAX_SPANS_PER_WINDOW]
            else:
                order = [0]
            still_n = STILL_RATE_FRACTION * (ref_rate or 0.0) * age0
            # Held only straight after a detection or a held window, and only if the whole image is quiet too: a
            # camera turning the board out of view leaves the board's region quiet when it shows a plain wall.
            if (self.hold_still and circles and last_uv is not None and ref_rate is not None and roi is not None
                    and prev is not None and abs(int(tq) - prev[0] - period_s * 1e9) < 0.5 * period_s * 1e9
                    and _supported_events(near) < still_n
                    and _supported_events(self._clean(ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1)))
                    < STILL_RATE_FRACTION * (ref_all or 0.0) * age0):
                # Nothing moves around the board: it is where it was last seen (an event camera sees no change
                # without motion). Held detections are marked in the window outcomes.
                codes[k] = _CODE["held_still"]
                t_det = tq * 1e-9 - 0.5 * period_s
                if t_out and t_det <= t_out[-1]:
                    codes[k] = _CODE["time_not_increasing"]
                    skipped["time_not_increasing"] += 1
                    continue
                t_out.append(t_det)
                k_out.append(k)
                uv_out.append(last_uv)
                prev = (int(tq), t_det, _complete_by_homography(last_uv, board))
                predicted = prev[2]
                continue
            img = None
            det = None
            for j in order:
                frac = WINDOW_LADDER[j]
                age = frac * age0
                c0 = time.perf_counter()
                if frac > 1.0:
                    if decaying:
                        continue  # a decaying surface's look-back is fixed by tau
                    # Slow motion: a longer look-back from the whole buffered stream, where background activity
                    # would otherwise fill the circles' insides (in the board's region when it is known; over the
                    # whole image only while the event rate is low enough to filter it cheaply).
                    sub = stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    if roi is None and len(sub) > MAX_LONG_SPAN_EVENTS:
                        continue
                    sub = self._clean(sub, roi, ba=True)
                    if len(sub) < self.min_events:
                        continue
                    img = surfaces.surface(sub, kind, int(tq), **params)
                    img_decays = False
                elif img is None or not decaying or img_decays is False:
                    # Non-decaying kinds: rebuild the surface from the most recent events only. Decaying kinds are
                    # built once; the rim level below selects the age. A time surface's rims only show pixels
                    # whose last event is younger than tau, so older events need not be read at all (the leaky
                    # integrator sums over its whole look-back and keeps it).
                    if kind == "time_surface" and circles:
                        sub = ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1)
                    elif frac == 1.0 or decaying:
                        sub = ev
                    else:
                        sub = ev.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    sub = self._clean(sub)
                    if len(sub) < self.min_events:
                        continue  # too short a span to show the board; try the others
                    img = surfaces.surface(sub, kind, int(tq), **params)
                    img_decays = decaying
                c1 = time.perf_counter()
                if board.pattern == "aprilgrid":
                    # A light blur joins the speckled event edges into the solid tag borders aruco looks for.
                    tag_img = cv2.GaussianBlur(img, (0, 0), self.tag_blur) if self.tag_blur > 0 else img
                    det = detect_aprilgrid(
                        surfaces.to_uint8(tag_img), board, self.camera, detector=aruco, layout=self.tag_layout
                    )
                    as_image = kind == "leaky"  # tags are only read off intensity-like images
                else:
                    det, as_image = self._detect(img, kind, params, age, roi, predicted)
                secs["surfaces"] += c1 - c0
                secs["detection"] += time.perf_counter() - c1
                if det.reason == REASON_OK:
                    retries[j] += 1
                    last_good = j
                    break
            if det is None or det.reason != REASON_OK:
                reason = "too_few_events" if det is None else det.reason
                skipped[reason] += 1
                codes[k] = _CODE.get(reason, _CODE["grid_not_found"])
                # Keep looking where the board was for a while (slow boards are lost for a window or two, when
                # their rims are too thin); then search the whole image again.
                lost += 1
                if lost > KEEP_ROI_WINDOWS:
                    roi = predicted = None
                continue
            t_det = None
            age = WINDOW_LADDER[last_good] * age0
            if self.timestamp == "query" or (as_image and self.timestamp == "events"):
                t_det = tq * 1e-9
            elif self.timestamp == "events":
                src = ev if WINDOW_LADDER[last_good] <= 1.0 else self._clean(
                    stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1), roi, ba=True)
                t_det = _event_time(src, det.uv, int(tq), age)
            if t_det is None:  # "window_centre", or no event near the detection (cannot happen for rims)
                t_det = tq * 1e-9 - 0.5 * age
            codes[k] = _CODE["detected"]
            lost = 0
            # Constant-velocity prediction of all circles for the next window (from the last two windows;
            # circles not seen are filled in by the board's homography).
            full = _complete_by_homography(det.uv, board) if circles else det.uv
            if prev is not None and abs(int(tq) - prev[0] - period_s * 1e9) < 0.5 * period_s * 1e9 and t_det > prev[1]:
                predicted = full + (full - prev[2]) * (period_s / (t_det - prev[1]))
                ok = np.all(np.isfinite(full), axis=1)
                if ok.sum() >= 2:
                    step = np.nanmax(np.linalg.norm(predicted - full, axis=1))
                    d = np.linalg.norm(full[ok][:, None] - full[ok][None], axis=-1)
                    np.fill_diagonal(d, np.inf)
                    if step > MAX_PREDICTED_STEP * float(np.median(d.min(axis=1))):
                        # A jump of most of a spacing per window: the circles' labels could not be told from their
                        # predicted positions; the next window is searched without them.
                        predicted = None
            else:
                predicted = full
            prev = (int(tq), t_det, full)
            t_out.append(t_det)
            k_out.append(k)
            uv_out.append(det.uv)
            last_uv = det.uv
            roi = _roi_around(det.uv, stream.width, stream.height)
            n_roi = len(self._clean(ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1), roi))
            ref_rate = n_roi / max(age0, 1e-9)
            ref_all = _supported_events(self._clean(ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1))) / max(
                age0, 1e-9)
        if self.hold_still and circles and k_out and not st.get("seen_before"):
            self._hold_backwards(t_query, t_out, uv_out, k_out, codes, skipped, age0)
        self.state = {"roi": roi, "predicted": predicted, "prev": prev, "last_uv": last_uv, "ref_rate": ref_rate,
                      "seen_before": bool(k_out) or bool(st.get("seen_before")),
                      "last_good": last_good, "lost": lost, "ref_all": ref_all}
        return t_out, uv_out, k_out, skipped, secs, n_events, retries, codes


# The job of the current parallel run; forked workers inherit it instead of receiving a pickled copy.
_JOB: tuple | None = None


def _run_chunk(bounds: tuple[int, int]):
    job, t_query, i0s, i1s = _JOB
    a, b = bounds
    return job.run(t_query[a:b], i0s[a:b], i1s[a:b])


def _run_parallel(job: _WindowJob, t_query, i0s, i1s, workers: int, progress) -> list:
    """Contiguous chunks of windows on ``workers`` forked processes (the stream is shared, not copied)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    global _JOB
    _JOB = (job, t_query, i0s, i1s)
    edges = np.linspace(0, t_query.size, workers + 1).round().astype(int)  # one run per worker: tracking state
    chunks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]
    try:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            parts = []
            for j, part in enumerate(pool.map(_run_chunk, chunks)):
                parts.append(part)
                if progress is not None:
                    progress(chunks[j][1], t_query.size)
            return parts
    finally:
        _JOB = None


def _window_of(kind: str, surface_params: dict | None, window_s: float | None, rate_hz: float) -> tuple[dict, float]:
    """Surface parameters and the look-back of every window (s) for a resolved surface ``kind``."""
    params = {**DEFAULT_PARAMS[kind], **(surface_params or {})}
    if window_s is None:
        # Decaying surfaces look back 5 tau (exp(-5) is negligible); the others one frame period.
        tau = params.get("tau_s")
        window_s = surfaces.DECAY_LOOKBACK * tau if kind in ("time_surface", "leaky") and tau else 1.0 / rate_hz
    return params, window_s


def detect_in_events(
    stream: EventStream,
    camera: CameraModel,
    board: Board,
    rate_hz: float = 30.0,
    kind: str = "polarity",
    *,
    window_s: float | None = None,
    surface_params: dict | None = None,
    min_events: int = 100,
    timestamp: str = "events",
    tag_layout: str = "kalibr",
    tag_border_bits: int = 2,
    tag_blur_sigma: float = 1.0,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    t_query_ns: np.ndarray | None = None,
    require_detection: bool = True,
    denoise: bool = True,
    noise_model: noise.NoiseModel | None = None,
    hold_still: bool = True,
    tracking_state: dict | None = None,
) -> tuple[Detections, dict]:
    """Board detections in event surfaces at ``rate_hz``; see :func:`camera_track_from_events`.

    ``t_query_ns`` replaces the window grid (every 1 / rate_hz from the first event) by given window end
    times, as the streaming front end does per span. With ``require_detection`` False a stream without any
    detection gives empty detections instead of an error.
    Returns the detections (board-point order, NaN for unseen points) and the bookkeeping dict.
    """
    kind = resolve_kind(kind)
    if timestamp not in TIMESTAMPS:
        raise InputError(f"front end: timestamp must be one of {', '.join(TIMESTAMPS)}, got {timestamp!r}")
    if not rate_hz > 0:
        raise InputError(f"front end: rate_hz must be positive, got {rate_hz}")
    if (stream.width, stream.height) != (camera.width, camera.height):
        raise InputError(
            f"front end: events are {stream.width} x {stream.height} but the camera model is "
            f"{camera.width} x {camera.height}; use the intrinsics of this sensor"
        )
    params, window_s = _window_of(kind, surface_params, window_s, rate_hz)
    if not window_s > 0:
        raise InputError(f"front end: window_s must be positive, got {window_s}")
    period_ns = int(round(1e9 / rate_hz))
    window_ns = int(round(window_s * 1e9))
    n = board.n_points
    if len(stream) == 0:
        raise InsufficientDataError("front end: the event stream is empty; check the recording's event topic")
    if t_query_ns is None:
        t_query = np.arange(stream.t_first + period_ns, stream.t_last + period_ns, period_ns, dtype=np.int64)
    else:
        t_query = np.asarray(t_query_ns, dtype=np.int64)
    i1s = np.searchsorted(stream.t, t_query, side="right")
    i0s = np.searchsorted(stream.t, t_query - window_ns, side="right")
    mask = None
    if denoise:
        mask = (noise_model if noise_model is not None else noise.NoiseModel.from_stream(stream)).mask
    job = _WindowJob(
        stream, camera, board, kind, params, window_s, min_events, timestamp, tag_layout, tag_border_bits,
        tag_blur_sigma, noise_mask=mask, ba_dt_s=0.005 if denoise else 0.0, hold_still=hold_still,
    )
    job.period_s = period_ns * 1e-9
    job.state = tracking_state
    workers = max(1, min(int(workers), t_query.size))
    if workers == 1:
        parts = [job.run(t_query, i0s, i1s, progress)]
    else:
        parts = _run_parallel(job, t_query, i0s, i1s, workers, progress)
    skipped: Counter[str] = Counter()
    secs = {"surfaces": 0.0, "detection": 0.0}
    t_out, uv_out = [], []
    n_events = 0
    last_t = -np.inf
    ladder: Counter[int] = Counter()
    codes = []
    for p_t, p_uv, p_k, p_skipped, p_secs, p_n, p_ladder, p_codes in parts:
        skipped.update(p_skipped)
        ladder.update(p_ladder)
        n_events += p_n
        for key in secs:
            secs[key] += p_secs[key]
        for t_det, uv, kk in zip(p_t, p_uv, p_k, strict=True):
            if t_det <= last_t:
                skipped["time_not_increasing"] += 1
                p_codes[kk] = _CODE["time_not_increasing"]
                continue
            last_t = t_det
            t_out.append(t_det)
            uv_out.append(uv)
        codes.append(p_codes)
    codes_all = np.concatenate(codes) if codes else np.zeros(0, np.int8)
    if progress is not None:
        progress(t_query.size, t_query.size)
    info = {
        "kind": kind,
        "surface_params": params,
        "rate_hz": float(rate_hz),
        "window_s": float(window_s),
        "timestamp": timestamp,
        "board": board.name or board.pattern,
        "windows": int(t_query.size),
        "detected": len(t_out),
        "held_still": int(np.count_nonzero(codes_all == _CODE["held_still"])),
        "skipped": dict(skipped),
        # Per window: query time (s, the stream's clock) and outcome (index into OUTCOMES), for coverage plots.
        "window_outcomes": {"t": t_query * 1e-9, "code": codes_all, "names": OUTCOMES},
        "tracking_state": job.state if workers == 1 else None,
        "events_used": n_events,
        "detected_at_window_fraction": {str(WINDOW_LADDER[j]): int(c) for j, c in sorted(ladder.items())},
        "seconds": secs,
        "warnings": [],
    }
    if board.pattern == "asymmetric_circles" and board_is_symmetric(board):
        info["warnings"].append(
            f"board {board.name!r} looks the same turned by 180 degrees (even number of rows): its detections "
            "cannot be labelled uniquely and are rejected as ambiguous; use a board with an odd number of rows"
        )
    if not t_out and require_detection:
        raise InsufficientDataError(
            f"front end: no board detected in any of {t_query.size} windows ({dict(skipped)}); check that the "
            f"board definition ({board.cols} x {board.rows} {board.pattern}) matches the target, that it is in "
            "view and moving, and try another surface kind"
        )
    dets = Detections(np.asarray(t_out), np.asarray(uv_out).reshape(-1, n, 2), board.points)
    return dets, info


def camera_track_from_events(
    stream: EventStream,
    camera: CameraModel,
    board: Board,
    rate_hz: float = 30.0,
    kind: str = "polarity",
    *,
    window_s: float | None = None,
    surface_params: dict | None = None,
    min_events: int = 100,
    timestamp: str = "events",
    max_rms_px: float = 1.5,
    sigma_px: float | None = None,
    tag_layout: str = "kalibr",
    tag_border_bits: int = 2,
    tag_blur_sigma: float = 1.0,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> CameraTrack:
    """Camera track T_board_cam(t) from an event stream: surfaces at ``rate_hz`` -> detection -> PnP.

    ``kind``: a :mod:`plsgraph.frontend.surfaces` kind (``count``, ``polarity_sum``, ``time_surface``,
    ``polarity_aware``, ``leaky``) or an alias (``polarity``, ``classic``/``ts``). ``window_s``: the
    events' look-back per window (default one frame period, or 5 tau for decaying kinds);
    ``surface_params`` override :data:`DEFAULT_PARAMS`. Windows with fewer than ``min_events``
    events are skipped. ``timestamp``: how detections are stamped (module docstring). PnP frames
    with reprojection RMS above ``max_rms_px`` are dropped; ``sigma_px`` fixes the pixel noise of the
    covariance (default: estimated per frame). AprilGrids: ``tag_layout`` / ``tag_border_bits`` as
    in :func:`plsgraph.frontend.detect.detect_aprilgrid`, the image blurred by ``tag_blur_sigma`` px first.
    ``workers`` > 1 processes the windows in that many forked processes (Linux). Each chunk of
    windows starts its search afresh (no region of interest, full span first), so an occasional
    window may be found from another span than in one process. ``progress(done, total)`` is called
    per window.

    Raises :class:`InsufficientDataError` when no window yields a detection or no detection a pose.
    """
    dets, info = detect_in_events(
        stream,
        camera,
        board,
        rate_hz,
        kind,
        window_s=window_s,
        surface_params=surface_params,
        min_events=min_events,
        timestamp=timestamp,
        tag_layout=tag_layout,
        tag_border_bits=tag_border_bits,
        tag_blur_sigma=tag_blur_sigma,
        workers=workers,
        progress=progress,
    )
    return _track_from_detections(dets, info, camera, max_rms_px, sigma_px)


def _track_from_detections(
    dets: Detections, info: dict, camera: CameraModel, max_rms_px: float, sigma_px: float | None
) -> CameraTrack:
    """PnP on the detections and the front end's bookkeeping merged into the track's info."""
    info.pop("tracking_state", None)
    c0 = time.perf_counter()
    track = camera_track_from_detections(dets, camera, max_rms_px=max_rms_px, sigma_px=sigma_px)
    info["seconds"]["pnp"] = time.perf_counter() - c0
    skipped = Counter(info["skipped"])
    skipped.update(track.info.get("rejected", {}))
    info["skipped"] = dict(skipped)
    info["poses"] = len(track)
    info["median_rms_px"] = track.info.get("median_rms_px")
    for w in info["warnings"]:
        log.warning(w)
    log.info(
        "front end (%s): %d windows, %d detections, %d poses; skipped %s",
        info["kind"], info["windows"], info["detected"], info["poses"], info["skipped"],
    )
    return CameraTrack(track.t, track.T_board_cam, track.cov, track.rms_px, track.detections, info)


def later_than_all_before(t: np.ndarray) -> np.ndarray:
    """Mask of the stamps later than every stamp before them: what a time-ordered track may keep when detections
    of one span can be stamped before those of the previous one."""
    t = np.asarray(t)
    return np.r_[True, t[1:] > np.maximum.accumulate(t)[:-1]] if t.size else np.zeros(0, dtype=bool)


def camera_track_from_event_chunks(
    chunks: Iterable[EventStream],
    camera: CameraModel,
    board: Board,
    rate_hz: float = 30.0,
    kind: str = "count",
    *,
    span_s: float = 5.0,
    history_s: float = 1.0,
    max_rms_px: float = 1.5,
    sigma_px: float | None = None,
    expected_span_ns: tuple[int, int] | None = None,
    progress: Callable[[int, int], None] | None = None,
    **detect_options,
) -> CameraTrack:
    """The front end of :func:`camera_track_from_events` on a stream of event chunks, in bounded memory.

    Windows lie on the same grid as in one pass (every 1 / ``rate_hz`` from the first event). Events are
    buffered until they span ``span_s``; the windows ending inside the buffer are detected, then all but the
    last ``history_s`` (longer than any window's look-back) is dropped. Memory therefore follows the span,
    not the recording's length. Tracking goes on across spans (its state is handed over); hot and flickering
    pixels are judged on all events seen so far (:class:`plsgraph.frontend.noise.NoiseModel`, updated per span).
    ``expected_span_ns`` (first, last event time, e.g. from the file's summary) only sizes the progress bar.
    """
    if not (span_s > 0 and history_s > 0 and rate_hz > 0):
        raise InputError("streaming front end: span_s, history_s and rate_hz must be positive")
    period = int(round(1e9 / rate_hz))
    _, window_s = _window_of(resolve_kind(kind), detect_options.get("surface_params"), detect_options.get("window_s"),
                             rate_hz)
    span_ns = int(span_s * 1e9)
    keep_ns = max(int(history_s * 1e9), int(window_s * 1e9) + period)  # every window's look-back stays buffered
    reorder_ns = 100_000_000  # packets arrive up to this much out of order: their windows wait that long
    buf: EventStream | None = None
    # Hot and flickering pixels are judged on all the events seen so far (updated once per span).
    noise_model: noise.NoiseModel | None = None
    denoise = detect_options.get("denoise", True)
    outcome_t: list[np.ndarray] = []
    outcome_code: list[np.ndarray] = []
    new_from = None  # first event time not yet added to the noise model
    state = None  # the tracker's state at the end of the previous span
    next_q: int | None = None
    t_parts: list[np.ndarray] = []
    uv_parts: list[np.ndarray] = []
    info: dict = {}
    skipped: Counter[str] = Counter()
    late_events = 0
    total = None
    if expected_span_ns is not None:
        total = max(1, int((expected_span_ns[1] - expected_span_ns[0]) // period))

    def detect(t_end: int) -> None:
        nonlocal buf, next_q, info, noise_model, new_from, state
        q = np.arange(next_q, t_end, period, dtype=np.int64)
        if q.size:
            if denoise:
                if noise_model is None:
                    noise_model = noise.NoiseModel(buf.width, buf.height)
                fresh = buf.slice_time(buf.t_first if new_from is None else new_from, t_end)
                if len(fresh):
                    noise_model.update(fresh)
                    new_from = int(fresh.t_last) + 1
            dets, part = detect_in_events(buf, camera, board, rate_hz, kind, t_query_ns=q, require_detection=False,
                                          noise_model=noise_model, tracking_state=state, **detect_options)
            state = part.pop("tracking_state")
            wo = part.pop("window_outcomes")
            outcome_t.append(wo["t"])
            outcome_code.append(wo["code"])
            t_parts.append(dets.t)
            uv_parts.append(dets.uv)
            skipped.update(part["skipped"])
            if info:
                info["windows"] += part["windows"]
                info["events_used"] += part["events_used"]
                info["held_still"] += part["held_still"]
                for k, v in part["seconds"].items():
                    info["seconds"][k] = info["seconds"].get(k, 0.0) + v
            else:
                info = part
            next_q = int(q[-1]) + period
            if progress is not None:
                done = info["windows"]
                progress(done, max(done, total or done))
        buf = buf.slice_time(next_q - keep_ns, np.iinfo(np.int64).max)

    for ch in chunks:
        if len(ch) == 0:
            continue
        if next_q is not None and ch.t_first < next_q - period:
            late_events += int(np.count_nonzero(ch.t < next_q - period))  # their windows are already done
        if buf is None:
            buf = ch
        elif ch.t_first >= buf.t_last:
            buf = EventStream.concatenate([buf, ch])
        else:  # packets that overlap in time: merge, so every window sees its events in order
            joined = EventStream(*(np.concatenate([getattr(buf, a), getattr(ch, a)]) for a in "txyp"),
                                 buf.width, buf.height)
            buf = joined.sorted()
        if next_q is None:
            next_q = buf.t_first + period
        if buf.t_last - reorder_ns - next_q >= span_ns:
            detect(buf.t_last - reorder_ns)  # windows well before the newest event have all their events
    if buf is None or len(buf) == 0:
        raise InsufficientDataError("front end: the event stream is empty; check the recording's event topic")
    detect(buf.t_last + period)
    t = np.concatenate(t_parts) if t_parts else np.zeros(0)
    uv = np.concatenate(uv_parts) if uv_parts else np.zeros((0, board.n_points, 2))
    if t.size > 1:  # a detection stamped before its predecessor (across spans) would break the time order
        keep = later_than_all_before(t)
        if not keep.all():
            skipped["time_not_increasing"] += int(np.count_nonzero(~keep))
        t, uv = t[keep], uv[keep]
    info["skipped"] = dict(skipped)
    info["detected"] = int(t.size)
    info["window_outcomes"] = {"t": np.concatenate(outcome_t) if outcome_t else np.zeros(0),
                               "code": np.concatenate(outcome_code) if outcome_code else np.zeros(0, np.int8),
                               "names": OUTCOMES}
    info["streamed_span_s"] = span_s
    info["late_events"] = late_events  # arrived after their windows were detected (out-of-order packets)
    if t.size == 0:
        raise InsufficientDataError(
            f"front end: no board detected in any of {info.get('windows', 0)} windows ({dict(skipped)}); check that "
            f"the board definition ({board.cols} x {board.rows} {board.pattern}) matches the target, that it is in "
            "view and moving, and try another surface kind"
        )
    if progress is not None:
        progress(info["windows"], info["windows"])
    return _track_from_detections(Detections(t, uv, board.points), info, camera, max_rms_px, sigma_px)
