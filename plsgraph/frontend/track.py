"""The event front end: event surfaces at a fixed rate -> board detection -> PnP -> camera track.

For each window the events just before the query time t_k are turned into an image
(:mod:`plsgraph.frontend.surfaces`), the board is detected in it (:mod:`plsgraph.frontend.detect`) and the pose is
solved by PnP (:mod:`plsgraph.frontend.pose`). What is counted in ``track.info``:

* ``windows``: windows tried; ``detected``: windows with a verified board detection;
  ``poses``: windows that produced a pose;
* ``skipped``: reason -> count over all windows that gave no pose: ``too_few_events`` (nothing
  moved), the detector's reasons (``grid_not_found``, ``inconsistent_order``, ``mirrored_order``,
  ``ambiguous_labels``, ``too_few_points``, ``empty_image``), ``same_stamp`` (a second detection with
  one stamp), ``not_searched_while_lost`` (a window passed over while the board was lost, see
  ``LOST_SEARCH_STRIDE``) and PnP's (``pnp_failed``, ``rms_above_threshold``);
* ``detected_at_window_fraction``, ``seconds`` (surfaces, detection, PnP), ``warnings``;
* ``hot_pixels`` (masked), ``flicker_hz``, ``flicker_pixels``, ``flicker_event_share`` (recognised, not removed;
  the largest over the streamed spans).

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
from ..core.tracks import PER_FRAME_INFO, CameraTrack, Detections
from ..errors import InputError, InsufficientDataError
from . import surfaces
from .consistency import REASON_INCONSISTENT, inconsistent_frames
from .detect import (
    MIN_RIM_SPACING_PX,
    REASON_NOT_FOUND,
    REASON_OK,
    GridDetection,
    board_is_symmetric,
    check_grid_order,
    detect_aprilgrid,
    detect_circle_grid,
    make_aruco_detector,
    neighbour_distance,
    refine_centroids,
)
from .noise import drop_events, drop_pixels, flicker_census, flicker_events, hot_pixel_mask
from .pose import camera_track_from_detections, frame_pose

log = logging.getLogger(__name__)

#: Window outcome of a board found on a long span while lost that the half-span-earlier check refused.
REASON_MOVED = "moved_within_span"


def _refused(det: GridDetection) -> GridDetection:
    return GridDetection(np.full_like(det.uv, np.nan), False, REASON_MOVED, det.homography_rms_px)

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


#: Fractions of the nominal rim age tried in turn: fast motion smears a circle's rim over its whole
#: inside within a full window, so failed windows are retried on the most recent half, quarter and eighth;
#: slow motion leaves sparse rims, retried on 2, 4, 8 and 16 windows (up to about half a second at 30 Hz: a
#: board crossing the image at a few pixels per second moves by a pixel or two in that time).
WINDOW_LADDER = (1.0, 0.5, 0.25, 0.125, 2.0, 4.0, 8.0, 16.0)
#: The spans longer than the window are for slow motion, whose rims are thin and sparse in one window: tried
#: while the board was last seen moving slower than this across the image, and while it is lost (see
#: LONG_WHEN_LOST). (Tried on a board seen moving fast they smear rims into patterns a wrong board definition
#: could be matched to.)
SLOW_PX_S = 30.0
#: While the board is lost (no detection in the last RECENT_WINDOWS windows) the longer spans are tried in every
#: LOST_STRIDE-th window: a robot setting off slowly after a stop shows the board only on them.
LONG_WHEN_LOST = True
LOST_STRIDE = 1
#: Blob spans up to this multiple are tried in every window, the longer ones as the longer rim spans are.
SHORT_BLOB_SPAN = 4.0
#: After a window without the board, the next windows still search where it was last seen first (for
#: RECENT_WINDOWS windows): a slow board is still there, and the whole image holds more clutter.
KEEP_ROI = True
#: With a region to search (KEEP_ROI), a rim search that fails there is not repeated on the whole image (True: it is,
#: at every span of the ladder). On the ten cached recordings of the study's first seed those whole-image repeats
#: found no board in any of 4,773 windows with a region and took a tenth of the detector's time (9 of 91 s); a board
#: that left the region is still looked for in the whole image by the blob and ring search of the same window, and
#: by every search once the region is dropped (RECENT_WINDOWS after the last find).
RIMS_OUTSIDE_ROI = False
#: Try the rim thickness of the last find first (False: always :data:`~plsgraph.frontend.detect.RIM_THICKNESSES`'
#: order). On the 20 s benchmark recording the thinnest rims found 431 of 554 boards found on rims, after two
#: failed thicker ones.
RIM_MEMORY = True
#: How a find on a long span while lost is checked (see _WindowJob._holds_still): "recentre" or "detect".
STILL_CHECK = "recentre"
#: Hot pixels (:mod:`.noise`) are masked in each span before detection unless a caller says otherwise.
MASK_HOT_PIXELS = True
#: Drop the events of pixels flickering with the lights, within FLICKER_GATE_RAD of their locked phase (noise.py).
SUPPRESS_FLICKER = False
#: Spans (multiples of the window) over which circles are looked for as blobs of events when the rims fail, and
#: the blur that merges a small circle's events into one blob.
BLOB_SPANS = (1.0, 2.0, 4.0, 8.0, 16.0)
BLOB_BLUR_PX = 0.8
#: Blob centres as the mean of the ON and the OFF events' centroids (detect.polarity_centroids), each polarity
#: weighed equally, instead of the centroid of all events: a moving circle's two polarities lie on its two edges, and
#: how many more one fires than the other varies from circle to circle. On the independent recordings' blob
#: detections the centres' error (less their common shift) fell from 0.13-0.15 to 0.05-0.07 px rms on one-window
#: spans and from 0.22-0.33 to 0.11-0.22 px on eight-window spans (docs/frontend.md, "Blob centres by polarity").
BLOB_POLARITY_CENTRES = True
#: Rim detections (count surfaces) re-centred by polarity: each circle's ON and OFF events' centroids, each iterated
#: from the rim's hole centre in its own disk of RIM_POLARITY_DISK x the circle's radius in pixels, and their mean;
#: kept when the re-centred board passes the order check. The radius in pixels is the distance to the nearest circle
#: times the board's ratio of circle radius to neighbour distance (0.28 on acircles_4x11_a2, 0.42 on acircles_4x11):
#: a disk a little larger than the circle holds its rim's events and none of its neighbours'. A disk of a fixed share
#: of the neighbour distance does not: on a board with large circles it lies inside the empty hole. A hole's centre
#: is a binary region's: 0.4-0.5 px noisy on the independent recordings (less each frame's common shift), against
#: 0.16-0.25 px for the polarities' mean (docs/frontend.md, "Rim centres by polarity").
RIM_POLARITY_CENTRES = True
RIM_POLARITY_DISK = 1.1
RIM_POLARITY_BLUR_PX = 0.7
RIM_CENTROID_ITERATIONS = 4


def _circle_radius_share(board: Board) -> float:
    """The circles' radius over the distance between neighbouring circles (the diagonal neighbours, sqrt(2) square
    sizes apart) of an asymmetric circle grid."""
    return 0.5 * board.circle_diameter / (np.sqrt(2.0) * board.square_size)


def _rim_centres_by_polarity(det: GridDetection, events: EventStream, board: Board,
                             camera: CameraModel) -> GridDetection:
    """``det`` (a rim detection) with its centres re-centred on ``events`` (the rim window's) by polarity (see
    RIM_POLARITY_CENTRES); ``det`` itself when too few circles are seen, an image lacks one polarity, or the
    re-centred board fails the order check. A circle whose disk holds no events of one polarity keeps its hole
    centre."""
    seen = np.all(np.isfinite(det.uv), axis=1)
    if np.count_nonzero(seen) < 4 or len(events) == 0:
        return det
    from .detect import _polarity_mean

    q = det.uv[seen]
    r = RIM_POLARITY_DISK * _circle_radius_share(board) * neighbour_distance(q)
    # The ON and OFF count images over the board's box only: each of the centroids' iterations moves a disk by less
    # than its radius, and the blur reaches 4 sigma, so the box grown by that much holds every pixel read.
    grow = (RIM_CENTROID_ITERATIONS + 1) * float(np.max(r)) + 4.0 * RIM_POLARITY_BLUR_PX + 2.0
    x0, y0 = np.maximum(np.floor(q.min(axis=0) - grow).astype(int), 0)
    x1 = min(int(np.ceil(q[:, 0].max() + grow)) + 1, events.width)
    y1 = min(int(np.ceil(q[:, 1].max() + grow)) + 1, events.height)
    if x1 <= x0 or y1 <= y0:
        return det
    x, y = events.x, events.y
    inside = np.flatnonzero((x >= x0) & (x < x1) & (y >= y0) & (y < y1))
    pix = (y[inside].astype(np.intp) - y0) * (x1 - x0) + (x[inside].astype(np.intp) - x0)
    is_on = events.p[inside] > 0
    n_pix = (y1 - y0) * (x1 - x0)
    on, off = (cv2.GaussianBlur(np.bincount(pix[sel], minlength=n_pix).astype(np.float32).reshape(y1 - y0, x1 - x0),
                                (0, 0), RIM_POLARITY_BLUR_PX) for sel in (is_on, ~is_on))
    corner = np.array([x0, y0], dtype=float)
    c, lone = _polarity_mean(on, off, q - corner, r, support=True, iterations=RIM_CENTROID_ITERATIONS)
    c += corner
    c[lone] = q[lone]
    uv = det.uv.copy()
    uv[seen] = c
    reason, rms = check_grid_order(uv, board, camera)
    if reason != REASON_OK:
        return det
    return GridDetection(uv, True, REASON_OK, rms, det.rim_px)
#: Blob spans of RING_MIN_SPAN windows or more also look for the circles as rings (detect.ring_peaks), in the
#: whole image, when the blob detector's blobs do not give the board (slow, distant boards).
RING_PEAKS = True
RING_MIN_SPAN = 4.0
#: A detection this many windows back still says how large the circles are.
RECENT_WINDOWS = 15
#: Count images of spans longer than the window in which more than DENSE_ACTIVE of the pixels fired (a textured
#: scene under flickering light, background activity, half a second of events) bury the rims: with "any event" as
#: the rim level the circles' insides fill with events. A span whose rims were not found on such an image is tried
#: again on its local excess (:func:`_excess_image`): pixels with significantly more events than their surroundings.
DENSE_RETRY = True
DENSE_ACTIVE = 0.25
EXCESS_BOX_PX = 9
EXCESS_Z = 2.0


def _excess_image(counts: np.ndarray) -> np.ndarray:
    """Events per pixel above what its surroundings explain: count - (m + EXCESS_Z sqrt(m)), m the mean count in
    the EXCESS_BOX_PX box around it (for events that fall evenly over an area, sqrt(m) is their count's spread).
    A rim is a thin curve of many events, so it stands out above its box's mean; a pixel of an evenly busy area does
    not. Rims are the pixels above 0."""
    c = np.asarray(counts, dtype=np.float32)
    m = cv2.blur(c, (EXCESS_BOX_PX, EXCESS_BOX_PX), borderType=cv2.BORDER_REFLECT)
    return c - (m + EXCESS_Z * np.sqrt(m))


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


#: A detection whose circles lie this many spacings (median) from the previous window's board carried forward
#: is refused: no board accelerates that much in one frame period, a labelling shifted by a lattice step does.
JUMP_SPACINGS = 0.5
REASON_JUMP = "jumped_from_track"
#: The board's velocity for the prediction comes from the last two detections when they are at most this many
#: windows apart. Not only adjacent ones: the first find after a loss has no velocity, so its successor on a fast
#: board is refused as a jump, and were the velocity only taken from adjacent windows every other window would be
#: refused from then on (study run 17: 51 windows).
VELOCITY_WINDOWS = 3
#: For PREDICT_THROUGH_MISSES windows after a find (the first is the ordinary next-window prediction, so up to
#: PREDICT_THROUGH_MISSES - 1 windows without the board) circles are still labelled by the last find's positions carried
#: forward at its speed (a slow board's next find is then a tracked one, which needs fewer circles than the full
#: lattice labelling); 0 or 1: the prediction ends at the first miss. Such a carried prediction never refuses a find
#: as a jump, and a window without events or a refused jump ends it.
PREDICT_THROUGH_MISSES = 5
#: The blob detector's blobs are labelled by the predicted board too (before the lattice labelling).
BLOB_TRACKING = True
#: While the board is lost (circle grids), every window is searched for the first LOST_DENSE_WINDOWS windows after
#: the last find (or the start), then only every LOST_SEARCH_STRIDE-th: a lost window's full search (every span of
#: the ladder, rims and blobs, whole image) costs 15-60 times a tracked window's, and while the robot looks away
#: there is nothing to find. When the board is found again, the windows passed over just before are searched
#: backwards from the find (:meth:`_WindowJob._backfill`: around the board, labelled by its circles), so a board that
#: came back into view is found from the window it did. The outcome of a window passed over and not filled in is
#: :data:`REASON_NOT_SEARCHED`. 1: every window is searched.
LOST_DENSE_WINDOWS = 8
LOST_SEARCH_STRIDE = 3
REASON_NOT_SEARCHED = "not_searched_while_lost"


def _jumped(uv: np.ndarray, predicted: np.ndarray) -> bool:
    both = np.all(np.isfinite(uv), axis=1) & np.all(np.isfinite(predicted), axis=1)
    if np.count_nonzero(both) < 6:
        return False
    spacing = float(np.median(neighbour_distance(predicted[np.all(np.isfinite(predicted), axis=1)])))
    return float(np.median(np.linalg.norm(uv[both] - predicted[both], axis=1))) > JUMP_SPACINGS * spacing


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
                 tag_blur):
        self.stream, self.camera, self.board, self.kind, self.params = stream, camera, board, kind, params
        self.window_s, self.min_events, self.timestamp, self.tag_layout = window_s, min_events, timestamp, tag_layout
        self.border_bits, self.tag_blur = border_bits, float(tag_blur)

    def _holds_still(self, det: GridDetection, tq: int, age: float, how: str) -> bool:
        """Whether a board found on a span longer than the window while it was lost is a slow board: on the same
        span length ending half a span earlier, the circles' events are centred where it was found (each found
        centre re-centred on that span's events moves by less than a third of a spacing, and the re-centred points
        pass the order check). A fast board smears its circles over such a span into patterns a wrong board
        definition can fit, and the earlier span has its events somewhere else. (Detecting the board afresh on the
        earlier span refused most slow boards: a slow board's detection is marginal on any one span.)"""
        if STILL_CHECK == "detect":
            return self._found_again(det, tq, age, how)
        t_end = int(tq) - int(0.5 * age * 1e9)
        sub = self.stream.slice_time(t_end - int(age * 1e9), t_end + 1)
        if len(sub) < self.min_events:
            return False
        seen = np.all(np.isfinite(det.uv), axis=1)
        if np.count_nonzero(seen) < 4:
            return False
        q = det.uv[seen]
        spacing = neighbour_distance(q)
        weight = cv2.GaussianBlur(surfaces.count_image(sub), (0, 0), BLOB_BLUR_PX)
        moved = refine_centroids(weight, q, 0.5 * spacing)
        if float(np.median(np.linalg.norm(moved - q, axis=1))) >= float(np.median(spacing)) / 3.0:
            return False
        uv = np.full_like(det.uv, np.nan)
        uv[seen] = moved
        return check_grid_order(uv, self.board, self.camera)[0] == REASON_OK

    def _found_again(self, det: GridDetection, tq: int, age: float, how: str) -> bool:
        """The stricter check (``STILL_CHECK = "detect"``): the board detected afresh on the earlier span, within a
        third of a spacing."""
        t_end = int(tq) - int(0.5 * age * 1e9)
        sub = self.stream.slice_time(t_end - int(age * 1e9), t_end + 1)
        if len(sub) < self.min_events:
            return False
        box = _roi_around(det.uv, self.stream.width, self.stream.height)
        if box is None or box[2] <= box[0] or box[3] <= box[1]:
            return False
        if how == "rims":
            rim, level = _rim_image(surfaces.surface(sub, self.kind, t_end, **self.params), self.kind, self.params,
                                    age)
            again = detect_circle_grid(rim, self.board, self.camera, foreground="rims", rim_threshold=level, roi=box)
        else:
            img = surfaces.count_image(sub)
            view = np.zeros_like(img)
            x0, y0, x1, y1 = box
            view[y0:y1, x0:x1] = img[y0:y1, x0:x1]
            again = detect_circle_grid(view, self.board, self.camera, foreground="bright", blur_sigma=BLOB_BLUR_PX)
        if again.reason != REASON_OK:
            return False
        seen = np.all(np.isfinite(det.uv), axis=1)
        both = seen & np.all(np.isfinite(again.uv), axis=1)
        if np.count_nonzero(both) < 4:
            return False
        spacing = float(np.median(neighbour_distance(det.uv[seen])))
        return float(np.median(np.linalg.norm(det.uv[both] - again.uv[both], axis=1))) < spacing / 3.0

    def _blobs(self, tq: int, first: float, roi: tuple[int, int, int, int] | None, long_spans: bool = False,
               lost: bool = False, predicted: np.ndarray | None = None):
        """The board as blobs of events (:func:`detect_circle_grid` on a count image) over the spans of
        :data:`BLOB_SPANS` (multiples of the window; the one that worked last first): (detection, span s,
        multiple) or None. With ``roi`` (where the board was a moment ago) that part of the image is searched
        first, then the whole image; with ``predicted`` (the board's circles carried forward from its last find) the
        blobs there are labelled by them first."""
        for mult in sorted(BLOB_SPANS, key=lambda m: m != first):
            if mult > SHORT_BLOB_SPAN and not long_spans:
                continue
            age = mult * self.window_s
            sub = self.stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
            if len(sub) < self.min_events:
                continue
            img = surfaces.count_image(sub)
            on = surfaces.count_image(sub, polarity="on") if BLOB_POLARITY_CENTRES else None
            for box in ([roi] if roi is not None else []) + [None]:
                view, on_view = img, on
                if box is not None:  # only the events around the board: fewer blobs, less clutter
                    x0, y0, x1, y1 = box
                    view = np.zeros_like(img)
                    view[y0:y1, x0:x1] = img[y0:y1, x0:x1]
                    if on is not None:
                        on_view = np.zeros_like(on)
                        on_view[y0:y1, x0:x1] = on[y0:y1, x0:x1]
                det = detect_circle_grid(view, self.board, self.camera, foreground="bright", blur_sigma=BLOB_BLUR_PX,
                                         predicted_uv=predicted if box is not None else None,
                                         rings=RING_PEAKS and box is None and mult >= RING_MIN_SPAN,
                                         polarity_images=None if on_view is None else (on_view, view - on_view))
                if det.reason == REASON_OK and mult > SHORT_BLOB_SPAN and lost and not self._holds_still(
                        det, tq, age, "blobs"):
                    break  # refused: a board smeared over the long span; try the other spans
                if det.reason == REASON_OK:
                    return det, age, mult
        return None

    def _backfill(self, passed_over: list[tuple], k: int, full: np.ndarray, last_rim, by_blobs: bool,
                  span: float) -> list[tuple]:
        """The windows passed over just before window ``k``'s find, searched backwards from it: each around the board
        of the window after it, its circles labelled by that board's (``full``, all circles), on the rims of the
        find's span (``span``, in windows) and then of the window and its shorter fractions, or when the find was on
        blobs, on the blob spans; the first window without the board ends it. Returns the finds in window order:
        (window index, query time, stamp, uv, all circles, detector, span in windows, events in the window).

        What keeps a wrong labelling out is the later board: the rim holes are labelled by its circles first (with the
        shift test), and any find, also one labelled from scratch (the lattice labelling inside the region when that
        fails, or the blob search, which like the lost search goes on to the whole image), is refused when it lies
        more than half a spacing from it (:func:`_jumped`). Finds on long spans are not put to the still-board test
        of the lost search (:meth:`_holds_still`): a fit to a board smeared over a long span would have to put its
        circles within half a spacing (median) of the later board's. Both were measured stricter (blobs around the
        board only, long spans held still): 1 to 3 correct detections fewer on three of the study's recordings and no
        wrong label fewer (docs/frontend.md).
        Windows passed over at the end of a chunk of windows (a worker's, a streamed span's) are not filled in: the
        next chunk searches its first windows in full."""
        board, kind, params = self.board, self.kind, self.params
        decaying = kind in ("time_surface", "leaky")
        age0 = _active_age_s(kind, params, self.window_s)
        fracs = [span] + [f for f in WINDOW_LADDER if f <= 1.0 and f != span]
        out = []
        nxt = k
        for kj, tq, i0, i1 in reversed(passed_over):
            if kj != nxt - 1 or i1 - i0 < self.min_events:
                break
            roi = _roi_around(full, self.stream.width, self.stream.height)
            if roi is None:
                break
            ev = self.stream.slice_index(int(i0), int(i1))
            det, how, mult, used, age = None, "rims", 1.0, ev, age0
            if by_blobs:
                blob = self._blobs(tq, span, roi, False, False, full)
                if blob is not None:
                    det, age, mult = blob
                    used = self.stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    how = "blobs"
            else:
                img = None
                for frac in fracs:
                    age = frac * age0
                    if img is None or not decaying:
                        if kind == "time_surface":
                            sub = ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1)
                        elif frac == 1.0 or decaying:
                            sub = ev
                        elif frac > 1.0:
                            sub = self.stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                        else:
                            sub = ev.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                        if len(sub) < self.min_events:
                            continue
                        img = surfaces.surface(sub, kind, int(tq), **params)
                    rim, level = _rim_image(img, kind, params, age)
                    det = detect_circle_grid(rim, board, self.camera, foreground="rims", rim_threshold=level, roi=roi,
                                             predicted_uv=full, rim_first=last_rim)
                    if det.reason == REASON_OK:
                        used, mult = (sub if frac > 1.0 else ev), frac
                        break
            if det is None or det.reason != REASON_OK or _jumped(det.uv, full):
                break
            t_det = None
            if self.timestamp == "events":
                t_det = _event_time(used, det.uv, int(tq), age)
            elif self.timestamp == "query":
                t_det = tq * 1e-9
            if t_det is None:
                t_det = tq * 1e-9 - 0.5 * age
            full = _complete_by_homography(det.uv, board)
            out.append((kj, tq, t_det, det.uv, full, how, mult, int(i1 - i0)))
            nxt = kj
        return out[::-1]

    def run(self, t_query: np.ndarray, i0s: np.ndarray, i1s: np.ndarray, progress=None):
        # OpenCV's internal threads cost more than they save on images this small (connected components:
        # 3x the CPU time with 2 threads); parallelism comes from ``workers`` instead.
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            return self._run(t_query, i0s, i1s, progress)
        finally:
            cv2.setNumThreads(threads)

    def _run(self, t_query: np.ndarray, i0s: np.ndarray, i1s: np.ndarray, progress=None):
        stream, board, kind, params = self.stream, self.board, self.kind, self.params
        aruco = make_aruco_detector(self.border_bits) if board.pattern == "aprilgrid" else None
        skipped: Counter[str] = Counter()
        retries: Counter[int] = Counter()
        secs = {"surfaces": 0.0, "detection": 0.0}
        t_out, uv_out, src_out, span_out, win_out = [], [], [], [], []
        outcome: list[str] = []  # per window: the detector that found the board, or why nothing was found
        n_events = 0
        last_good = 0
        roi = predicted = prev = None
        velocity = None  # the board's image motion per window at the last find (N, 2), or None
        as_image = False
        last_blob = BLOB_SPANS[0]
        last_rim = None  # the rim thickness of the last find on rims: tried first (circles change size slowly)
        small_circles = None  # index of the last window whose detection had circles too small for rims
        slow_board = None  # (window, whether the board moved slower than SLOW_PX_S there) from the last two detections
        period_s = float(np.median(np.diff(t_query))) * 1e-9 if t_query.size > 1 else 0.0
        sparse = LOST_SEARCH_STRIDE > 1 and board.pattern == "asymmetric_circles" and kind != "leaky"
        passed_over: list[tuple] = []  # windows passed over since the last find: (k, tq, i0, i1)
        for k, (tq, i0, i1) in enumerate(zip(t_query, i0s, i1s, strict=True)):
            if progress is not None:
                progress(k, t_query.size)
            if i1 - i0 < self.min_events:
                skipped["too_few_events"] += 1
                outcome.append("too_few_events")
                roi = predicted = velocity = None
                continue
            lost_for = k - (prev[0] if prev is not None else -1)
            if sparse and lost_for > LOST_DENSE_WINDOWS and (lost_for - LOST_DENSE_WINDOWS) % LOST_SEARCH_STRIDE:
                skipped[REASON_NOT_SEARCHED] += 1
                outcome.append(REASON_NOT_SEARCHED)
                passed_over.append((k, tq, i0, i1))
                continue
            ev = stream.slice_index(int(i0), int(i1))
            n_events += int(i1 - i0)
            age0 = _active_age_s(kind, params, self.window_s)
            decaying = kind in ("time_surface", "leaky")
            img = None
            det = None
            # Spans longer than the window: while the board was last seen moving slowly, or (every LOST_STRIDE-th
            # window) while it is lost, as when the robot sets off slowly after a stop.
            stale = slow_board is None or k - slow_board[0] > RECENT_WINDOWS
            long_spans = not decaying and board.pattern == "asymmetric_circles" and (
                (not stale and slow_board[1]) or (stale and LONG_WHEN_LOST and k % LOST_STRIDE == 0))
            # Start with the span that worked last time: the speed of the board changes slowly.
            order = sorted(range(len(WINDOW_LADDER)), key=lambda i: (i != last_good, i))
            if board.pattern != "asymmetric_circles":
                order = [0]
            elif small_circles is not None and k - small_circles <= RECENT_WINDOWS:
                order = []  # the board was just seen with circles too small for rims: straight to the blobs
            for j in order:
                frac = WINDOW_LADDER[j]
                if frac > 1.0 and not long_spans:
                    continue  # longer spans: for counts of circle grids just seen moving slowly only
                age = frac * age0
                c0 = time.perf_counter()
                if img is None or not decaying:
                    # Non-decaying kinds: rebuild the surface from the most recent events only. Decaying kinds
                    # are built once; the rim level below selects the age. A time surface's rims only show
                    # pixels whose last event is younger than tau, so older events need not be read at all
                    # (the leaky integrator sums over its whole look-back and keeps it).
                    if kind == "time_surface" and board.pattern == "asymmetric_circles":
                        sub = ev.slice_time(int(tq) - int(age0 * 1e9), int(tq) + 1)
                    elif frac == 1.0 or decaying:
                        sub = ev
                    elif frac > 1.0:  # slow motion: thin, sparse rims in one window; look further back
                        sub = self.stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    else:
                        sub = ev.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    if len(sub) < self.min_events:
                        continue  # too short a span to show the board; try the others
                    img = surfaces.surface(sub, kind, int(tq), **params)
                c1 = time.perf_counter()
                excess = False
                if board.pattern == "aprilgrid":
                    # A light blur joins the speckled event edges into the solid tag borders aruco looks for.
                    tag_img = cv2.GaussianBlur(img, (0, 0), self.tag_blur) if self.tag_blur > 0 else img
                    det = detect_aprilgrid(
                        surfaces.to_uint8(tag_img), board, self.camera, detector=aruco, layout=self.tag_layout
                    )
                    as_image = kind == "leaky"  # tags are only read off intensity-like images
                else:
                    det = None
                    as_image = False
                    if kind == "leaky":
                        # The leaky integrator approximates log intensity (circles dark) once the board has
                        # moved by more than a circle within tau; try it as an image first. Such a detection
                        # shows the circles where they are now: it is stamped with the query time.
                        det = detect_circle_grid(img, board, self.camera, foreground="dark")
                        as_image = det.reason == REASON_OK
                    if det is None or det.reason != REASON_OK:
                        rim, level = _rim_image(img, kind, params, age)
                        det = None
                        if roi is not None:
                            # Look where the board was a moment ago first: fewer pixels and less clutter, and
                            # the circles can be labelled by their predicted positions.
                            det = detect_circle_grid(rim, board, self.camera, foreground="rims",
                                                     rim_threshold=level, roi=roi, predicted_uv=predicted,
                                                     rim_first=last_rim)
                        if det is None or (RIMS_OUTSIDE_ROI and det.reason != REASON_OK):
                            det = detect_circle_grid(rim, board, self.camera, foreground="rims",
                                                     rim_threshold=level, rim_first=last_rim)
                        if (det.reason != REASON_OK and DENSE_RETRY and kind == "count" and frac > 1.0
                                and np.count_nonzero(img) > DENSE_ACTIVE * img.size):
                            ex = _excess_image(img)
                            first, det = det, None
                            if roi is not None:
                                det = detect_circle_grid(ex, board, self.camera, foreground="rims", rim_threshold=0.0,
                                                         roi=roi, predicted_uv=predicted)
                            if det is None or (RIMS_OUTSIDE_ROI and det.reason != REASON_OK):
                                det = detect_circle_grid(ex, board, self.camera, foreground="rims", rim_threshold=0.0)
                            excess = det.reason == REASON_OK
                            det = det if excess else first  # a miss keeps the plain image's reason
                if det.reason == REASON_OK and frac > 1.0 and stale and not self._holds_still(det, tq, age, "rims"):
                    det = _refused(det)
                secs["surfaces"] += c1 - c0
                secs["detection"] += time.perf_counter() - c1
                if det.reason == REASON_OK:
                    retries[("rims_excess" if excess else "rims", WINDOW_LADDER[j])] += 1
                    if frac > 1.0:
                        ev = sub  # the events the rims came from, for the time stamp
                    last_good = j
                    if not excess and RIM_MEMORY:
                        last_rim = det.rim_px
                    break
            blob = None
            blob_tried = False
            if (det is None or det.reason != REASON_OK) and board.pattern == "asymmetric_circles":
                blob_tried = True
                # Circles a few pixels wide have no inside left between their rims, and slow motion leaves a
                # window too sparse for rims: look for the circles as blobs of events over this and longer spans.
                c0 = time.perf_counter()
                blob = self._blobs(tq, last_blob, roi, long_spans, stale,
                                   predicted if BLOB_TRACKING else None)
                secs["blobs"] = secs.get("blobs", 0.0) + time.perf_counter() - c0
                if blob is not None:
                    det, age, mult = blob
                    ev = self.stream.slice_time(int(tq) - int(age * 1e9), int(tq) + 1)
                    as_image = False
                    last_blob = mult
                    retries[("blob", mult)] += 1
            if det is None or det.reason != REASON_OK:
                reason = det.reason if det is not None else (REASON_NOT_FOUND if blob_tried else "too_few_events")
                skipped[reason] += 1
                outcome.append(reason)
                predicted = None
                if PREDICT_THROUGH_MISSES and prev is not None and velocity is not None \
                        and k + 1 - prev[0] <= PREDICT_THROUGH_MISSES:
                    predicted = prev[2] + velocity * (k + 1 - prev[0])
                if not (KEEP_ROI and prev is not None and k - prev[0] <= RECENT_WINDOWS):
                    roi = None
                continue
            # A prediction carried through missed windows labels candidates (with its own shift test) but does not
            # refuse a find: the board's speed may have changed meanwhile.
            fresh = prev is not None and k - prev[0] == 1
            if board.pattern == "asymmetric_circles" and predicted is not None and fresh and _jumped(det.uv, predicted):
                # The previous window's board, carried forward at its speed, lies half a spacing or more away:
                # one of the two labellings is shifted. Refuse this one; the search starts afresh next window.
                skipped[REASON_JUMP] += 1
                outcome.append(REASON_JUMP)
                roi = predicted = velocity = None
                continue
            if RIM_POLARITY_CENTRES and board.pattern == "asymmetric_circles" and blob is None and not as_image \
                    and kind == "count":
                c0 = time.perf_counter()
                det = _rim_centres_by_polarity(det, ev.slice_time(int(tq) - int(age * 1e9), int(tq) + 1), board,
                                               self.camera)
                secs["rim_polarity"] = secs.get("rim_polarity", 0.0) + time.perf_counter() - c0
            if board.pattern == "asymmetric_circles":
                seen = det.uv[np.all(np.isfinite(det.uv), axis=1)]
                small = float(np.median(neighbour_distance(seen))) < MIN_RIM_SPACING_PX if len(seen) > 1 else False
                small_circles = k if small else None
            t_det = None
            if self.timestamp == "query" or (as_image and self.timestamp == "events"):
                t_det = tq * 1e-9
            elif self.timestamp == "events":
                t_det = _event_time(ev, det.uv, int(tq), age)
            if t_det is None:  # "window_centre", or no event near the detection (cannot happen for rims)
                t_det = tq * 1e-9 - 0.5 * age
            # Constant-velocity prediction of all circles for the next window (from the last two windows;
            # circles not seen are filled in by the board's homography).
            full = _complete_by_homography(det.uv, board) if board.pattern == "asymmetric_circles" else det.uv
            if passed_over:
                c0 = time.perf_counter()
                filled = self._backfill(passed_over, k, full, last_rim, blob is not None,
                                        last_blob if blob is not None else WINDOW_LADDER[last_good])
                secs["backfill"] = secs.get("backfill", 0.0) + time.perf_counter() - c0
                for kj, tqj, t_j, uv_j, full_j, how, mult_j, n_j in filled:  # in window order
                    n_events += n_j
                    skipped[REASON_NOT_SEARCHED] -= 1
                    if not skipped[REASON_NOT_SEARCHED]:
                        del skipped[REASON_NOT_SEARCHED]
                    outcome[kj] = how
                    retries[("backfill_" + how, mult_j)] += 1
                    t_out.append(t_j)
                    win_out.append(tqj * 1e-9)
                    uv_out.append(uv_j)
                    src_out.append(how)
                    span_out.append(float(mult_j))
                    prev = (kj, t_j, full_j)
                passed_over = []
            if prev is not None and k - prev[0] <= RECENT_WINDOWS and t_det > prev[1]:
                step = np.nanmedian(np.linalg.norm(full - prev[2], axis=1))
                slow_board = (k, bool(step / (t_det - prev[1]) < SLOW_PX_S))
            if prev is not None and k - prev[0] <= VELOCITY_WINDOWS and t_det > prev[1]:
                velocity = (full - prev[2]) * (period_s / (t_det - prev[1]))
            else:
                velocity = np.zeros_like(full)
            predicted = full + velocity
            prev = (k, t_det, full)
            t_out.append(t_det)
            win_out.append(tq * 1e-9)
            uv_out.append(det.uv)
            src_out.append("blobs" if blob is not None else ("image" if as_image else "rims"))
            span_out.append(float(last_blob if blob is not None else (1.0 if as_image else WINDOW_LADDER[last_good])))
            outcome.append(src_out[-1])
            roi = _roi_around(det.uv, stream.width, stream.height)
        return t_out, uv_out, skipped, secs, n_events, retries, src_out, outcome, span_out, win_out


