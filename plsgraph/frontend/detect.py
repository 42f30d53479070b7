"""Board detection in one image: asymmetric circle grids and Kalibr AprilGrids.

Images are 2-D arrays (any dtype). For circle grids the caller says how the circles show:
``foreground="dark"`` for intensity images (black circles on white paper), ``"bright"`` for filled
bright marks, and ``"rims"`` for event-activity images (count frames, time surfaces, the
polarity-aware surface) in which a moving circle shows only as a ring of active pixels around an
empty inside. Rims are found as the small, compact holes of the binarized activity image; the hole's
centroid is the circle centre at the middle of the window (the inside stays free of events only where
the circle covered it all the time).

A detection is only returned when its point order is verified: the image points must be the image
of the board points under one homography (after undistortion, when a camera is given) with small
residuals, and the board must be seen from its front (no mirrored labelling). A wrong order would
give a wrong pose with a good-looking fit, so it is rejected here rather than handed to PnP.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np

from ..core.board import Board
from ..core.camera import CameraModel
from ..errors import InputError

log = logging.getLogger(__name__)

# Reasons a window yields no detection; the front end counts them in track.info.
REASON_OK = "ok"
REASON_EMPTY = "empty_image"
REASON_NOT_FOUND = "grid_not_found"
REASON_ORDER = "inconsistent_order"
REASON_MIRRORED = "mirrored_order"
REASON_TOO_FEW = "too_few_points"
REASON_AMBIGUOUS = "ambiguous_labels"
REASON_TOO_SMALL = "circles_too_small_for_rims"

#: Rims are only trusted while the circles are this many pixels apart (nearest neighbours, diagonal on the
#: asymmetric grid). Closer, the circles are under ~6 px across (diameter / spacing is 0.57 on the bundled
#: boards): the thickened rims close their insides, the holes left are the gaps between circles, and a lattice
#: of those labels the board wrongly. Such boards are found as blobs of events instead.
MIN_RIM_SPACING_PX = 10.0

#: Hole-area ratio between the two parity classes of a grown lattice above which it is taken for the
#: lattice of circles and gaps (see :func:`label_circle_grid`).
FINE_LATTICE_AREA_RATIO = 1.3
#: Share of the lattice points found that must land on board circles for a labelling to be accepted.
MIN_INSIDE_FRACTION = 0.85
#: Rim thicknesses tried, in order (see _detect_rims; a caller may put the one that worked last first), and
#: whether a predicted board is looked for at every thickness before the full lattice labelling is tried at any.
RIM_THICKNESSES = (2, 3, 1)
TRACK_BEFORE_LABEL = True
#: Circles a board labelled by its predicted positions (:func:`track_circle_grid`) must show; None: half the
#: board's, as for the full lattice labelling.
TRACK_MIN_POINTS: int | None = 11
#: Candidates for the lattice labelling when the blob detector's do not give a board: the local maxima of the
#: weight image smoothed at each of these scales (pixels). A distant board's circles are 4-6 px rings of events
#: spaced 10 px apart; thresholded at the blob detector's levels, neighbouring rings merge at the low levels
#: and break into arcs at the high ones, so it finds a few of 44 clearly visible circles. Smoothed at about
#: the ring's radius, each ring is one peak. () turns the peaks off.
PEAK_SIGMAS_PX = (2.5, 1.5)
#: Whether :func:`detect_circle_grid` labels the peaks when its ``peaks`` is not given. Off: on the study
#: (docs/frontend.md, study_v17) the peaks found the board in more windows (median coverage 71 -> 76 %) but the
#: refinement ended further from the truth (rotation median 0.48 -> 0.54 deg, p95 2.3 -> 4.0 deg; no worse than
#: the closed form on 89 -> 83 % of the recordings).
PEAKS_BY_DEFAULT = False
#: A peak must reach this share of the smoothed image's 99.9th percentile. An image with more peaks than
#: PEAK_MAX_CANDIDATES is mostly noise (a board that holds still, or none in view): it is not labelled. On the
#: study's recordings the labelling found the board among up to 100 peaks and never among more, at 4-6 ms
#: against 9 ms for 300.
PEAK_FRACTION = 0.25
PEAK_MAX_CANDIDATES = 120
PEAK_REFINE_RADIUS = 0.5  # the re-centring disk, in spacings (0.35 cuts into the rings: most labellings then fail)
#: Candidates of a slowly moving, distant board's circles when the blob detector's do not give a board: the
#: strongest responses of a ring filter (a ring of the circle's radius against its inside and outside) over these
#: radii (px). Over half a second such a board's circles are thin rings of a few events per pixel, often weaker than
#: the textured background's events; thresholded, they break up (the blob detector found 7 of 44 circles in a study
#: window in which the ring filter's strongest 44 responses held 33). Labelled like any candidates (never a guessed
#: order), in the whole image, for count images of RING_MIN_SPAN windows or more (the caller's ``rings``).
RING_RADII_PX = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0)
#: How many of the strongest ring responses are labelled, in multiples of the board's circles (fewer first).
RING_CANDIDATES = (1.0, 1.5)


@dataclass(frozen=True)
class GridDetection:
    """One image's detection result.

    ``uv`` (N, 2) pixel coordinates in board-point order, NaN for unseen points (all NaN when
    ``ok`` is False); ``reason`` one of the ``REASON_*`` strings; ``homography_rms_px`` the
    residual of the order check (NaN when it was not reached); ``n_seen`` the number of finite points;
    ``rim_px`` the rim thickness of a detection on rims (``foreground="rims"``), else None.
    """

    uv: np.ndarray
    ok: bool
    reason: str
    homography_rms_px: float = float("nan")
    rim_px: int | None = None

    @property
    def n_seen(self) -> int:
        return int(np.count_nonzero(np.all(np.isfinite(self.uv), axis=1)))


def _fail(n: int, reason: str, rms: float = float("nan")) -> GridDetection:
    return GridDetection(np.full((n, 2), np.nan), False, reason, rms)


def normalize_image(image: np.ndarray, foreground: str = "bright") -> np.ndarray | None:
    """Float32 weight image in [0, 1] where the pattern's marks are bright and the paper is ~0.

    Uses robust percentiles so a few hot pixels do not compress the range; returns None for an
    image without contrast (no events in the window, a blank render).
    """
    if foreground not in ("bright", "dark"):
        raise InputError(f"detect: foreground must be 'bright', 'dark' or 'rims', got {foreground!r}")
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise InputError(f"detect: expected a single-channel 2-D image, got shape {img.shape}")
    if foreground == "dark":
        img = -img
    lo, hi = np.percentile(img, [50.0, 99.7]) if img.size else (0.0, 0.0)
    if not np.isfinite(hi - lo) or hi - lo <= 1e-9:
        hi = float(img.max(initial=0.0))
        if hi - lo <= 1e-9:
            return None
    return np.clip((img - lo) / (hi - lo), 0.0, 1.0)


@lru_cache(maxsize=16)
def _ring_kernel(radius: float) -> np.ndarray:
    """A ring of ``radius`` px (weights summing to 1) minus its inside and the annulus just outside (summing to -1)."""
    half = int(np.ceil(radius + 3.0))
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1]
    d = np.hypot(xx, yy)
    ring = (np.abs(d - radius) <= 0.75).astype(np.float32)
    around = ((d <= radius - 1.5) | ((d > radius + 1.5) & (d <= radius + 3.0))).astype(np.float32)
    k = ring / ring.sum() - around / around.sum()
    k.setflags(write=False)
    return k


#: Ring kernels up to this size are applied directly (cv2.filter2D); larger ones share one Fourier transform of the
#: image (filter2D would transform the image again for each: 2.5 ms per radius on a DAVIS346 image, against 0.3 ms
#: for the small kernels it applies directly; all seven radii 13 -> 3 ms).
RING_DIRECT_MAX = 11


@lru_cache(maxsize=8)
def _ring_spectra(shape: tuple[int, int], radii: tuple[float, ...]) -> tuple[tuple[int, int], tuple]:
    """The padded transform size for an image of ``shape`` and the spectra of the ring kernels of ``radii`` larger
    than RING_DIRECT_MAX, each centred on the origin (zero padding: a linear, not circular, filter)."""
    big = [float(r) for r in radii if _ring_kernel(float(r)).shape[0] > RING_DIRECT_MAX]
    half = max((_ring_kernel(r).shape[0] // 2 for r in big), default=0)
    size = tuple(cv2.getOptimalDFTSize(max(n + half, 2 * half + 1)) for n in shape)
    spectra = []
    for r in big:
        k = _ring_kernel(r)
        h = k.shape[0] // 2
        pad = np.zeros(size, np.float32)
        pad[: k.shape[0], : k.shape[1]] = k
        spectra.append(cv2.dft(np.roll(pad, (-h, -h), axis=(0, 1))))  # packed (CCS): a real image's half
    return size, tuple(spectra)


def ring_response(weight: np.ndarray, radii: tuple[float, ...] = RING_RADII_PX) -> np.ndarray:
    """The largest ring-filter response over ``radii`` at each pixel (float32, the image's shape). Within
    ``ring_margin(radii)`` px of the border it is 0: there the image's edge looks like a ring's outside."""
    w = np.asarray(weight, dtype=np.float32)
    m = ring_margin(radii)
    if min(w.shape) <= 2 * m:  # all of it within the margin
        return np.zeros(w.shape, np.float32)
    resp = np.full(w.shape, -np.inf, np.float32)
    for r in radii:
        k = _ring_kernel(float(r))
        if k.shape[0] <= RING_DIRECT_MAX:
            np.maximum(resp, cv2.filter2D(w, -1, k, borderType=cv2.BORDER_CONSTANT), out=resp)
    size, spectra = _ring_spectra(w.shape, tuple(float(r) for r in radii))
    if spectra:
        pad = np.zeros(size, np.float32)
        pad[: w.shape[0], : w.shape[1]] = w
        image = cv2.dft(pad)
        for spec in spectra:  # the kernels are symmetric: their correlation is their convolution
            out = cv2.idft(cv2.mulSpectrums(image, spec, 0), flags=cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT)
            np.maximum(resp, out[: w.shape[0], : w.shape[1]], out=resp)
    resp[:m], resp[-m:], resp[:, :m], resp[:, -m:] = 0.0, 0.0, 0.0, 0.0
    return resp


def ring_margin(radii: tuple[float, ...] = RING_RADII_PX) -> int:
    return int(np.ceil(max(radii) + 3.0))


def ring_peaks(resp: np.ndarray, count: int, fraction: float = 0.1, min_dist_px: float = 2.0) -> np.ndarray:
    """The ``count`` strongest local maxima (3 x 3) of a :func:`ring_response` above ``fraction`` of its largest
    value, none within ``min_dist_px`` of a stronger one: candidate centres (k, 2) of circles seen as rings of
    events, strongest first, each placed at the top of a parabola through its row and column."""
    top = float(resp.max(initial=0.0))
    if not np.isfinite(top) or top <= 0.0:
        return np.zeros((0, 2))
    local_max = cv2.dilate(resp, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero((resp >= local_max) & (resp > fraction * top))
    order = np.argsort(-resp[ys, xs], kind="stable")[: 4 * count]
    ys, xs = ys[order], xs[order]
    # The strongest of maxima closer than min_dist_px (flat tops, ties): taken strongest first, each one kept
    # suppresses the weaker ones near it. Integer pixel distances: exact.
    yi, xi = ys.astype(np.int64), xs.astype(np.int64)
    near = (yi[:, None] - yi[None, :]) ** 2 + (xi[:, None] - xi[None, :]) ** 2 < min_dist_px**2
    suppressed = np.zeros(ys.size, bool)
    keep: list[int] = []
    for i in range(ys.size):
        if not suppressed[i]:
            keep.append(i)
            if len(keep) == count:
                break
            suppressed |= near[i]
    ys, xs = ys[keep], xs[keep]
    h, w = resp.shape
    inner = (xs > 0) & (xs < w - 1) & (ys > 0) & (ys < h - 1)
    fx, fy = xs.astype(float), ys.astype(float)
    for axis, (dy, dx) in enumerate(((0, 1), (1, 0))):
        c = resp[ys[inner], xs[inner]].astype(float)
        lo = resp[ys[inner] - dy, xs[inner] - dx].astype(float)
        hi = resp[ys[inner] + dy, xs[inner] + dx].astype(float)
        curv = lo + hi - 2.0 * c
        step = np.where(curv < 0.0, 0.5 * (lo - hi) / np.where(curv < 0.0, curv, -1.0), 0.0)
        step = np.clip(step, -0.5, 0.5)
        if axis == 0:
            fx[inner] += step
        else:
            fy[inner] += step
    return np.c_[fx, fy]


#: A ring labelling is refused when the ring response at the board's gaps (each circle's position moved by one
#: square along the rows: the empty sites between the circles) reaches this share of the response at its circles.
#: The filter also answers, more weakly, between four rings; labelled, those gap sites form a lattice as regular as
#: the circles' (the board turned by 180 degrees) whose own gaps are the true circles, where the response is larger.
RING_GAP_RATIO = 0.8


def ring_gaps_weaker(resp: np.ndarray, uv: np.ndarray, board: Board) -> bool:
    """Whether the ring response at the labelled circles ``uv`` (N, 2; NaN unseen) clearly exceeds that at the
    board's gaps, mapped into the image by the labelling's homography (see RING_GAP_RATIO)."""
    seen = np.all(np.isfinite(uv), axis=1)
    if np.count_nonzero(seen) < 4:
        return False
    H, _ = cv2.findHomography(board.points[seen, :2].astype(np.float64), uv[seen].astype(np.float64), 0)
    if H is None:
        return False
    gaps = board.points[:, :2] + np.array([board.square_size, 0.0])
    g = cv2.perspectiveTransform(gaps.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)

    def at(p: np.ndarray) -> np.ndarray:
        q = np.rint(p).astype(int)
        h, w = resp.shape
        q = q[(q[:, 0] >= 1) & (q[:, 0] < w - 1) & (q[:, 1] >= 1) & (q[:, 1] < h - 1)]
        if q.shape[0] == 0:
            return np.zeros(0)
        return np.max([resp[q[:, 1] + dy, q[:, 0] + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)

    on, off = at(uv[seen]), at(g[np.all(np.isfinite(g), axis=1)])
    if on.size < 4 or off.size < 4:
        return False
    return float(_median(off)) < RING_GAP_RATIO * float(_median(on))


def blob_peaks(weight: np.ndarray, sigma_px: float, fraction: float = PEAK_FRACTION) -> np.ndarray:
    """Candidate circle centres (k, 2): the local maxima (3 x 3) of ``weight`` smoothed by a Gaussian of
    ``sigma_px`` that reach ``fraction`` of the smoothed image's 99.9th percentile, strongest first.
    Whole-pixel positions; the caller re-centres them."""
    smooth = cv2.GaussianBlur(np.asarray(weight, dtype=np.float32), (0, 0), float(sigma_px))
    top = float(np.percentile(smooth, 99.9)) if smooth.size else 0.0
    if not np.isfinite(top) or top <= 0.0:
        return np.zeros((0, 2))
    local_max = cv2.dilate(smooth, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero((smooth >= local_max) & (smooth > fraction * top))
    order = np.argsort(-smooth[ys, xs], kind="stable")
    return np.c_[xs[order], ys[order]].astype(float)


def _blob_detector(image_shape: tuple[int, int], blob_color: int) -> cv2.SimpleBlobDetector:
    """A SimpleBlobDetector for small, possibly smeared and noisy circles on a DAVIS-sized sensor."""
    p = cv2.SimpleBlobDetector_Params()
    p.blobColor = blob_color
    p.filterByColor = True
    p.minThreshold, p.maxThreshold, p.thresholdStep = 40, 220, 30
    p.minRepeatability = 2
    # Neighbouring circles of a distant board are only a few pixels apart.
    p.minDistBetweenBlobs = 2.0
    p.filterByArea = True
    p.minArea = 3.0
    p.maxArea = max(p.minArea, 0.05 * image_shape[0] * image_shape[1])  # tiny images: OpenCV wants min <= max
    p.filterByCircularity = False  # motion smears circles into ellipses and crescents
    p.filterByConvexity = True
    p.minConvexity = 0.6
    p.filterByInertia = True
    p.minInertiaRatio = 0.15
    return cv2.SimpleBlobDetector_create(p)


def _norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norms along the last axis: what np.linalg.norm(x, axis=-1) computes (the same sum of squares and
    root, the same numbers), without its argument handling, which costs more than the sum on these small arrays."""
    return np.sqrt(np.add.reduce(x * x, axis=-1))


def _homog(p: np.ndarray) -> np.ndarray:
    """np.c_[p, np.ones(len(p))] as float64: the points (n, 2) with a column of ones (without np.c_'s parsing)."""
    out = np.empty((p.shape[0], 3))
    out[:, :2] = p
    out[:, 2] = 1.0
    return out


def _median(x: np.ndarray, axis: int | None = None):
    """np.median(x) (``axis=None``, any shape) or np.median(x, axis=0) (2-D): the same numbers (the middle element, or
    the mean of the two middle ones: (a + b) / 2 as np.median's mean computes it; NaN where a NaN is among them) from
    a sort, without np.median's argument handling, which costs several times the sort on these arrays of a few
    dozen values. Empty input gives NaN (without np.median's warning)."""
    a = np.sort(np.asarray(x, dtype=np.float64).ravel() if axis is None else np.asarray(x, dtype=np.float64), axis=0)
    n = a.shape[0]
    if n == 0:
        return np.nan if axis is None else np.full(a.shape[1:], np.nan)
    m = n // 2
    mid = a[m] if n % 2 else (a[m - 1] + a[m]) / 2.0
    nan = np.isnan(a[-1])  # NaNs sort last
    if axis is None:
        return np.float64(np.nan) if nan else mid
    return np.where(nan, np.nan, mid)


def _fit_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """Homography dst ~ H src by the normalised DLT (no iterative refinement); None if degenerate.

    Used while growing the lattice, where it runs several times per image: several times cheaper than
    cv2.findHomography there, and the final order check still uses OpenCV's.
    """
    def frame(p: np.ndarray) -> np.ndarray:
        # p.mean(axis=0) and np.mean(...): the same sums and division, without np.mean's argument handling
        c = np.add.reduce(p, axis=0) / p.shape[0]
        d = float(np.add.reduce(_norm(p - c)) / p.shape[0])
        k = np.sqrt(2.0) / d if d > 1e-12 else 1.0
        return np.array([[k, 0.0, -k * c[0]], [0.0, k, -k * c[1]], [0.0, 0.0, 1.0]])

    Ts, Td = frame(src), frame(dst)
    a = src @ Ts[:2, :2].T + Ts[:2, 2]
    b = dst @ Td[:2, :2].T + Td[:2, 2]
    m = a.shape[0]
    A = np.zeros((2 * m, 9))
    A[0::2, 0:2], A[0::2, 2] = a, 1.0
    A[0::2, 6:8], A[0::2, 8] = -b[:, :1] * a, -b[:, 0]
    A[1::2, 3:5], A[1::2, 5] = a, 1.0
    A[1::2, 6:8], A[1::2, 8] = -b[:, 1:] * a, -b[:, 1]
    # Null vector from the 9 x 9 normal matrix (well conditioned after the normalisation; cheaper than an
    # SVD of the 2n x 9 design matrix).
    w, V = np.linalg.eigh(A.T @ A)
    if w[1] < 1e-12 * w[-1]:
        return None
    H = np.linalg.solve(Td, V[:, 0].reshape(3, 3) @ Ts)
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else None


def neighbour_distance(uv: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest other point (n,)."""
    d = _norm(uv[:, None, :] - uv[None, :, :])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1)


def refine_centroids(weight: np.ndarray, uv: np.ndarray, radius: np.ndarray, iterations: int = 4,
                     image: np.ndarray | None = None, support: bool = False):
    """Weighted centroids of ``weight`` in disks of ``radius`` (n,) around ``uv`` (n, 2), iterated.

    A filled circle and a symmetric rim both have their centroid at the centre; each iteration
    re-centres the disk (mean shift), which converges in a few steps. Pixels are sampled at their
    centres (pixel (x, y) covers [x - 0.5, x + 0.5]), OpenCV's convention. Points whose disk holds
    no weight keep their input position. ``weight`` may be a stack of images (k, h, w), ``image`` (n,)
    then says which one each point's centroid is taken on (several images in one pass). With ``support`` also
    the weight in each point's disk at its input position (n,), as :func:`_disk_weight` gives it.
    """
    uv = np.asarray(uv, dtype=float).copy()
    radius = np.asarray(radius, dtype=float)
    stack = weight if weight.ndim == 3 else weight[None]
    which = np.zeros(len(uv), dtype=np.intp) if image is None else np.asarray(image, dtype=np.intp)
    h, w = stack.shape[1:]
    R = int(np.ceil(radius.max())) + 1
    # A border of R zero pixels: a disk reaching past the image's edge reads zeros there, with no test per pixel. A
    # point outside the image has its disk laid around the nearest edge pixel: the part of its disk within R of that
    # pixel is read, and the part beyond lies outside the image (zeros) anyway.
    padded = np.zeros((stack.shape[0], h + 2 * R, w + 2 * R), dtype=np.float32)
    padded[:, R:R + h, R:R + w] = stack
    flat = padded.reshape(-1)
    hp, wp = h + 2 * R, w + 2 * R
    off = np.arange(-R, R + 1)
    dy, dx = np.meshgrid(off, off, indexing="ij")
    dxi, dyi = dx.ravel(), dy.ravel()
    # Only the offsets a disk can reach: a point lies within half a pixel on each axis of the pixel its disk is laid
    # around (outside the image, its disk's part inside lies closer to the edge pixel than its radius).
    reach = dxi**2 + dyi**2 <= (float(radius.max()) + np.sqrt(0.5)) ** 2
    dxi, dyi = dxi[reach], dyi[reach]
    dx, dy = dxi.astype(np.float32), dyi.astype(np.float32)
    r_sq = (radius**2).astype(np.float32)[:, None]
    base = (which * (hp * wp))[:, None] + (R * wp + R) + (dyi * wp + dxi)[None, :]
    first = None
    moving = np.ones(len(uv), dtype=bool)  # points of an image whose centroids have not all settled yet
    for _ in range(max(iterations, 1 if support else 0)):
        # The pixel each disk is laid around, inside the image (a NaN point's disk, at NaN from it, reads nothing).
        ci = np.clip(np.where(np.isfinite(uv), np.round(uv), 0.0), 0.0, [w - 1, h - 1]).astype(np.intp)
        f = np.clip(uv - ci, -1e6, 1e6).astype(np.float32)  # the point relative to the pixel its disk is laid around
        disk = (dx[None, :] - f[:, :1]) ** 2 + (dy[None, :] - f[:, 1:]) ** 2 <= r_sq
        wt = flat[base + (ci[:, 1] * wp + ci[:, 0])[:, None]] * disk
        s = wt.sum(axis=1, dtype=np.float64)
        if first is None:
            first = s
            if iterations == 0:
                break
        good = s > 1e-9
        new = ci + np.stack([wt @ dx, wt @ dy], axis=-1).astype(np.float64) / np.where(good, s, 1.0)[:, None]
        step = np.where((good & moving)[:, None], new - uv, 0.0)
        uv += step
        # Each image's points stop together once all of them moved by less than 1e-3 px (as one call per image).
        big = np.abs(step).max(axis=1, initial=0.0) >= 1e-3
        if not big.any():
            break
        if image is not None:
            moving &= np.isin(which, which[big])
    if support:
        return uv, (first if first is not None else np.zeros(len(uv)))
    return uv


def polarity_centroids(on: np.ndarray, off: np.ndarray, uv: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Circle centres from the ON and the OFF events apart: the mean of the two polarities' centroids
    (:func:`refine_centroids` on each, from ``uv``), each polarity weighed equally.

    A dark circle moving over a light board fires OFF events along its leading edge and ON events along its trailing
    edge, so each polarity's events are centred off the circle, by as much ahead as the other's behind. Their plain
    count centres the blob towards whichever polarity fired more there, and how many more varies from circle to
    circle (thresholds, the circle's contrast against what it passes over, its speed). A point where either polarity
    has no events in its disk keeps the both-polarity centroid of ``on + off``, and so does one whose polarities'
    mean lies more than half the disk's radius from it (a polarity's centroid drawn to a neighbouring circle's edge
    on a span that smears the circles into each other)."""
    uv = np.asarray(uv, dtype=float)
    radius = np.asarray(radius, dtype=float)
    both = refine_centroids(on + off, uv, radius)
    out = _polarity_mean(on, off, both, radius)
    keep = (_disk_weight(on, both, radius) <= 0.0) | (_disk_weight(off, both, radius) <= 0.0)
    keep |= np.linalg.norm(out - both, axis=1) > 0.5 * radius
    out[keep] = both[keep]
    return out


def _polarity_mean(on: np.ndarray, off: np.ndarray, uv: np.ndarray, radius: np.ndarray, support: bool = False,
                   iterations: int = 4):
    """The mean of the ON and the OFF image's centroids (:func:`refine_centroids`), each iterated from ``uv``; with
    ``support`` also whether each point's disk at ``uv`` lacks one polarity's weight (n,) bool."""
    n = len(uv)
    c, s = refine_centroids(np.stack([on, off]), np.concatenate([uv, uv]), np.concatenate([radius, radius]),
                            iterations=iterations, image=np.repeat([0, 1], n), support=True)
    mean = 0.5 * (c[:n] + c[n:])
    if support:
        return mean, (s[:n] <= 0.0) | (s[n:] <= 0.0)
    return mean


def _disk_weight(weight: np.ndarray, uv: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The sum of ``weight`` in disks of ``radius`` around ``uv`` (pixel centres, as refine_centroids samples)."""
    h, w = weight.shape
    R = int(np.ceil(np.max(radius, initial=0.0))) + 1
    off = np.arange(-R, R + 1)
    dy, dx = np.meshgrid(off, off, indexing="ij")
    cx, cy = (np.where(np.isfinite(a), np.round(a), 0.0).astype(int) for a in (uv[:, 0], uv[:, 1]))
    px = cx[:, None] + dx.ravel()[None, :]
    py = cy[:, None] + dy.ravel()[None, :]
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    r2 = (px - uv[:, :1]) ** 2 + (py - uv[:, 1:]) ** 2
    return np.where(inside & (r2 <= np.asarray(radius)[:, None] ** 2),
                    weight[np.clip(py, 0, h - 1), np.clip(px, 0, w - 1)], 0.0).sum(axis=1)


def check_grid_order(
    uv: np.ndarray,
    board: Board,
    camera: CameraModel | None = None,
    *,
    max_rms_px: float = 1.0,
    max_point_frac: float = 0.3,
) -> tuple[str, float]:
    """Verify that ``uv`` (N, 2; NaN allowed) lists the board points in the board's order.

    Fits a homography from board (x, y) to the image points (undistorted with ``camera`` when
    given, in pixel units via fx), and rejects when the RMS residual exceeds ``max_rms_px`` or any
    point is off by more than ``max_point_frac`` of its nearest-neighbour spacing (a swap of two
    neighbours moves each by a whole spacing while barely changing the RMS of a large board).
    Also rejects a mirrored labelling: seen from the front, the board's (x, y) orientation in the
    image is fixed by its convention (circle grids: x right, y down as printed; AprilGrids: y up).
    Returns (reason, rms_px) with reason :data:`REASON_OK` when the order is consistent.
    """
    seen = np.all(np.isfinite(uv), axis=1)
    if np.count_nonzero(seen) < 4:
        return REASON_TOO_FEW, float("nan")
    q = uv[seen]
    scale = 1.0
    if camera is not None:
        q = camera.undistort_pixels(q)
        scale = camera.fx
        q = q * scale
    P = board.points[seen, :2]
    H, _ = cv2.findHomography(P, q, 0)
    if H is None or not np.all(np.isfinite(H)):
        return REASON_ORDER, float("nan")
    ph = _homog(P) @ H.T
    if np.any(ph[:, 2] * np.sign(_median(ph[:, 2])) <= 0):
        return REASON_ORDER, float("nan")
    pred = ph[:, :2] / ph[:, 2:]
    err = _norm(pred - q)
    rms = float(np.sqrt(np.add.reduce(err**2) / err.shape[0]))  # np.mean's numbers
    spacing = neighbour_distance(pred) if len(pred) > 1 else np.full(1, np.inf)
    if rms > max_rms_px or np.any(err > max_point_frac * spacing):
        return REASON_ORDER, rms
    # Orientation: sign of the Jacobian determinant of the homography at the board centroid.
    c = P.mean(axis=0)
    x, y, wgt = H @ np.array([c[0], c[1], 1.0])
    J = (H[:2, :2] * wgt - np.outer([x, y], H[2, :2])) / wgt**2
    front = 1.0 if board.pattern == "asymmetric_circles" else -1.0
    if np.sign(np.linalg.det(J)) != front:
        return REASON_MIRRORED, rms
    return REASON_OK, rms


def board_is_symmetric(board: Board) -> bool:
    """True when a 180-degree turn maps the board's point set onto itself with a different labelling.

    Such a board (an asymmetric circle grid with an even number of rows) cannot be told from its
    turned self in a single image; the front end must resolve it from continuity.
    """
    P = board.points[:, :2]
    turned = P.min(axis=0) + P.max(axis=0) - P
    d = _norm(turned[:, None, :] - P[None, :, :])
    return bool(np.all(d.min(axis=1) < 1e-9 * max(1.0, float(np.ptp(P)))))


def rim_holes(active: np.ndarray, min_area: int = 2, max_area_frac: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (k, 2) and areas (k,) of the compact holes of a binary activity image.

    A hole is a 4-connected component of inactive pixels (never the active pixels themselves, however compact
    they are) that does not touch the image border, is no larger than ``max_area_frac`` of the image, fills at
    least 60 % of its bounding ellipse and is not elongated beyond 4 : 1 (a ring's inside seen obliquely or
    smeared by motion stays compact).
    """
    h, w = active.shape
    n, _, stats, cent = cv2.connectedComponentsWithStats((~active).astype(np.uint8), connectivity=4)
    x, y, bw, bh, area = stats.T
    fill = area / (0.25 * np.pi * np.maximum(bw * bh, 1))
    ok = (
        (area >= min_area)
        & (area <= max_area_frac * h * w)
        & (x > 0)
        & (y > 0)
        & (x + bw < w)
        & (y + bh < h)
        & (fill > 0.6)
        & (np.maximum(bw, bh) <= 4 * np.minimum(bw, bh))
    )
    ok[0] = False  # label 0 is the active pixels themselves, never a hole
    return cent[ok].astype(float), area[ok].astype(float)


@lru_cache(maxsize=16)
def board_lattice(board: Board) -> np.ndarray:
    """Integer lattice coordinates (N, 2) of an asymmetric circle grid's points.

    The circles sit at (x, y) = ((2 j + i mod 2) s, i s): exactly the points with x + y even (in
    units of s), a square lattice turned by 45 degrees with basis (s, s) and (s, -s). Coordinates
    (a, b) = ((x + y) / 2, (x - y) / 2) number it; only the board's outline is asymmetric.
    """
    q = np.round(board.points[:, :2] / board.square_size).astype(int)
    lat = np.stack([(q[:, 0] + q[:, 1]) // 2, (q[:, 0] - q[:, 1]) // 2], axis=-1)
    lat.setflags(write=False)  # cached: shared between calls
    return lat


_LATTICE_MAPS = np.array(
    [[[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]], [[0, 1], [-1, 0]],
     [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[-1, 0], [0, 1]], [[0, -1], [-1, 0]]]
)  # the 8 symmetries of the square lattice (4 turns, 4 reflections)


def _grow_lattice(pts: np.ndarray, seed: int, nn: np.ndarray, tol: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Integer lattice coordinates for the points reachable from ``seed``: (indices, coords)."""
    d = pts - pts[seed]
    dist = _norm(d)
    near = np.flatnonzero((dist > 0) & (dist < 1.35 * nn[seed]))
    if near.size < 2:
        return np.zeros(0, int), np.zeros((0, 2), int)
    e1 = d[near[np.argmin(dist[near])]]
    cosang = np.abs(d[near] @ e1) / (dist[near] * np.linalg.norm(e1))
    if cosang.min() > 0.5:
        return np.zeros(0, int), np.zeros((0, 2), int)
    e2 = d[near[np.argmin(cosang)]]
    # Homography lattice -> image, started as the affine map of the seed's neighbourhood and re-fitted
    # while the accepted region grows ring by ring (perspective bends the lattice far from the seed).
    H = np.array([[e1[0], e2[0], pts[seed, 0]], [e1[1], e2[1], pts[seed, 1]], [0.0, 0.0, 1.0]])
    idx = np.zeros(0, int)
    lat = np.zeros((0, 2), int)
    radius = 1
    pts_h = _homog(pts)
    for _ in range(40):
        try:
            Hinv = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            break
        ph = pts_h @ Hinv.T
        if np.any(np.abs(ph[:, 2]) < 1e-12):
            break
        lc = ph[:, :2] / ph[:, 2:]
        a = np.round(lc).astype(int)
        res = _norm(lc - a)
        ok = (res < tol) & (np.max(np.abs(a), axis=1) <= radius)
        cand = np.flatnonzero(ok)
        # One point per lattice site: the best-fitting one (sites keyed as one integer, |a| <= radius).
        order = cand[np.argsort(res[cand])]
        key = (a[order, 0] + radius) * (2 * radius + 1) + (a[order, 1] + radius)
        # np.unique(key, return_index=True)[1], as it computes it (a stable sort, the first of each run of equal keys)
        perm = np.argsort(key, kind="mergesort")
        aux = key[perm]
        first = perm[np.concatenate(([True], aux[1:] != aux[:-1]))] if key.size else perm
        new_idx = np.sort(order[first])
        grown = new_idx.size > idx.size
        idx, lat = new_idx, a[new_idx]
        if not grown and radius >= 3:
            break  # (the homography is not used after the loop: no refit)
        if idx.size >= 4:
            Hn = _fit_homography(lat.astype(np.float64), pts[idx])
            if Hn is None:
                break
            H = Hn
        radius = radius + 1 if radius < 2 else 2 * radius  # 1, 2, 4, 8, ...: few refits
    return idx, lat


def label_circle_grid(
    points: np.ndarray,
    board: Board,
    camera: CameraModel | None = None,
    *,
    areas: np.ndarray | None = None,
    min_points: int | None = None,
    max_rms_px: float = 1.0,
) -> GridDetection:
    """Label candidate centres ``points`` (k, 2; clutter allowed, circles may be missing) with board points.

    The candidates are organised into the square lattice of the grid by growing a lattice homography
    from several seeds; the lattice region found is then placed on the board's lattice by the one
    lattice symmetry and shift that puts most of its points on board circles. The placement must be
    unique: when the points seen do not span the board far enough to tell (e.g. a shift by one circle
    fits as well), the detection is rejected as ambiguous rather than returned with a guessed order.
    At least ``min_points`` (default max(6, N / 2)) circles must be labelled, and the result must pass
    :func:`check_grid_order` (one homography, seen from the front). ``areas`` (k,), the sizes of the
    candidates, let it recognise a lattice of circles and the gaps between them (see the code).
    """
    n = board.n_points
    min_points = max(6, n // 2) if min_points is None else int(min_points)
    pts = np.asarray(points, dtype=float)
    if pts.shape[0] < min_points:
        return _fail(n, REASON_NOT_FOUND)
    dm = _norm(pts[:, None] - pts[None])
    np.fill_diagonal(dm, np.inf)
    nn = dm.min(axis=1)
    # Seeds: points with at least 3 neighbours at about their nearest distance (inside the grid).
    n_close = np.count_nonzero(dm < 1.35 * nn[:, None], axis=1)
    seeds = np.flatnonzero(n_close >= 3)
    if seeds.size == 0:
        return _fail(n, REASON_NOT_FOUND)
    centre = _median(pts[seeds], axis=0)
    seeds = seeds[np.argsort(_norm(pts[seeds] - centre))][:6]
    best_idx, best_lat = np.zeros(0, int), np.zeros((0, 2), int)
    for sd in seeds:
        if (best_idx == sd).any():  # growing from a point of the best lattice would find it again
            continue
        idx, lat = _grow_lattice(pts, int(sd), nn)
        if idx.size > best_idx.size:
            best_idx, best_lat = idx, lat
        if best_idx.size >= n or best_idx.size >= 0.8 * pts.shape[0]:
            break  # all circles, or most candidates, already on one lattice
    if best_idx.size < min_points:
        return _fail(n, REASON_NOT_FOUND)
    if areas is not None:
        # Touching rims also enclose the gaps between circles; circles and gaps together form a lattice
        # twice as dense (axis-aligned on the board) in which the circles are the sites of one parity and
        # clearly larger (for the bundled board about 2 to 4 times the area). Labelling that lattice as
        # circles would give a wrong order that still fits a homography, so decide which lattice was grown.
        par = (best_lat.sum(axis=1) % 2).astype(bool)
        a = np.asarray(areas, dtype=float)[best_idx]
        if np.count_nonzero(par) >= 3 and np.count_nonzero(~par) >= 3:
            m_odd, m_even = float(_median(a[par])), float(_median(a[~par]))
            if max(m_odd, m_even) > FINE_LATTICE_AREA_RATIO * min(m_odd, m_even):
                circ = par if m_odd > m_even else ~par
                q = best_lat[circ] - (np.array([1, 0]) if m_odd > m_even else 0)  # circles to even sites
                best_idx = best_idx[circ]
                best_lat = np.stack([(q[:, 0] + q[:, 1]) // 2, (q[:, 0] - q[:, 1]) // 2], axis=-1)
                if best_idx.size < min_points:
                    return _fail(n, REASON_TOO_FEW)
    B = board_lattice(board)
    bmin = B.min(axis=0)
    span = B.max(axis=0) - bmin + 1
    occupied = np.full(tuple(span), -1, dtype=int)
    occupied[tuple((B - bmin).T)] = np.arange(n)
    if MIN_INSIDE_FRACTION * best_idx.size > n:
        # More lattice points than the board has circles could ever hold (see below): clutter or the denser
        # lattice of circles and gaps. Decided before scoring any placement.
        return _fail(n, REASON_ORDER)
    # Score every lattice symmetry and every shift: the number of seen points that land on board circles under
    # a shift s is the number of (seen point d, board circle b) pairs with b - d = s, counted over all pairs at
    # once (the cross-correlation of the two occupancy images, without the images).
    scored = []  # (shifts (k, 2), hits (k,)), per lattice map
    for M in _LATTICE_MAPS:
        D = best_lat @ M.T
        S = (B[None, :, :] - D[:, None, :]).reshape(-1, 2)
        lo = S.min(axis=0)
        width = int(S[:, 1].max() - lo[1]) + 1
        code = (S[:, 0] - lo[0]) * width + (S[:, 1] - lo[1])
        hits = np.bincount(code)
        nz = np.flatnonzero(hits)
        scored.append((np.stack([nz // width + lo[0], nz % width + lo[1]], axis=-1), hits[nz]))
    top = max(int(h.max()) for _, h in scored)
    placements = [(top, k, sh) for k, (shifts, h) in enumerate(scored) for sh in shifts[h == top]]
    if top < min_points:
        return _fail(n, REASON_TOO_FEW)
    if top < MIN_INSIDE_FRACTION * best_idx.size:
        # The grown lattice does not fit on the board: most likely the denser lattice of circles and the
        # gaps between them (or a repetitive background) taken for the circles. Never label it.
        return _fail(n, REASON_ORDER)
    # Seen from the board's front the image keeps the board's orientation, so only lattice maps of one
    # handedness can be right: that of the affine fit lattice -> image combined with the board's own
    # lattice (board (x, y) -> (a, b) has determinant -1/2). The lattice placements that agree in
    # orientation all fit one homography equally well; more than one means the order is ambiguous.
    A, *_ = np.linalg.lstsq(_homog(best_lat), pts[best_idx], rcond=None)
    want = -np.sign(np.linalg.det(A[:2].T))
    front = [(k, sh) for c, k, sh in placements if c == top and round(np.linalg.det(_LATTICE_MAPS[k])) == want]
    if not front:
        return _fail(n, REASON_MIRRORED)
    if len(front) > 1:
        return _fail(n, REASON_AMBIGUOUS)
    k, sh = front[0]
    cells = best_lat @ _LATTICE_MAPS[k].T + sh - bmin
    inside = np.all((cells >= 0) & (cells < span), axis=-1)
    lab = np.full(cells.shape[0], -1)
    lab[inside] = occupied[cells[inside, 0], cells[inside, 1]]
    uv = np.full((n, 2), np.nan)
    uv[lab[lab >= 0]] = pts[best_idx[lab >= 0]]
    reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_rms_px)
    if reason != REASON_OK:
        return _fail(n, reason, rms)
    return GridDetection(uv, True, REASON_OK, rms)


def detect_circle_grid(
    image: np.ndarray,
    board: Board,
    camera: CameraModel | None = None,
    *,
    foreground: str = "bright",
    blur_sigma: float = 0.0,
    refine: bool = True,
    max_homography_rms_px: float = 1.0,
    exhaustive: bool = False,
    rim_threshold: float = 0.0,
    min_points: int | None = None,
    roi: tuple[int, int, int, int] | None = None,
    predicted_uv: np.ndarray | None = None,
    lattice_fallback: bool = True,
    peaks: bool | None = None,
    rings: bool = False,
    rim_first: int | None = None,
    polarity_images: tuple[np.ndarray, np.ndarray] | None = None,
) -> GridDetection:
    """Find an asymmetric circle grid and return its centres in ``board.points`` order.

    Candidate blobs come from OpenCV's SimpleBlobDetector on the (optionally smoothed) weight
    image and are ordered by ``cv2.findCirclesGrid``, first with its fast clustering grid finder,
    then with the slower default one. With ``exhaustive`` the inside of rims (dark blobs) is tried
    as well. With ``refine`` each centre becomes the weighted centroid of the weight image in a
    disk of half the distance to its nearest neighbour (a rim, even smeared by motion, is centred
    on the circle). The order check of :func:`check_grid_order` decides what is returned. When
    OpenCV's finder fails (it needs every circle), the blobs are labelled by :func:`label_circle_grid`,
    which accepts a partly visible board (unseen points NaN, at least ``min_points`` seen);
    ``lattice_fallback=False`` keeps OpenCV's finder alone (for comparisons). When both fail, the local
    maxima of the smoothed weight image (:func:`blob_peaks`, scales :data:`PEAK_SIGMAS_PX`) are labelled the
    same way: small ringed circles the blob detector misses are one peak each (``peaks``; default
    :data:`PEAKS_BY_DEFAULT`). With ``rings``, before the peaks, the strongest responses of a ring filter
    (:func:`ring_response`, :func:`ring_peaks`): circles seen as thin rings of events, of a slow, distant board.

    ``foreground="rims"`` (event-activity images): pixels above ``rim_threshold`` are active; the
    circle centres are the centroids of the holes inside the rims (:func:`rim_holes`). Between
    touching rims there are smaller holes too, so only holes at least 0.4 times as large as the
    typical large hole are kept before they are labelled (:func:`label_circle_grid`, which allows
    missing circles: unseen points are NaN, at least ``min_points`` must be found). ``roi`` (x0, y0,
    x1, y1) restricts the rim search to that part of the image (coordinates stay full-image ones).
    ``predicted_uv`` (N, 2), where the circles are expected (e.g. extrapolated from the previous
    windows), lets :func:`track_circle_grid` label the candidates (rim holes, or the blob detector's blobs) by it
    before the full search. ``rim_first``: the rim thickness tried first (the one that worked in the previous
    window: a board's circles change size slowly), then the others of :data:`RIM_THICKNESSES` in order.
    ``polarity_images`` (the ON and the OFF events' count images behind ``image``): with ``refine``, the blobs' centres
    are the mean of the two polarities' centroids (:func:`polarity_centroids`), not the centroid of ``image``.
    """
    if board.pattern != "asymmetric_circles":
        raise InputError(f"detect_circle_grid: board {board.name!r} is a {board.pattern}, not asymmetric_circles")
    n = board.n_points
    if foreground == "rims":
        order = RIM_THICKNESSES
        if rim_first in RIM_THICKNESSES:
            order = (rim_first, *(k for k in RIM_THICKNESSES if k != rim_first))
        return _detect_rims(
            np.asarray(image), board, camera, rim_threshold, max_homography_rms_px, min_points, roi, predicted_uv,
            order,
        )
    weight = normalize_image(image, foreground)
    if weight is None:
        return _fail(n, REASON_EMPTY)
    smooth = cv2.GaussianBlur(weight, (0, 0), blur_sigma) if blur_sigma > 0 else weight
    recentre = refine_centroids
    if polarity_images is not None:
        on, off = (np.asarray(x, dtype=np.float32) for x in polarity_images)
        if on.shape != weight.shape or off.shape != weight.shape:
            raise InputError("detect_circle_grid: polarity_images must have the image's shape")
        if blur_sigma > 0:
            on, off = cv2.GaussianBlur(on, (0, 0), blur_sigma), cv2.GaussianBlur(off, (0, 0), blur_sigma)

        def recentre(_weight, uv, radius):
            return polarity_centroids(on, off, uv, radius)
    img8 = np.clip(smooth * (255.0 / max(float(smooth.max()), 1e-6)), 0, 255).astype(np.uint8)
    # The blobs once: OpenCV's grid finders need every circle among them, the lattice labelling at least six.
    kp = _blob_detector(img8.shape, 255).detect(img8)
    attempts = ([(255, True), (255, False)] if len(kp) >= n else []) + (
        [(0, True), (0, False)] if exhaustive else [])
    last_reason, last_rms = REASON_NOT_FOUND, float("nan")
    tried: set[tuple] = set()
    for blob_color, clustering in attempts:
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID | (cv2.CALIB_CB_CLUSTERING if clustering else 0)
        found, centres = cv2.findCirclesGrid(
            img8, board.pattern_size, flags=flags, blobDetector=_blob_detector(img8.shape, blob_color)
        )
        if not found or centres is None:
            continue
        uv = centres.reshape(-1, 2).astype(float)
        key = tuple(np.round(uv[[0, -1]].ravel(), 1))
        if key in tried:  # the other grid finder returned the same grid; its verdict stands
            continue
        tried.add(key)
        if refine:
            uv = (recentre if blob_color == 255 else refine_centroids)(weight if blob_color == 255 else smooth, uv,
                                                                         0.5 * neighbour_distance(uv))
        reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_homography_rms_px)
        if reason == REASON_OK:
            return GridDetection(uv, True, REASON_OK, rms)
        last_reason, last_rms = reason, rms
        log.debug("circle grid rejected (%s, homography rms %.2f px)", reason, rms)
    # OpenCV's grid finder needs every circle. For a board partly out of view (or partly hidden) label the
    # blobs with the lattice method instead, which allows missing circles but never guesses an order; a board
    # predicted from its last find labels them by that prediction first (tracking: no shifted grid may explain
    # them as well).
    if lattice_fallback and len(kp) >= 6:
        pts = np.array([k.pt for k in kp], dtype=float)
        det = _fail(n, REASON_NOT_FOUND)
        if predicted_uv is not None:
            det = track_circle_grid(pts, predicted_uv, board, camera, max_rms_px=max_homography_rms_px,
                                    min_points=TRACK_MIN_POINTS)
        if not det.ok:
            det = label_circle_grid(pts, board, camera, min_points=min_points, max_rms_px=max_homography_rms_px)
        if det.ok:
            uv = det.uv
            if refine:
                seen = np.all(np.isfinite(uv), axis=1)
                uv = uv.copy()
                uv[seen] = recentre(weight, uv[seen], 0.5 * neighbour_distance(uv[seen]))
            reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_homography_rms_px)
            if reason == REASON_OK:
                return GridDetection(uv, True, REASON_OK, rms)
            # The refined centres no longer fit: that is why (not the labelling's own verdict, which was ok).
            last_reason, last_rms = reason, rms
        elif last_reason == REASON_NOT_FOUND:
            last_reason = det.reason
    # Circles seen as thin rings (a slow, distant board over a long span): the ring filter's strongest responses.
    resp = ring_response(weight) if (lattice_fallback and rings) else None
    for share in RING_CANDIDATES if resp is not None else ():
        want = int(round(share * n))
        pts = ring_peaks(resp, want)
        if pts.shape[0] < 6:
            break
        # Labelled from scratch (half the board at least, a unique placement, the order check), never by a
        # prediction: the strongest responses alone hide the weak candidates the tracker's shift test looks at.
        det = label_circle_grid(pts, board, camera, min_points=min_points, max_rms_px=max_homography_rms_px)
        if det.ok and not ring_gaps_weaker(resp, det.uv, board):
            det = _fail(n, REASON_ORDER)  # the gaps between the circles answer as strongly: not certain
        if det.ok:
            # The ring filter's sub-pixel peaks are the centres: re-centring on the events would pull them towards
            # the background's events inside the disk.
            return det
        last_reason, last_rms = det.reason, det.homography_rms_px
        if pts.shape[0] < want:
            break  # no more candidates to add
    # Neither found the board among the blob detector's blobs: label the smoothed image's peaks instead.
    if peaks is None:
        peaks = PEAKS_BY_DEFAULT
    for sigma in PEAK_SIGMAS_PX if (lattice_fallback and peaks) else ():
        pts = blob_peaks(weight, sigma)
        if not 6 <= pts.shape[0] <= PEAK_MAX_CANDIDATES:
            continue
        det = label_circle_grid(pts, board, camera, min_points=min_points, max_rms_px=max_homography_rms_px)
        if not det.ok:
            continue
        uv = det.uv.copy()
        seen = np.all(np.isfinite(uv), axis=1)
        if refine:
            uv[seen] = recentre(weight, uv[seen], PEAK_REFINE_RADIUS * neighbour_distance(uv[seen]))
        reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_homography_rms_px)
        if reason == REASON_OK:
            return GridDetection(uv, True, REASON_OK, rms)
        last_reason, last_rms = reason, rms
    return _fail(n, last_reason, last_rms)


_STEPS = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]


@lru_cache(maxsize=16)
def _shift_tables(board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the lattice shifts s of one and two steps (S = 16): ``stays`` (S, N), which board circles still
    land on a circle after the shift; ``beyond`` (M, 2), the board-plane positions of the lattice sites just
    outside the board that a labelling shifted by -s would claim, and ``which`` (M,) their shift index."""
    B = board_lattice(board)
    key = set(map(tuple, B.tolist()))
    stays, beyond, which = [], [], []
    for k, (da, db) in enumerate(_STEPS + [(2 * a, 2 * b) for a, b in _STEPS]):
        stays.append([(a + da, b + db) in key for a, b in B.tolist()])
        sites = sorted({(a - da, b - db) for a, b in B.tolist()} - key)
        beyond += sites
        which += [k] * len(sites)
    ab = np.array(beyond, dtype=float).reshape(-1, 2)
    xy = np.stack([ab[:, 0] + ab[:, 1], ab[:, 0] - ab[:, 1]], axis=-1) * board.square_size
    out = (np.array(stays), xy, np.array(which, dtype=int))
    for arr in out:
        arr.setflags(write=False)
    return out


def _shift_explains(uv: np.ndarray, free: np.ndarray, board: Board, H: np.ndarray | None = None,
                    spacing: float | None = None) -> bool:
    """True when a labelling shifted by a lattice step (one or two circles, 8 directions) could explain the
    candidates as well as ``uv`` does: a shift pushes the seen circles on one edge off the board and can only
    gain ``free`` candidates (not used by ``uv``) just beyond the opposite edge. ``uv`` stands only if, for
    every shift, the seen edge circles outnumber such candidates by two or more. A board cut by the image
    border, whose outline does not show which circles are missing, therefore never stands. ``H``: the
    board-plane -> image homography (fitted to ``uv`` when None); ``spacing``: the circles' image spacing."""
    seen = np.all(np.isfinite(uv), axis=1)
    if H is None:
        H, _ = cv2.findHomography(board.points[seen, :2], uv[seen], 0)
        if H is None:
            return True
    if spacing is None:
        spacing = float(_median(neighbour_distance(uv[seen])))
    stays, beyond, which = _shift_tables(board)
    edge = np.count_nonzero(seen[None, :] & ~stays, axis=1)  # (S,) seen circles a shift pushes off
    gained = np.zeros(stays.shape[0], dtype=int)  # (S,) free candidates a shift could claim
    if free.shape[0]:
        bh = _homog(beyond) @ H.T
        ok = bh[:, 2] > 1e-9
        bp = bh[ok, :2] / bh[ok, 2:]
        occupied_site = _norm(bp[:, None, :] - free[None, :, :]).min(axis=1) < 0.3 * spacing
        gained = np.bincount(which[ok][occupied_site], minlength=stays.shape[0])
    return bool(np.any(edge < gained + 2))


def _unused(candidates: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The candidates farther than a quarter spacing from every labelled point (not used by the labelling)."""
    q = uv[np.all(np.isfinite(uv), axis=1)]
    if candidates.shape[0] == 0 or q.shape[0] < 2:
        return candidates
    near = 0.25 * float(_median(neighbour_distance(q)))
    return candidates[_norm(candidates[:, None, :] - q[None, :, :]).min(axis=1) >= near]


def track_circle_grid(
    points: np.ndarray,
    predicted_uv: np.ndarray,
    board: Board,
    camera: CameraModel | None = None,
    *,
    min_points: int | None = None,
    max_rms_px: float = 1.0,
) -> GridDetection:
    """Label candidates by their predicted circles; accepted only when no shifted grid explains them as well.

    The common offset between the predictions and their nearest candidates is removed, every predicted
    circle takes the nearest candidate within 0.3 of its neighbour spacing, and circles the prediction
    missed are picked up through the homography of the matched ones.

    A labelling off by a lattice step s (one or two circles in any of 8 directions; a bad prediction
    can only cause that) would push the matched circles on the board's edge facing s off the board, and
    could only gain candidates lying where the board has no circles, just beyond its opposite edge. The
    labelling is accepted only if, for every s, the matched edge circles outnumber such candidates by two
    or more, at least ``min_points`` (default max(6, N / 2)) circles are matched, the median match
    distance is below a quarter spacing and :func:`check_grid_order` passes. Otherwise the caller
    searches in full.
    """
    n = board.n_points
    min_points = max(6, n // 2) if min_points is None else int(min_points)
    pred = np.asarray(predicted_uv, dtype=float)
    ok_pred = np.all(np.isfinite(pred), axis=1)
    pts = np.asarray(points, dtype=float)
    if np.count_nonzero(ok_pred) < min_points or pts.shape[0] < min_points:
        return _fail(n, REASON_NOT_FOUND)
    spacing = np.full(n, np.nan)
    spacing[ok_pred] = neighbour_distance(pred[ok_pred])
    d = _norm(pred[:, None, :] - pts[None, :, :])  # (N, k)
    # Take out the common part of the prediction error first (the median offset to the nearest candidates).
    # If the prediction was off by half a spacing or more this may shift every label; the shift test below
    # is what refuses such a labelling.
    j0 = np.argmin(np.where(ok_pred[:, None], d, np.inf), axis=1)
    near = ok_pred & (d[np.arange(n), j0] < 0.6 * spacing)
    if np.count_nonzero(near) >= min_points:
        pred = pred + _median((pts[j0] - pred)[near], axis=0)
        d = _norm(pred[:, None, :] - pts[None, :, :])
    j = np.argmin(np.where(ok_pred[:, None], d, np.inf), axis=1)
    dist = d[np.arange(n), j]
    hit = ok_pred & (dist < 0.3 * spacing)
    # One candidate per circle: a candidate claimed twice is dropped for both.
    _, inv, cnt = np.unique(j[hit], return_inverse=True, return_counts=True)
    hit[np.flatnonzero(hit)[cnt[inv] > 1]] = False
    if np.count_nonzero(hit) < min_points or _median(dist[hit] / spacing[hit]) > 0.25:
        return _fail(n, REASON_NOT_FOUND)
    uv = np.full((n, 2), np.nan)
    uv[hit] = pts[j[hit]]
    taken = np.zeros(pts.shape[0], dtype=bool)
    taken[j[hit]] = True
    # Circles the prediction missed: project the board with the homography of the matched ones and take
    # the free candidates that now sit on a free circle (predictions are off by the unmodelled acceleration).
    H, _ = cv2.findHomography(board.points[hit, :2], uv[hit], 0)
    if H is None:
        return _fail(n, REASON_ORDER)
    ph = _homog(board.points[:, :2]) @ H.T
    proj = ph[:, :2] / ph[:, 2:]
    sp = neighbour_distance(proj)
    if np.count_nonzero(~hit):
        d2 = _norm(proj[:, None, :] - pts[None, :, :])
        j2 = np.argmin(d2, axis=1)
        add = ~hit & (d2[np.arange(n), j2] < 0.2 * sp) & ~taken[j2]
        _, inv2, cnt2 = np.unique(j2[add], return_inverse=True, return_counts=True)
        add[np.flatnonzero(add)[cnt2[inv2] > 1]] = False
        uv[add] = pts[j2[add]]
        taken[j2[add]] = True
    if _shift_explains(uv, pts[~taken], board, H, float(_median(sp))):
        return _fail(n, REASON_AMBIGUOUS)
    reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_rms_px)
    if reason != REASON_OK:
        return _fail(n, reason, rms)
    return GridDetection(uv, True, REASON_OK, rms)


def _detect_rims(
    image: np.ndarray, board: Board, camera: CameraModel | None, threshold: float, max_rms_px: float,
    min_points: int | None, roi: tuple[int, int, int, int] | None = None, predicted_uv: np.ndarray | None = None,
    thicknesses: tuple[int, ...] = RIM_THICKNESSES,
) -> GridDetection:
    n = board.n_points
    if image.ndim != 2:
        raise InputError(f"detect: expected a single-channel 2-D image, got shape {image.shape}")
    x0, y0 = 0, 0
    if roi is not None:
        h, w = image.shape
        x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
        x1, y1 = min(w, int(roi[2])), min(h, int(roi[3]))
        if x1 - x0 < 8 or y1 - y0 < 8:
            return _fail(n, REASON_EMPTY)
        image = image[y0:y1, x0:x1]
    active = (image > threshold).astype(np.uint8)
    if not np.any(active):
        return _fail(n, REASON_EMPTY)
    # Sensor noise is mostly isolated pixels, rims are connected curves: drop active pixels without an
    # active 8-neighbour before the dilation below turns noise into walls across the circles' insides.
    neighbours = cv2.boxFilter(active, cv2.CV_16U, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    active &= (neighbours >= 2).astype(np.uint8)
    # Where the circle's edge runs along the motion it produces no events, so each rim has two breaks
    # through which its inside would leak into the background. Thickening the rims by k pixels closes
    # breaks up to 2k + 1 wide and shrinks every hole evenly (its centroid stays). k = 2 closes most
    # breaks; k = 3 helps slow motion (wide breaks), k = 1 small, distant circles (small holes).
    result = _fail(n, REASON_NOT_FOUND)
    holes = {}  # rim thickness k -> (candidate centres in full-image coordinates, their areas), or None

    def candidates(k: int):
        if k not in holes:
            holes[k] = _rim_candidates(active, k, n, x0, y0)
        return holes[k]

    def accepted(det: GridDetection, k: int) -> GridDetection:
        seen = det.uv[np.all(np.isfinite(det.uv), axis=1)]
        if float(_median(neighbour_distance(seen))) < MIN_RIM_SPACING_PX:
            return _fail(n, REASON_TOO_SMALL, det.homography_rms_px)
        return replace(det, rim_px=k)

    if predicted_uv is not None and TRACK_BEFORE_LABEL:
        # Labelling by the prediction is cheap and certain when it works: try it at every thickness before the
        # full lattice labelling at any (which costs several times more, and mostly fails where tracking did).
        # A find of half the board or more is taken at once; one of fewer circles (TRACK_MIN_POINTS or more) only if
        # no thickness shows more of them.
        best, best_seen, best_k = None, 0, 0
        for k in thicknesses:
            cand = candidates(k)
            if cand is None:
                continue
            det = track_circle_grid(cand[0], predicted_uv, board, camera, max_rms_px=max_rms_px,
                                    min_points=TRACK_MIN_POINTS)
            if not det.ok:
                continue
            seen = int(np.count_nonzero(np.all(np.isfinite(det.uv), axis=1)))
            if seen >= max(6, n // 2):
                return accepted(det, k)
            if seen > best_seen:
                best, best_seen, best_k = det, seen, k
        if best is not None:
            return accepted(best, best_k)
        predicted_uv = None
    for k in thicknesses:
        det = _rims_at(candidates(k), n, board, camera, max_rms_px, min_points, predicted_uv)
        if det.ok:
            return accepted(det, k)
        result = det if result.reason == REASON_NOT_FOUND else result
    return result


def _rim_candidates(active, k, n, x0, y0) -> tuple[np.ndarray, np.ndarray] | None:
    """Holes of the rims thickened by ``k`` px that may be circle insides: (centres (m, 2), areas (m,)),
    in full-image coordinates; None when fewer than six holes."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
    centres, area = rim_holes(cv2.dilate(active, kernel).astype(bool))
    if centres.shape[0] < 6:
        return None
    # Circle insides are the largest compact holes; gaps between touching rims and texture leave
    # smaller ones. Reference: the median of the n largest.
    ref = float(_median(np.sort(area)[-n:]))
    keep = area >= 0.4 * ref
    return centres[keep] + (x0, y0), area[keep]


def _rims_at(cand, n, board, camera, max_rms_px, min_points, predicted_uv) -> GridDetection:
    """Rim holes ``cand`` (from :func:`_rim_candidates`) labelled as the board (see :func:`_detect_rims`)."""
    if cand is None:
        return _fail(n, REASON_NOT_FOUND)
    pts, area = cand
    if predicted_uv is not None:
        det = track_circle_grid(pts, predicted_uv, board, camera, max_rms_px=max_rms_px, min_points=TRACK_MIN_POINTS)
        if det.ok:
            return det
    det = label_circle_grid(pts, board, camera, areas=area, min_points=min_points, max_rms_px=max_rms_px)
    if det.ok and _shift_explains(det.uv, _unused(pts, det.uv), board):
        return _fail(n, REASON_AMBIGUOUS, det.homography_rms_px)
    return det


# --- AprilGrid -------------------------------------------------------------------------------------


TAG_LAYOUTS = ("kalibr", "opencv")


def aprilgrid_corner_index(tag_ids: np.ndarray, cols: int, layout: str = "kalibr") -> np.ndarray:
    """Board point indices (n, 4) of OpenCV's four corners of each tag, in Kalibr's numbering.

    Kalibr prints tag k in tag row k // cols counted from the bottom (board y axis up) and numbers
    the corners on a (2 rows) x (2 cols) grid from the board origin. OpenCV's tag36h11 dictionary
    holds each code turned by 180 degrees with respect to Kalibr's print, so on a Kalibr board
    (``layout="kalibr"``) OpenCV's corners 0, 1, 2, 3 ("top-left" clockwise in its own marker
    image) are the printed tag's bottom-right, bottom-left, top-left and top-right: grid points
    (2r, 2c + 1), (2r, 2c), (2r + 1, 2c), (2r + 1, 2c + 1). (Checked by rendering tags bit by bit
    as Kalibr's target generator lays them out; see tests/test_detect.py.) ``layout="opencv"`` is
    a board whose tags are OpenCV's marker images printed upright (top row at the largest y), as
    plsgraph's simulator renders them: corner 0 is then the tag's top-left, grid point (2r + 1, 2c).
    """
    if layout not in TAG_LAYOUTS:
        raise InputError(f"detect: tag layout must be one of {', '.join(TAG_LAYOUTS)}, got {layout!r}")
    tag_ids = np.asarray(tag_ids, dtype=int)
    r, c = np.divmod(tag_ids, cols)
    nc = 2 * cols
    base = 2 * r * nc + 2 * c  # grid point (2r, 2c): the tag's corner at its own board origin
    if layout == "kalibr":
        return np.stack([base + 1, base, base + nc, base + nc + 1], axis=-1)
    return np.stack([base + nc, base + nc + 1, base + 1, base], axis=-1)


def make_aruco_detector(border_bits: int = 2, refine: str = "apriltag") -> cv2.aruco.ArucoDetector:
    """An ArucoDetector for tag36h11. Kalibr's AprilGrids have a 2-bit black border; AprilTag's own
    tag images have a 1-bit one. ``refine`` is ``"apriltag"`` (edge-fit corners, the most precise on
    rendered tags: about 0.1 px scatter against 0.4 px for ``"subpix"``), ``"subpix"``, ``"contour"``
    or ``"none"``."""
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = int(border_bits)
    methods = {
        "none": cv2.aruco.CORNER_REFINE_NONE,
        "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
        "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
        "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
    }
    if refine not in methods:
        raise InputError(f"detect: refine must be one of {', '.join(methods)}, got {refine!r}")
    params.cornerRefinementMethod = methods[refine]
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    return cv2.aruco.ArucoDetector(dictionary, params)


@dataclass(frozen=True)
class TagDetection:
    """Raw tag36h11 detections of one image: ``ids`` (k,) and ``corners`` (k, 4, 2) in OpenCV order."""

    ids: np.ndarray
    corners: np.ndarray


def detect_tags(image8: np.ndarray, detector: cv2.aruco.ArucoDetector) -> TagDetection:
    """All tag36h11 markers in an 8-bit image (ids need not belong to any board)."""
    corners, ids, _ = detector.detectMarkers(image8)
    if ids is None or len(ids) == 0:
        return TagDetection(np.zeros(0, dtype=int), np.zeros((0, 4, 2)))
    c = np.asarray(corners, dtype=float).reshape(-1, 4, 2)
    if detector.getDetectorParameters().cornerRefinementMethod == cv2.aruco.CORNER_REFINE_APRILTAG:
        # The AprilTag refinement reports corners with pixel centres at +0.5 (measured: +0.45 px bias
        # in x and y on rendered tags); OpenCV and plsgraph put pixel centres at integers.
        c -= 0.5
    return TagDetection(np.asarray(ids, dtype=int).ravel(), c)


def detect_aprilgrid(
    image8: np.ndarray,
    board: Board,
    camera: CameraModel | None = None,
    *,
    detector: cv2.aruco.ArucoDetector | None = None,
    layout: str = "kalibr",
    min_tags: int = 2,
    max_homography_rms_px: float = 2.0,
) -> GridDetection:
    """Kalibr AprilGrid corners in ``board.points`` order, NaN for tags not seen (partial boards allowed).

    Tags with ids outside the board and ids seen twice (stray tags in the scene) are ignored;
    the remaining corners must pass :func:`check_grid_order` (one homography, front side).
    ``layout`` says how the tags are printed (see :func:`aprilgrid_corner_index`); ``detector``
    defaults to :func:`make_aruco_detector` with Kalibr's 2-bit tag border.
    """
    if board.pattern != "aprilgrid":
        raise InputError(f"detect_aprilgrid: board {board.name!r} is a {board.pattern}, not an aprilgrid")
    img = np.asarray(image8)
    if img.dtype != np.uint8:
        raise InputError("detect_aprilgrid: give an 8-bit image (see plsgraph.frontend.surfaces.to_uint8)")
    n = board.n_points
    det = detect_tags(img, detector or make_aruco_detector())
    n_tags = board.cols * board.rows
    ids, counts = np.unique(det.ids, return_counts=True)
    good_ids = ids[(counts == 1) & (ids < n_tags)]
    keep = np.isin(det.ids, good_ids)
    if np.count_nonzero(keep) < min_tags:
        return _fail(n, REASON_NOT_FOUND if det.ids.size == 0 else REASON_TOO_FEW)
    uv = np.full((n, 2), np.nan)
    uv[aprilgrid_corner_index(det.ids[keep], board.cols, layout).ravel()] = det.corners[keep].reshape(-1, 2)
    reason, rms = check_grid_order(uv, board, camera, max_rms_px=max_homography_rms_px, max_point_frac=0.5)
    if reason != REASON_OK:
        return _fail(n, reason, rms)
    return GridDetection(uv, True, REASON_OK, rms)
