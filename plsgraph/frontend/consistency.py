"""Detections that disagree with their neighbours in time: a labelling shifted by a lattice step.

A circle grid labelled one column off, or mirrored, still gives a pose that fits its own pixels well, so PnP's
residual cannot refuse it; the pose is then centimetres from its neighbours and, for the closed form and the
factor graph, an outlier with a large pull (three such frames out of 440 moved the refined yaw of one validation
recording by 8 degrees). The circles' image motion is smooth over a few frame periods, so each detection is
compared with where its neighbours put the board at its time: every pair of neighbours within ``max_dt_s``
predicts each point by a line through time (interpolation when they straddle the frame, extrapolation when
not), and the detection is refused when the median over pairs of the median point distance exceeds
``spacings`` lattice spacings. The median over pairs keeps one wrong neighbour from condemning a good frame.
A frame with fewer than two neighbours within ``max_dt_s`` is checked against its two nearest within twice
that, and failing that against its nearest detections before and after within MAX_BRIDGE_S when the board moved
less than a spacing between them (a slow board's isolated finds); one without is kept (it cannot be checked).

Consecutive wrong frames vouch for each other: a slow board labelled afresh after a gap, one lattice step off, is
then tracked in that labelling for several frames. So where two runs of frames meet across a short gap, each run's
board is carried to the middle of the gap at its own speed; when the two disagree by most of a spacing in their
labels but their circles coincide once the labels are ignored, one run is a lattice step off, and which of its
labels name which of the other's is read off the circles. Runs joined by such tests form chains; composing those
maps along the chain gives each run's labels in the first run's terms, runs that agree there share a labelling,
and every labelling but the one with the most frames is refused (all of them when the most are tied). A run of one
frame is carried at its neighbouring run's speed; two single frames are not compared.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from .detect import neighbour_distance

#: Reason recorded for a refused detection (window outcome and skipped counts).
REASON_INCONSISTENT = "inconsistent_with_neighbours"
#: Neighbours within this time of a frame predict it (s).
MAX_DT_S = 0.1
#: A frame whose points lie this many lattice spacings (median) from the neighbours' prediction is refused.
SPACINGS = 0.5
#: At most this many neighbours on each side.
MAX_SIDE = 3
#: A pair predicts a frame only if the frame lies within this many of the pair's own time apart from the first of
#: them (|a| in uv_j + a (uv_k - uv_j)): beyond, the pair's detection noise is amplified past the threshold.
MAX_EXTRAPOLATION = 3.0
#: Runs of frames a lattice step off the run they meet across a short gap are refused (shifted_runs).
SHIFTED_RUNS = True


def _spacing(uv: np.ndarray) -> float:
    seen = uv[np.all(np.isfinite(uv), axis=1)]
    return float(np.median(neighbour_distance(seen))) if len(seen) > 1 else float("nan")


def _score(i: int, t: np.ndarray, uv: np.ndarray, finite: np.ndarray, alive: np.ndarray, max_dt_s: float,
           min_points: int) -> float:
    """Median over neighbour pairs of the median distance of frame i's points from the pair's prediction, in
    lattice spacings (NaN when it cannot be checked)."""
    lo = np.searchsorted(t, t[i] - 2 * max_dt_s, side="left")
    hi = np.searchsorted(t, t[i] + 2 * max_dt_s, side="right")
    before = [j for j in range(i - 1, lo - 1, -1) if alive[j]][:MAX_SIDE]
    after = [j for j in range(i + 1, hi) if alive[j]][:MAX_SIDE]
    near = [j for j in before[::-1] + after if abs(t[j] - t[i]) <= max_dt_s]
    # Up to MAX_SIDE neighbours each side within max_dt_s; a frame with fewer is checked against its two nearest
    # within twice that (a detection after a gap is the likeliest to be labelled afresh, and wrongly).
    nb = near if len(near) >= 2 else sorted(before + after, key=lambda j: abs(t[j] - t[i]))[:2]
    spacing = _spacing(uv[i])
    if not np.isfinite(spacing) or spacing <= 0:
        return float("nan")
    errs = []
    for j, k in combinations(nb, 2) if len(nb) >= 2 else ():
        both = finite[i] & finite[j] & finite[k]
        if np.count_nonzero(both) < min_points:
            continue
        a = (t[i] - t[j]) / (t[k] - t[j])
        if abs(a) > MAX_EXTRAPOLATION:  # two neighbours close together and far from the frame: noise amplified
            continue
        pred = uv[j, both] + a * (uv[k, both] - uv[j, both])
        errs.append(float(np.median(np.linalg.norm(uv[i, both] - pred, axis=1))))
    if not errs:
        errs = _bridged(i, t, uv, finite, alive, spacing, min_points)
    return float(np.median(errs)) / spacing if errs else float("nan")


#: A frame no near pair can check is checked against the nearest detections before and after it within this
#: time (s), interpolated, when the board moved less than BRIDGE_STILL_SPACINGS lattice spacings between them:
#: a slow board's isolated finds (long spans, between gaps) are where a shifted labelling went unchecked.
MAX_BRIDGE_S = 0.5
BRIDGE_STILL_SPACINGS = 1.0


def _bridged(i: int, t: np.ndarray, uv: np.ndarray, finite: np.ndarray, alive: np.ndarray, spacing: float,
             min_points: int) -> list[float]:
    j = next((j for j in range(i - 1, -1, -1) if alive[j]), None)
    k = next((k for k in range(i + 1, t.size) if alive[k]), None)
    if j is None or k is None or t[i] - t[j] > MAX_BRIDGE_S or t[k] - t[i] > MAX_BRIDGE_S:
        return []
    both = finite[i] & finite[j] & finite[k]
    if np.count_nonzero(both) < min_points:
        return []
    if float(np.median(np.linalg.norm(uv[k, both] - uv[j, both], axis=1))) > BRIDGE_STILL_SPACINGS * spacing:
        return []  # the board moved too much across the gap for a straight line to predict it
    a = (t[i] - t[j]) / (t[k] - t[j])
    pred = uv[j, both] + a * (uv[k, both] - uv[j, both])
    return [float(np.median(np.linalg.norm(uv[i, both] - pred, axis=1)))]


#: Runs of frames (stamps at most max_dt_s apart) that meet across a gap of at most this (s) are compared.
MAX_SHIFT_GAP_S = 0.5
#: ... when each run's board, carried at its own speed, moves less than this many spacings across the gap.
SHIFT_STILL_SPACINGS = 2.0
#: The runs disagree by a lattice step when their labelled circles lie more than SHIFT_LABELLED_SPACINGS apart
#: (median) and their circles, labels ignored, within SHIFT_UNLABELLED_SPACINGS of each other (median).
SHIFT_LABELLED_SPACINGS = 0.75
SHIFT_UNLABELLED_SPACINGS = 0.35


def _velocity(i: int, j: int | None, t: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """Each point's image velocity (N, 2) from frames ``i`` and ``j`` (px/s); points not seen in both move at the
    median velocity of those that are. None without a second frame, a time between them or two points seen in
    both."""
    if j is None or t[i] == t[j]:
        return None
    v = (uv[i] - uv[j]) / (t[i] - t[j])
    seen = np.all(np.isfinite(v), axis=1)
    if np.count_nonzero(seen) < 2:
        return None
    return np.where(seen[:, None], v, np.median(v[seen], axis=0))


def shifted_runs(t: np.ndarray, uv: np.ndarray, keep: np.ndarray, *, max_dt_s: float = MAX_DT_S,
                 min_points: int = 6) -> np.ndarray:
    """Mask (m,) of the frames among ``keep`` refused because their run of frames holds the board under other
    labels than the runs it is chained to across short gaps, and those have more frames (see the module's doc)."""
    t = np.asarray(t, dtype=float)
    uv = np.asarray(uv, dtype=float)
    out = np.zeros(t.size, dtype=bool)
    kept = np.flatnonzero(keep)
    if kept.size < 2:
        return out
    cut = np.flatnonzero(np.diff(t[kept]) > max_dt_s) + 1
    runs = np.split(kept, cut)
    finite = np.all(np.isfinite(uv), axis=2)
    n = uv.shape[1]
    # Each boundary between consecutive runs: None (no test), the identity (the runs agree) or the map (N,) from
    # the later run's labels to the earlier run's labels of the same circles (-1: not seen in both).
    rel = [_relation(r1, r2, t, uv, finite, min_points) for r1, r2 in zip(runs[:-1], runs[1:], strict=True)]
    start = 0
    for end in range(len(runs)):
        if end < len(rel) and rel[end] is not None:
            continue
        chain = runs[start:end + 1]
        # Each run's labels as the chain's first run's labels (-1: unknown), composed along the chain.
        perm = [np.arange(n)]
        for m in rel[start:end]:
            p = perm[-1]
            perm.append(np.where(m >= 0, p[np.maximum(m, 0)], -1))
        # Runs whose labels agree (on the circles known in both) share a class; the class with the most frames is
        # kept, the others are refused (all of them when the most frames are tied).
        reps: list[np.ndarray] = []
        cls = []
        for p in perm:
            for c, q in enumerate(reps):
                known = (p >= 0) & (q >= 0)
                if np.count_nonzero(known) >= min_points and np.mean(p[known] == q[known]) >= 0.8:
                    cls.append(c)
                    break
            else:
                cls.append(len(reps))
                reps.append(p)
        if len(reps) > 1:
            frames = np.bincount(cls, weights=[r.size for r in chain])
            best = int(np.argmax(frames))
            tied = np.count_nonzero(frames == frames[best]) > 1
            for r, c in zip(chain, cls, strict=True):
                if tied or c != best:
                    out[r] = True
        start = end + 1
    return out


def _relation(r1: np.ndarray, r2: np.ndarray, t: np.ndarray, uv: np.ndarray, finite: np.ndarray,
              min_points: int) -> np.ndarray | None:
    """How the run ``r1`` and the next run ``r2`` meet: the map (N,) from ``r2``'s labels to ``r1``'s of the same
    circles (the identity when they agree; -1 for circles not seen in both), or None when the gap cannot be tested
    (too long, neither run with a speed, a fast board, too few common circles, or the board moved across it)."""
    a, b = int(r1[-1]), int(r2[0])
    if t[b] - t[a] > MAX_SHIFT_GAP_S:
        return None
    spacing = _spacing(uv[b])
    if not np.isfinite(spacing) or spacing <= 0:
        return None
    va = _velocity(a, int(r1[-2]) if r1.size > 1 else None, t, uv)
    vb = _velocity(b, int(r2[1]) if r2.size > 1 else None, t, uv)
    if va is None and vb is None:
        return None  # a single frame on each side: nothing says how the board moved across the gap
    va = vb if va is None else va  # a run of one frame moves at its neighbour's speed
    vb = va if vb is None else vb
    tm = 0.5 * (t[a] + t[b])
    step_a, step_b = va * (tm - t[a]), vb * (tm - t[b])
    move = max(float(np.median(np.linalg.norm(step_a[finite[a]], axis=1))),
               float(np.median(np.linalg.norm(step_b[finite[b]], axis=1))))
    if move > SHIFT_STILL_SPACINGS * spacing:
        return None  # a fast board: carrying it across the gap is no test
    pa, pb = uv[a] + step_a, uv[b] + step_b
    both = finite[a] & finite[b]
    if np.count_nonzero(both) < min_points:
        return None
    labelled = float(np.median(np.linalg.norm(pa[both] - pb[both], axis=1)))
    if labelled <= SHIFT_LABELLED_SPACINGS * spacing:
        return np.arange(uv.shape[1])
    la, lb = np.flatnonzero(finite[a]), np.flatnonzero(finite[b])
    d = np.linalg.norm(pb[lb][:, None] - pa[la][None], axis=-1)
    nearest = d.min(axis=1)
    if float(np.median(nearest)) >= SHIFT_UNLABELLED_SPACINGS * spacing:
        return None  # the board itself moved (or turned) across the gap, not its labels
    m = np.full(uv.shape[1], -1)
    close = nearest < SHIFT_UNLABELLED_SPACINGS * spacing
    m[lb[close]] = la[d.argmin(axis=1)[close]]
    return m


def _spacings(uv: np.ndarray, chunk: int = 512) -> np.ndarray:
    """Median nearest-neighbour distance of each frame's points (m,), NaN for fewer than two points."""
    out = np.full(uv.shape[0], np.nan)
    for a in range(0, uv.shape[0], chunk):
        u = uv[a:a + chunk]
        d = np.sqrt(np.sum(np.square(u[:, :, None, :] - u[:, None, :, :]), axis=-1))
        n = d.shape[1]
        d[:, np.arange(n), np.arange(n)] = np.inf
        d = np.where(np.isnan(d), np.inf, d)
        nearest = d.min(axis=2)
        nearest[~np.isfinite(nearest)] = np.nan
        with np.errstate(all="ignore"):
            ok = np.count_nonzero(np.isfinite(nearest), axis=1) >= 2
            out[a:a + chunk][ok] = np.nanmedian(nearest[ok], axis=1)
    return out


def _quick_scores(t: np.ndarray, uv: np.ndarray, finite: np.ndarray, max_dt_s: float,
                  min_points: int) -> np.ndarray:
    """Each frame's distance (in spacings) from the line through its two adjacent frames, when both lie within
    ``max_dt_s``; NaN elsewhere. One numpy pass over all frames."""
    m = t.size
    out = np.full(m, np.nan)
    dt = np.diff(t)
    idx = np.where(np.r_[False, dt <= max_dt_s] & np.r_[dt <= max_dt_s, False])[0]
    if idx.size == 0:
        return out
    a = ((t[idx] - t[idx - 1]) / (t[idx + 1] - t[idx - 1]))[:, None, None]
    pred = uv[idx - 1] + a * (uv[idx + 1] - uv[idx - 1])
    both = finite[idx] & finite[idx - 1] & finite[idx + 1]
    d = np.where(both, np.linalg.norm(uv[idx] - pred, axis=-1), np.nan)
    enough = np.count_nonzero(both, axis=1) >= min_points
    spacing = _spacings(uv[idx])
    with np.errstate(all="ignore"):
        med = np.nanmedian(d[enough], axis=1)
        out[idx[enough]] = med / spacing[enough]
    return out


def inconsistent_frames(t: np.ndarray, uv: np.ndarray, *, max_dt_s: float = MAX_DT_S,
                        spacings: float = SPACINGS, min_points: int = 6) -> np.ndarray:
    """Mask (m,) of the detections ``uv`` (m, N, 2) at times ``t`` (m,, strictly increasing) that their
    neighbours refuse. The worst frame goes first and its neighbours are scored again without it, so a wrong
    frame does not take its good neighbours with it."""
    t = np.asarray(t, dtype=float)
    uv = np.asarray(uv, dtype=float)
    m = t.size
    alive = np.ones(m, dtype=bool)
    if m < 3:
        return ~alive
    finite = np.all(np.isfinite(uv), axis=2)  # (m, N)
    score = _quick_scores(t, uv, finite, max_dt_s, min_points)
    # Frames their two adjacent neighbours already agree with (well inside the threshold) need no full check.
    for i in np.where(~(score < 0.5 * spacings))[0]:
        score[i] = _score(i, t, uv, finite, alive, max_dt_s, min_points)
    while True:
        s = np.where(alive & np.isfinite(score), score, -np.inf)
        i = int(np.argmax(s))
        if not s[i] > spacings:
            break
        alive[i] = False
        lo = np.searchsorted(t, t[i] - 4 * max_dt_s, side="left")
        hi = np.searchsorted(t, t[i] + 4 * max_dt_s, side="right")
        for j in range(lo, hi):
            if alive[j]:
                score[j] = _score(j, t, uv, finite, alive, max_dt_s, min_points)
    if SHIFTED_RUNS:
        alive &= ~shifted_runs(t, uv, alive, max_dt_s=max_dt_s, min_points=min_points)
    return ~alive