# The bookkeeping key of the poses solved in the worker processes (detect_in_events' ``pnp``).
_POSES = "_poses"
# The job of the current parallel run; forked workers inherit it instead of receiving a pickled copy.
_JOB: tuple | None = None


def _run_chunk(bounds: tuple[int, int]):
    job, t_query, i0s, i1s, pnp = _JOB
    a, b = bounds
    part = job.run(t_query[a:b], i0s[a:b], i1s[a:b])
    if pnp is None:
        return part, None
    return part, [frame_pose(uv, job.board.points, job.camera, sigma_px=pnp["sigma_px"]) for uv in part[1]]


def _run_parallel(job: _WindowJob, t_query, i0s, i1s, workers: int, progress, pnp: dict | None = None,
                  beside: Callable[[], None] | None = None) -> list:
    """Contiguous chunks of windows on ``workers`` forked processes (the stream is shared, not copied): a list of
    (part, poses), poses None unless ``pnp`` ({"sigma_px": ...}) asks for each detection's pose beside it.
    ``beside()`` runs in this process while the workers detect."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    global _JOB
    _JOB = (job, t_query, i0s, i1s, pnp)
    edges = np.linspace(0, t_query.size, workers + 1).round().astype(int)  # one run per worker: tracking state
    chunks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]
    try:
        from ..core.processes import worker_initializer

        init, args = worker_initializer()
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=init, initargs=args) as pool:
            parts = []
            results = pool.map(_run_chunk, chunks)  # every chunk is submitted now
            if beside is not None:
                beside()
            for j, part in enumerate(results):
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


def _no_board(windows: int, skipped: Counter, board: Board, info: dict | None = None) -> InsufficientDataError:
    exc = InsufficientDataError(
        f"front end: no board detected in any of {windows} windows ({dict(skipped)}); check that the board "
        f"definition ({board.cols} x {board.rows} {board.pattern}) matches the target, that it is in view and "
        "moving, and try another surface kind"
    )
    exc.frontend_info = info  # the windows' outcomes, for the diagnosis's coverage
    return exc


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
    tag_border_bits: int | None = None,
    tag_blur_sigma: float = 1.0,
    workers: int = 1,
    progress: Callable[[int, int], None] | None = None,
    t_query_ns: np.ndarray | None = None,
    require_detection: bool = True,
    mask_hot_pixels: bool | None = None,
    pnp: dict | None = None,
) -> tuple[Detections, dict]:
    """Board detections in event surfaces at ``rate_hz``; see :func:`camera_track_from_events`.

    ``t_query_ns`` replaces the window grid (every 1 / rate_hz from the first event) by given window end
    times, as the streaming front end does per span. With ``require_detection`` False a stream without any
    detection gives empty detections instead of an error. ``mask_hot_pixels`` (default
    :data:`MASK_HOT_PIXELS`) drops the events of pixels that fire like hot pixels (:mod:`.noise`) first.
    ``pnp`` ({"sigma_px": ...}): with ``workers`` > 1, each detection's pose is solved in the worker that found it
    (:func:`~plsgraph.frontend.pose.frame_pose`) and kept in the bookkeeping for :func:`camera_track_from_events`.
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
    n_hot = 0
    if (MASK_HOT_PIXELS if mask_hot_pixels is None else mask_hot_pixels):
        hot = hot_pixel_mask(stream)
        n_hot = int(hot.sum())
        stream = drop_pixels(stream, hot)
        if len(stream) == 0:
            raise InsufficientDataError("front end: every event came from a hot pixel")
    # Lamps flickering with the mains: recognised and reported (see FLICKER_WARN_SHARE); their phase-locked events
    # are dropped only with SUPPRESS_FLICKER (docs/frontend.md, "Flickering lights"). Otherwise the windows do not
    # depend on the test, and with worker processes it runs in this process while they detect.
    # Only to report it, a long stream's flicker is measured on a sample of it (noise.flicker_census).
    flicker_first = SUPPRESS_FLICKER or max(1, int(workers)) == 1
    tested: list = []  # (share of the events, frequency, pixels) of the test run beside the workers
    if SUPPRESS_FLICKER:
        flicker, flicker_hz, n_flicker = flicker_events(stream)
        flicker_share = float(flicker.mean())
        if flicker.any():
            stream = drop_events(stream, flicker)
    elif flicker_first:
        flicker_share, flicker_hz, n_flicker = flicker_census(stream)
    if t_query_ns is None:
        t_query = np.arange(stream.t_first + period_ns, stream.t_last + period_ns, period_ns, dtype=np.int64)
    else:
        t_query = np.asarray(t_query_ns, dtype=np.int64)
    i1s = np.searchsorted(stream.t, t_query, side="right")
    i0s = np.searchsorted(stream.t, t_query - window_ns, side="right")
    job = _WindowJob(
        stream, camera, board, kind, params, window_s, min_events, timestamp, tag_layout,
        board.tag_border_bits if tag_border_bits is None else tag_border_bits, tag_blur_sigma,
    )
    workers = max(1, min(int(workers), t_query.size))
    poses: list | None = None  # each detection's pose, when solved in the worker processes (``pnp``)
    if workers == 1:
        parts = [job.run(t_query, i0s, i1s, progress)]
    else:
        beside = None if flicker_first else (lambda: tested.append(flicker_census(stream)))
        solved = _run_parallel(job, t_query, i0s, i1s, workers, progress, pnp, beside)
        parts = [part for part, _ in solved]
        if pnp is not None:
            poses = [e for _, part_poses in solved for e in part_poses]
    if not flicker_first:
        flicker_share, flicker_hz, n_flicker = tested[0] if tested else flicker_census(stream)
    skipped: Counter[str] = Counter()
    secs = {"surfaces": 0.0, "detection": 0.0, "blobs": 0.0, "backfill": 0.0, "rim_polarity": 0.0}
    t_out, uv_out, src_out, span_out, win_out = [], [], [], [], []
    n_events = 0
    ladder: Counter[tuple] = Counter()
    outcomes: list[str] = []
    for p_t, p_uv, p_skipped, p_secs, p_n, p_ladder, p_src, p_outcome, p_span, p_win in parts:
        outcomes += p_outcome
        skipped.update(p_skipped)
        ladder.update(p_ladder)
        n_events += p_n
        for key in secs:
            secs[key] += p_secs.get(key, 0.0)
        t_out += list(p_t)
        uv_out += list(p_uv)
        src_out += list(p_src)
        span_out += list(p_span)
        win_out += list(p_win)
    same_stamp_windows: list[float] = []
    if t_out:  # long-span finds are stamped half their span back, possibly before earlier finds: put them in order
        keep = time_order(np.asarray(t_out, dtype=float), np.asarray(span_out, dtype=float))
        if keep.size < len(t_out):
            skipped["same_stamp"] += len(t_out) - keep.size
            same_stamp_windows = [win_out[i] for i in np.setdiff1d(np.arange(len(t_out)), keep)]
        t_out, uv_out, src_out, span_out, win_out = ([x[i] for i in keep]
                                                     for x in (t_out, uv_out, src_out, span_out, win_out))
        if poses is not None:
            poses = [poses[i] for i in keep]
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
        "detector": src_out,
        "span_windows": span_out,
        "window_t": win_out,
        "window_outcomes": {"t": (t_query * 1e-9).tolist(), "outcome": outcomes},
        "skipped": dict(skipped),
        "events_used": n_events,
        "detected_at_window_fraction": {f"{m}:{f:g}": int(c) for (m, f), c in sorted(ladder.items())},
        "seconds": secs,
        "warnings": [],
        "hot_pixels": n_hot,
        "flicker_hz": flicker_hz,
        "flicker_pixels": n_flicker,
        "flicker_event_share": flicker_share,
    }
    _mark_outcomes(info, np.asarray(same_stamp_windows, dtype=float), "same_stamp")
    if board.pattern == "asymmetric_circles" and board_is_symmetric(board):
        info["warnings"].append(
            f"board {board.name!r} looks the same turned by 180 degrees (even number of rows): its detections "
            "cannot be labelled uniquely and are rejected as ambiguous; use a board with an odd number of rows"
        )
    if not t_out and require_detection:
        raise _no_board(t_query.size, skipped, board, info)
    if poses is not None:
        info[_POSES] = poses  # taken out by camera_track_from_events
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
    tag_border_bits: int | None = None,
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
    covariance (default: estimated per frame). AprilGrids: ``tag_layout`` / ``tag_border_bits`` (default: the
    board's) as in :func:`plsgraph.frontend.detect.detect_aprilgrid`, the image blurred by ``tag_blur_sigma`` px
    first.
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
        pnp={"sigma_px": sigma_px},
    )
    return _track_from_detections(dets, info, camera, max_rms_px, sigma_px, info.pop(_POSES, None))


#: The window outcome of a detection PnP gave no pose for (it failed, or its reprojection RMS was too large).
REASON_NO_POSE = "no_pose"
#: Share of the events (largest over the streamed spans) from pixels flickering with the lights above which the
#: front end warns (:func:`plsgraph.frontend.noise.flicker_events`) ...
FLICKER_WARN_SHARE = 0.1
#: ... when the board was found in fewer than this share of the windows (flicker alone does not stop the detector:
#: study run 1, 81 % of its events flicker, has it in 90 % of its in-view windows).
FLICKER_WARN_FOUND = 0.5
#: Spans handed to the worker processes beyond one per worker, so that a worker finishing a span finds the next
#: one decoded and waiting (each costs one more span of events in memory).
QUEUED_SPANS = 1


#: Detections per streamed span whose windows' events are kept as count images for the report's event frames (the
#: span's first and last and some between), and most such images kept for the whole recording (every other one is
#: dropped when there are more: an even spread over the recording, in bounded memory).
EVENT_FRAMES_PER_SPAN = 5
EVENT_FRAMES_KEPT = 24


def event_frame(stream: EventStream, mid_ns: int, window_s: float) -> np.ndarray | None:
    """The count image (height, width; uint16) of ``stream``'s events within half a window of ``mid_ns`` (t0 <= t < t1,
    as the report's event frames show a detection's window), or None without events there."""
    half = int(window_s * 0.5e9)
    ev = stream.slice_time(mid_ns - half, mid_ns + half)
    if len(ev) == 0:
        return None
    w, h = stream.width, stream.height
    counts = np.bincount(ev.y.astype(np.int64) * w + ev.x, minlength=w * h)
    return np.minimum(counts, np.iinfo(np.uint16).max).astype(np.uint16).reshape(h, w)


def _event_frames(stream: EventStream, t: np.ndarray, window_s: float, n: int = EVENT_FRAMES_PER_SPAN) -> list[tuple]:
    """(mid, count image) of up to ``n`` of the detections at times ``t`` (s, the events' clock) evenly over them: the
    images the report's event frames draw (:func:`plsgraph.report.coverage.fig_event_frames`), made here from the
    events at hand instead of decoding the recording again."""
    if t.size == 0:
        return []
    out = []
    for i in np.unique(np.linspace(0, t.size - 1, n).round().astype(int)):
        mid = int(round(float(t[i]) * 1e9))
        img = event_frame(stream, mid, window_s)
        if img is not None:
            out.append((mid, img))
    return out


class _FrameSample:
    """At most ``n`` of the frames added, (mid, image) in time order, spread evenly over them in bounded memory: every
    ``stride``-th frame added is kept (the stride doubles, and the kept ones are thinned to match, whenever more than
    ``n`` would be kept), and the last frame added is kept besides."""

    def __init__(self, n: int) -> None:
        self.n, self.stride, self.count = max(2, int(n)), 1, 0
        self.kept: list[tuple[int, tuple]] = []  # (index among those added, frame)
        self.last: tuple[int, tuple] | None = None

    def add(self, frame: tuple) -> None:
        if self.count % self.stride == 0:
            self.kept.append((self.count, frame))
            while len(self.kept) > self.n - 1:  # one place is the last frame's
                self.stride *= 2
                self.kept = [(i, f) for i, f in self.kept if i % self.stride == 0]
        self.last = (self.count, frame)
        self.count += 1

    def frames(self) -> list[tuple]:
        out = [f for _, f in self.kept]
        if self.last is not None and (not self.kept or self.kept[-1][0] != self.last[0]):
            out.append(self.last[1])
        return out


def _keep_frames(info: dict, n: int, keep: np.ndarray) -> None:
    for key in PER_FRAME_INFO:
        if len(info.get(key, ())) == n:
            info[key] = [v for v, k in zip(info[key], keep, strict=True) if k]


def _track_from_detections(
    dets: Detections, info: dict, camera: CameraModel, max_rms_px: float, sigma_px: float | None,
    estimates: list | None = None,
) -> CameraTrack:
    """PnP on the detections and the front end's bookkeeping merged into the track's info. ``estimates``: each
    detection's pose if already solved (:func:`~plsgraph.frontend.pose.frame_pose`, same settings)."""
    c0 = time.perf_counter()
    skipped = Counter(info["skipped"])
    bad = inconsistent_frames(dets.t, dets.uv) if len(dets) else np.zeros(0, dtype=bool)
    if bad.any():
        # A labelling shifted by a lattice step fits its own pixels (PnP cannot refuse it) but not its neighbours.
        skipped[REASON_INCONSISTENT] += int(bad.sum())
        win = info.get("window_t")  # the window each detection was found in (its stamp may lie windows back)
        found_in = np.asarray(win, dtype=float) if win is not None and len(win) == len(dets) else np.asarray(dets.t)
        where = found_in[bad]
        _mark_outcomes(info, where, REASON_INCONSISTENT)
        _keep_frames(info, len(dets), ~bad)
        info["detected"] = int(info.get("detected", len(dets))) - int(bad.sum())
        dets = Detections(np.asarray(dets.t)[~bad], np.asarray(dets.uv)[~bad], dets.board_points)
        if estimates is not None:
            estimates = [e for e, b in zip(estimates, bad, strict=True) if not b]
        if not len(dets):
            exc = InsufficientDataError("no detection agrees with its neighbours in time; check the board definition")
            exc.frontend_info = info
            raise exc
    info["seconds"]["consistency"] = time.perf_counter() - c0
    c0 = time.perf_counter()
    win = info.get("window_t")  # the window each detection was found in
    found_in = np.asarray(win, dtype=float) if win is not None and len(win) == len(dets) else np.asarray(dets.t)
    try:
        extra = {} if estimates is None else {"estimates": estimates}
        track = camera_track_from_detections(dets, camera, max_rms_px=max_rms_px, sigma_px=sigma_px, **extra)
    except InsufficientDataError as exc:  # no frame gave a pose: the diagnosis still shows what each window gave
        _mark_outcomes(info, found_in, REASON_NO_POSE)
        exc.frontend_info = info
        raise
    info["seconds"]["pnp"] = info["seconds"].get("pnp", 0.0) + time.perf_counter() - c0
    skipped.update(track.info.get("rejected", {}))
    info["skipped"] = dict(skipped)
    info["poses"] = len(track)
    posed = np.isin(np.asarray(dets.t), np.asarray(track.t))
    _mark_outcomes(info, found_in[~posed], REASON_NO_POSE)  # found, then refused by PnP: not a find in the coverage
    _keep_frames(info, len(dets), posed)  # as the track's detections
    info["median_rms_px"] = track.info.get("median_rms_px")
    share = info.get("flicker_event_share") or 0.0
    found = int(info.get("detected", 0)) / max(int(info.get("windows", 0)), 1)
    if share >= FLICKER_WARN_SHARE and found < FLICKER_WARN_FOUND:
        info["warnings"].append(
            f"the board was found in only {100 * found:.0f} % of the windows, and {100 * share:.0f} % of the events "
            f"come from about {info['flicker_pixels']} pixels flickering in step with {info['flicker_hz']:g} Hz "
            "lighting (lamps on AC mains); if the board was in view, record under steady (DC or day) light or with the "
            "camera's anti-flicker filter on"
        )
    for w in info["warnings"]:
        log.warning(w)
    log.info(
        "front end (%s): %d windows, %d detections, %d poses; skipped %s",
        info["kind"], info["windows"], info["detected"], info["poses"], info["skipped"],
    )
    return CameraTrack(track.t, track.T_board_cam, track.cov, track.rms_px, track.detections, info)


def _mark_outcomes(info: dict, t_refused: np.ndarray, reason: str) -> None:
    """The outcome of each refused detection's window (the window that ends nearest its stamp) becomes ``reason``."""
    wo = info.get("window_outcomes")
    if not wo or not len(wo["t"]) or not t_refused.size:
        return
    tw = np.asarray(wo["t"], dtype=float)
    k = np.clip(np.searchsorted(tw, t_refused), 1, tw.size - 1)
    k = np.where(np.abs(tw[k - 1] - t_refused) <= np.abs(tw[k] - t_refused), k - 1, k)
    outcome = list(wo["outcome"])
    for j in k:
        outcome[int(j)] = reason
    info["window_outcomes"] = {"t": wo["t"], "outcome": outcome}


#: Stamps closer than this are one stamp (seconds on an epoch clock carry about 0.2 us of rounding; window-centre
#: stamps of spans that nest, e.g. 2 windows ending at k and 4 ending at k + 1, coincide up to that rounding).
SAME_STAMP_S = 1e-6


def time_order(t: np.ndarray, span: np.ndarray | None = None) -> np.ndarray:
    """Indices that put detections in stamp order, one per stamp. A detection found on a span of several windows is
    stamped half its span back, which can lie before detections of the windows just before it (a board found again
    after a loss, a span that ends in the next streamed span); it is a detection of its own window all the same and
    keeps its place in time. Of detections with the same stamp (within SAME_STAMP_S) the one from the shortest span is
    kept."""
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    span = np.zeros_like(t) if span is None else np.asarray(span, dtype=float)
    q = np.round(t / SAME_STAMP_S).astype(np.int64)  # stamps on a grid of SAME_STAMP_S (epoch seconds fit)
    order = np.lexsort((span, q))  # by stamp, then by span
    qs = q[order]
    return order[np.r_[True, qs[1:] - qs[:-1] > 1]]  # one grid step apart still counts as the same stamp


def _ready() -> None:
    """A worker process's first task: loading this module (to unpickle the task) is what it is for."""


def _detect_span(args: tuple) -> tuple[Detections, dict, list]:
    """One streamed span's windows (in this process or a worker), and each detection's pose
    (:func:`~plsgraph.frontend.pose.frame_pose`: it depends on that detection alone, so it is solved where the
    detection was made, in parallel with the other spans)."""
    buf, camera, board, rate_hz, kind, q, detect_options, sigma_px = args
    if isinstance(buf, list):  # the span's chunks, joined here rather than in the process that reads them
        chunks = buf
        buf = chunks[0] if len(chunks) == 1 else EventStream.concatenate(chunks)
        # The task holds the list until it returns: emptied, the chunks' arrays go now that they are joined (a span's
        # worth of memory; the caller's own list of them, in this process, is another list and keeps them).
        chunks.clear()
    dets, part = detect_in_events(buf, camera, board, rate_hz, kind, t_query_ns=q, require_detection=False,
                                  **detect_options)
    part["event_frames"] = _event_frames(buf, dets.t, float(part["window_s"]))
    c0 = time.perf_counter()
    poses = [frame_pose(uv, dets.board_points, camera, sigma_px=sigma_px) for uv in dets.uv]
    part["seconds"]["pnp"] = part["seconds"].get("pnp", 0.0) + time.perf_counter() - c0
    return dets, part, poses


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
    workers: int = 1,
    while_waiting: Callable[[], None] | None = None,
    **detect_options,
) -> CameraTrack:
    """The front end of :func:`camera_track_from_events` on a stream of event chunks, in bounded memory.

    Windows lie on the same grid as in one pass (every 1 / ``rate_hz`` from the first event). Events are
    buffered until they span ``span_s``; the windows ending inside the buffer are detected, then all but the
    last ``history_s`` (longer than any window's look-back) is dropped. Memory therefore follows the span,
    not the recording's length. The grid tracking restarts at each span (a full search in its first window).
    ``expected_span_ns`` (first, last event time, e.g. from the file's summary) only sizes the progress bar.
    ``workers`` > 1 detects that many spans at once in worker processes, with the same result as one.
    ``while_waiting()`` is called once the whole stream is read while worker processes still detect its last spans
    (work this process can do meanwhile; what it raises is logged, not raised).
    """
    if not (span_s > 0 and history_s > 0 and rate_hz > 0):
        raise InputError("streaming front end: span_s, history_s and rate_hz must be positive")
    period = int(round(1e9 / rate_hz))
    _, window_s = _window_of(resolve_kind(kind), detect_options.get("surface_params"), detect_options.get("window_s"),
                             rate_hz)
    span_ns = int(span_s * 1e9)
    keep_ns = max(int(history_s * 1e9), int(window_s * 1e9) + period)  # every window's look-back stays buffered
    reorder_ns = 100_000_000  # packets arrive up to this much out of order: their windows wait that long
    next_q: int | None = None
    t_parts: list[np.ndarray] = []
    uv_parts: list[np.ndarray] = []
    pose_parts: list = []  # each detection's pose, solved beside it
    src_parts: list[str] = []
    span_parts: list[float] = []
    win_parts: list[float] = []
    wo_t: list[float] = []
    wo_o: list[str] = []
    info: dict = {}
    skipped: Counter[str] = Counter()
    late_events = 0
    total = None
    if expected_span_ns is not None:
        total = max(1, int((expected_span_ns[1] - expected_span_ns[0]) // period))

    event_frames = _FrameSample(EVENT_FRAMES_KEPT)  # some detections' windows, for the report

    def absorb(dets: Detections, part: dict, poses: list) -> None:
        nonlocal info
        for frame in part.pop("event_frames", []):
            event_frames.add(frame)
        t_parts.append(dets.t)
        pose_parts.extend(poses)
        uv_parts.append(dets.uv)
        src_parts.extend(part["detector"])
        span_parts.extend(part["span_windows"])
        win_parts.extend(part["window_t"])
        wo_t.extend(part["window_outcomes"]["t"])
        wo_o.extend(part["window_outcomes"]["outcome"])
        skipped.update(part["skipped"])
        if info:
            info["windows"] += part["windows"]
            info["events_used"] += part["events_used"]
            info["hot_pixels"] = max(info.get("hot_pixels", 0), part.get("hot_pixels", 0))
            if part.get("flicker_pixels", 0) > info.get("flicker_pixels", 0):
                for k in ("flicker_hz", "flicker_pixels", "flicker_event_share"):
                    info[k] = part.get(k)
            for k, v in part["seconds"].items():
                info["seconds"][k] = info["seconds"].get(k, 0.0) + v
            ladder = info["detected_at_window_fraction"]
            for k, v in part["detected_at_window_fraction"].items():
                ladder[k] = ladder.get(k, 0) + v
        else:
            info = part
        if progress is not None:
            done = info["windows"]
            progress(done, max(done, total or done))

    pool = None
    pending: list = []  # spans being detected in worker processes, oldest first
    if workers > 1:
        import multiprocessing as mp

        from ..core.processes import spawn_would_rerun_main, warn_in_process

        if mp.current_process().daemon:  # e.g. a Dask or multiprocessing pool worker: it may not start processes
            workers = 1
        elif spawn_would_rerun_main():  # a spawned worker would run the calling script again
            warn_in_process("the front end")
            workers = 1

    # The buffered events as the chunks they came in, in time order: a span is handed on as its chunks and joined
    # where it is detected (a worker), so this process, which also reads the recording, neither copies the growing
    # span again for every chunk nor makes one span-sized copy per span.
    parts: list[EventStream] = []

    def detect(t_end: int) -> None:
        nonlocal parts, next_q, pool
        q = np.arange(next_q, t_end, period, dtype=np.int64)
        if q.size:
            args = (list(parts), camera, board, rate_hz, kind, q, detect_options, sigma_px)
            if pool is not None:
                # Spans are independent (tracking restarts at each), so they can be detected side by side with
                # the same result; at most ``workers + QUEUED_SPANS`` spans' events are held at once, so memory
                # stays bounded. Results are absorbed in order; a span that finished before an older, slower one
                # waits as its (small) result, and does not keep the next span from an idle worker.
                pending.append(pool.submit(_detect_span, args))
                while True:
                    while pending and pending[0].done():
                        absorb(*pending.pop(0).result())
                    running = [f for f in pending if not f.done()]
                    if len(running) < workers + QUEUED_SPANS:
                        break
                    wait(running, return_when=FIRST_COMPLETED)
            else:
                absorb(*_detect_span(args))
            next_q = int(q[-1]) + period
        cut = next_q - keep_ns  # every later window's look-back stays
        parts = [p.slice_time(cut, np.iinfo(np.int64).max) for p in parts if p.t_last >= cut]
        parts = [p for p in parts if len(p)]

    try:  # the worker processes end however this ends
        if workers > 1:
            from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

            # Started fresh ("spawn"), not forked: the calibrating process may have threads by now (the figure
            # worker's), and a fork taken while one of them holds a lock can hang the child. Started before the
            # first span is decoded, so that the workers have loaded the detector by the time it arrives.
            from ..core.processes import worker_initializer

            init, args = worker_initializer()  # the workers end with this process, however it ends
            pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=init, initargs=args)
            for _ in range(workers):
                pool.submit(_ready)
        for ch in chunks:
            if len(ch) == 0:
                continue
            if next_q is not None and ch.t_first < next_q - period:
                late_events += int(np.count_nonzero(ch.t < next_q - period))  # their windows are already done
            if not parts:
                parts, t_last = [ch], ch.t_last
            elif ch.t_first >= t_last:
                parts.append(ch)
                t_last = ch.t_last
            else:  # packets that overlap in time: merge, so every window sees its events in order
                held = parts[0] if len(parts) == 1 else EventStream.concatenate(parts)
                merged = EventStream(*(np.concatenate([getattr(held, a), getattr(ch, a)]) for a in "txyp"),
                                     held.width, held.height).sorted()
                parts, t_last = [merged], merged.t_last
            if next_q is None:
                next_q = parts[0].t_first + period
            if t_last - reorder_ns - next_q >= span_ns:
                detect(t_last - reorder_ns)  # windows well before the newest event have all their events
        if not parts:
            raise InsufficientDataError("front end: the event stream is empty; check the recording's event topic")
        detect(t_last + period)
        if pending and while_waiting is not None:
            try:
                while_waiting()
            except Exception as exc:  # noqa: BLE001 - work beside the front end must not cost it
                from ..core.processes import reraise_interrupt

                reraise_interrupt(exc)  # interrupted inside an import: the interrupt, not a failed import
                log.warning("while the front end's workers finish: %s", exc)
        while pending:
            absorb(*pending.pop(0).result())
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    t = np.concatenate(t_parts) if t_parts else np.zeros(0)
    uv = np.concatenate(uv_parts) if uv_parts else np.zeros((0, board.n_points, 2))
    src = np.asarray(src_parts, dtype=object)
    spans = np.asarray(span_parts, dtype=float)
    wins = np.asarray(win_parts, dtype=float)
    if t.size > 1:  # a long-span find stamped before detections of earlier windows (across spans): in time order
        keep = time_order(t, spans)
        dropped_windows = np.delete(wins, keep)
        if keep.size < t.size:
            skipped["same_stamp"] += int(t.size - keep.size)
        t, uv, src, spans, wins = t[keep], uv[keep], src[keep], spans[keep], wins[keep]
        pose_parts = [pose_parts[i] for i in keep]
    else:
        dropped_windows = np.zeros(0)
    info["detector"] = src.tolist()
    info["span_windows"] = spans.tolist()
    info["window_t"] = wins.tolist()
    info["window_outcomes"] = {"t": wo_t, "outcome": wo_o}
    _mark_outcomes(info, dropped_windows, "same_stamp")
    info["skipped"] = dict(skipped)
    info["detected"] = int(t.size)
    info["streamed_span_s"] = span_s
    info["late_events"] = late_events  # arrived after their windows were detected (out-of-order packets)
    if t.size == 0:
        raise _no_board(info.get("windows", 0), skipped, board, info)
    if progress is not None:
        progress(info["windows"], info["windows"])
    track = _track_from_detections(Detections(t, uv, board.points), info, camera, max_rms_px, sigma_px, pose_parts)
    track.info["event_frames"] = event_frames.frames()  # the pipeline takes them (Run.event_frames): not a report item
    return track
