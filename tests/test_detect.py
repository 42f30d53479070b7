"""Board detection on rendered images with known truth, and the order checks that guard PnP."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from plsgraph.core.board import Board, load_board
from plsgraph.core.camera import CameraModel, davis346_default
from plsgraph.core.geometry import inv_T, make_T, rotation_error_deg, so3_exp, transform_points
from plsgraph.errors import InputError
from plsgraph.frontend.detect import (
    REASON_AMBIGUOUS,
    REASON_EMPTY,
    REASON_MIRRORED,
    REASON_OK,
    REASON_ORDER,
    aprilgrid_corner_index,
    board_is_symmetric,
    check_grid_order,
    detect_aprilgrid,
    detect_circle_grid,
    make_aruco_detector,
    track_circle_grid,
)
from plsgraph.frontend.pose import solve_pnp
from plsgraph.sim.render import render_intensity_u8, render_log_intensity

CAM = davis346_default()
CIRCLES = load_board("acircles_4x11")
GRID = Board(pattern="aprilgrid", cols=6, rows=6, tag_size=0.088, tag_spacing=0.3)


def pose_facing(board: Board, dist: float, rotvec, front_z: float) -> np.ndarray:
    """T_board_cam of a camera ``dist`` m from the board centre on the side where board z has sign ``front_z``."""
    R = so3_exp(np.asarray(rotvec, dtype=float))
    if front_z > 0:  # look along -z of the board: turn the optical axis around
        R = R @ np.diag([1.0, -1.0, -1.0])
    t = np.array([0.0, 0.0, dist]) - R @ board.points.mean(axis=0)
    return inv_T(make_T(R, t))


def truth_pixels(T_board_cam: np.ndarray, board: Board, camera: CameraModel = CAM) -> np.ndarray:
    return camera.project(transform_points(inv_T(T_board_cam), board.points))


CIRCLE_POSES = [(0.45, (0.2, -0.3, 0.1)), (0.7, (0.5, 0.3, 1.0)), (1.1, (-0.3, 0.4, -2.0))]


@pytest.mark.parametrize("dist,rotvec", CIRCLE_POSES)
def test_circle_grid_on_rendered_image(dist, rotvec):
    T = pose_facing(CIRCLES, dist, rotvec, front_z=-1)
    img = render_log_intensity(T, CAM, CIRCLES)
    det = detect_circle_grid(img, CIRCLES, CAM, foreground="dark")
    assert det.ok and det.reason == REASON_OK and det.n_seen == CIRCLES.n_points
    err = np.linalg.norm(det.uv - truth_pixels(T, CIRCLES), axis=1)
    # Centroids of perspective-distorted disks are biased by a small fraction of a pixel at most.
    assert np.median(err) < 0.15 and err.max() < 0.3
    est = solve_pnp(det.uv, CIRCLES.points, CAM)
    assert rotation_error_deg(est.T_board_cam[:3, :3], T[:3, :3]) < 0.3
    assert np.linalg.norm(est.T_board_cam[:3, 3] - T[:3, 3]) < 0.005 * dist


def test_circle_grid_bad_windows():
    n = CIRCLES.n_points
    blank = np.zeros((CAM.height, CAM.width), np.float32)
    det = detect_circle_grid(blank, CIRCLES, CAM)
    assert not det.ok and det.reason == REASON_EMPTY and np.isnan(det.uv).all() and det.uv.shape == (n, 2)
    # Board cut by the image border: the circles in view could be any block of the grid's columns, so
    # the labelling is ambiguous and there is no detection (never a guessed order).
    T = pose_facing(CIRCLES, 0.45, (0.1, 0.2, 0.0), front_z=-1) @ make_T(np.eye(3), np.array([0.3, 0.0, 0.0]))
    assert 5 < np.count_nonzero(truth_pixels(T, CIRCLES)[:, 0] < 0) < 30  # the set-up really cuts the board
    det = detect_circle_grid(render_log_intensity(T, CAM, CIRCLES), CIRCLES, CAM, foreground="dark")
    assert not det.ok and det.reason == REASON_AMBIGUOUS
    # Circles hidden inside the board (a finger, a reflection): the outline still fixes the labels.
    T = pose_facing(CIRCLES, 0.6, (0.2, -0.3, 0.1), front_z=-1)
    img = render_log_intensity(T, CAM, CIRCLES)
    truth = truth_pixels(T, CIRCLES)
    hidden = [13, 18, 26]
    for k in hidden:
        u, v = np.round(truth[k]).astype(int)
        img[v - 4 : v + 5, u - 4 : u + 5] = img[v - 4 : v + 5, u - 4 : u + 5].max()  # paper white
    det = detect_circle_grid(img, CIRCLES, CAM, foreground="dark")
    assert det.ok
    seen = np.all(np.isfinite(det.uv), axis=1)
    assert not seen[hidden].any() and seen.sum() == CIRCLES.n_points - len(hidden)
    assert np.max(np.linalg.norm(det.uv[seen] - truth[seen], axis=1)) < 0.3
    # A board definition that does not match what is seen (3 instead of 4 circles per row).
    wrong = Board(pattern="asymmetric_circles", cols=3, rows=11, square_size=0.025, circle_diameter=0.03)
    T = pose_facing(CIRCLES, 0.7, (0.2, -0.3, 0.1), front_z=-1)
    assert not detect_circle_grid(render_log_intensity(T, CAM, CIRCLES), wrong, CAM, foreground="dark").ok


def test_order_check_rejects_permuted_and_mirrored_labels():
    T = pose_facing(CIRCLES, 0.7, (0.2, -0.3, 0.4), front_z=-1)
    uv = truth_pixels(T, CIRCLES) + np.random.default_rng(0).normal(0, 0.1, (CIRCLES.n_points, 2))
    assert check_grid_order(uv, CIRCLES, CAM)[0] == REASON_OK
    swapped = uv.copy()
    swapped[[9, 10]] = swapped[[10, 9]]  # two neighbouring circles exchanged
    reason, rms = check_grid_order(swapped, CIRCLES, CAM)
    assert reason == REASON_ORDER
    assert check_grid_order(uv[::-1], CIRCLES, CAM)[0] == REASON_ORDER
    shuffled = uv[np.random.default_rng(1).permutation(CIRCLES.n_points)]
    assert check_grid_order(shuffled, CIRCLES, CAM)[0] == REASON_ORDER
    # A mirror image of the board fits a homography exactly but would mean seeing it from behind.
    mirrored = uv.copy()
    mirrored[:, 0] = CAM.width - 1 - mirrored[:, 0]
    assert check_grid_order(mirrored, CIRCLES)[0] == REASON_MIRRORED


def test_tracking_never_accepts_a_grid_shifted_by_one_circle():
    T = pose_facing(CIRCLES, 0.6, (0.2, -0.3, 0.4), front_z=-1)
    rng = np.random.default_rng(3)
    truth = truth_pixels(T, CIRCLES)
    cand = truth + rng.normal(0, 0.1, truth.shape)
    clutter = rng.uniform(0, [CAM.width, CAM.height], (15, 2))
    pts = np.vstack([cand, clutter])[rng.permutation(CIRCLES.n_points + 15)]
    # A prediction off by 0.4 of a spacing in a common direction is corrected and labels every circle right.
    step = truth[5] - truth[1]  # neighbouring circles (row 1, col 1) and (row 0, col 1): one lattice step
    ok = track_circle_grid(pts, truth + 0.4 * step, CIRCLES, CAM)
    assert ok.ok and np.max(np.linalg.norm(ok.uv - truth, axis=1)) < 0.5
    # Off by a whole lattice step, every circle would take its neighbour's label: refused.
    assert not track_circle_grid(pts, truth + step, CIRCLES, CAM).ok
    assert not track_circle_grid(pts, truth - step, CIRCLES, CAM).ok
    assert not track_circle_grid(pts, truth + 2 * step, CIRCLES, CAM).ok
    # Circles missing inside the board: still unambiguous, labelled right, the missing ones NaN.
    inner = [12, 13, 17, 21, 26, 30]
    keep = np.setdiff1d(np.arange(CIRCLES.n_points), inner)
    part = np.vstack([cand[keep], clutter])
    det = track_circle_grid(part, truth + 0.3 * step, CIRCLES, CAM)
    assert det.ok and np.isnan(det.uv[inner]).all()
    assert np.max(np.linalg.norm(det.uv[keep] - truth[keep], axis=1)) < 0.5
    # The whole first row and the left column missing: a shift towards them cannot be ruled out.
    row0_col0 = np.flatnonzero((CIRCLES.points[:, 1] < 1e-9) | (CIRCLES.points[:, 0] < 1e-9))
    keep = np.setdiff1d(np.arange(CIRCLES.n_points), row0_col0)
    det = track_circle_grid(np.vstack([cand[keep], clutter]), truth, CIRCLES, CAM)
    assert not det.ok


def test_symmetric_board_flagged():
    assert not board_is_symmetric(CIRCLES)
    even = Board(pattern="asymmetric_circles", cols=4, rows=10, square_size=0.025, circle_diameter=0.02)
    assert board_is_symmetric(even)


# --- AprilGrid ---------------------------------------------------------------------------------------


def test_aprilgrid_on_rendered_image_with_partial_view():
    T = pose_facing(GRID, 0.7, (0.2, -0.3, 0.1), front_z=1)
    u8 = render_intensity_u8(T, CAM, GRID)
    truth = truth_pixels(T, GRID)
    det = detect_aprilgrid(u8, GRID, CAM, detector=make_aruco_detector(border_bits=1), layout="opencv")
    assert det.ok
    seen = np.all(np.isfinite(det.uv), axis=1)
    assert seen.sum() >= 4 * 30  # most of the 36 tags
    err = np.linalg.norm(det.uv[seen] - truth[seen], axis=1)
    assert np.median(err) < 0.2 and err.max() < 1.0
    # Partial board: blank out the left part of the image; unseen corners are NaN, the rest still right.
    part = u8.copy()
    part[:, : CAM.width // 2] = 128
    pdet = detect_aprilgrid(part, GRID, CAM, detector=make_aruco_detector(border_bits=1), layout="opencv")
    pseen = np.all(np.isfinite(pdet.uv), axis=1)
    assert pdet.ok and 8 <= pseen.sum() < seen.sum()
    assert np.all(truth[pseen, 0] > CAM.width // 2 - 1)
    assert np.median(np.linalg.norm(pdet.uv[pseen] - truth[pseen], axis=1)) < 0.2
    # The same tags read with Kalibr's print orientation put corners in the wrong places: rejected.
    kal = detect_aprilgrid(u8, GRID, CAM, detector=make_aruco_detector(border_bits=1), layout="kalibr")
    assert not kal.ok and kal.reason == REASON_ORDER


# tag36h11 codes of ids 0..3 (36 bits, most significant bit = top-left data cell of the printed tag,
# 1 = white), as listed in the AprilTag / Kalibr code tables.
TAG36H11_CODES = [0xD5D628584, 0xD97F18B49, 0xDD280910E, 0xE479E9C98]


def kalibr_flat_board(cols: int, rows: int, bit_px: int, spacing: float) -> tuple[np.ndarray, float]:
    """A 2 x 2 Kalibr AprilGrid drawn cell by cell as Kalibr's target generator lays it out: tag k at
    tag row k // cols from the *bottom*, upright, 2-bit black border, 6 x 6 data bits. Returns the
    image (row 0 at the top) and the margin in bits. Board y points up the printed page."""
    tag_bits = 10
    gap = int(round(spacing * tag_bits))
    margin = 8
    w = 2 * margin + cols * tag_bits + (cols - 1) * gap
    h = 2 * margin + rows * tag_bits + (rows - 1) * gap
    cells = np.full((h, w), 255, np.uint8)
    for k in range(cols * rows):
        r, c = divmod(k, cols)
        x0 = margin + c * (tag_bits + gap)
        y_top = h - (margin + r * (tag_bits + gap) + tag_bits)  # rows counted from the bottom
        tag = np.zeros((tag_bits, tag_bits), np.uint8)
        bits = [(TAG36H11_CODES[k] >> (35 - i)) & 1 for i in range(36)]
        tag[2:8, 2:8] = np.array(bits, np.uint8).reshape(6, 6) * 255
        cells[y_top : y_top + tag_bits, x0 : x0 + tag_bits] = tag
    return cv2.resize(cells, (w * bit_px, h * bit_px), interpolation=cv2.INTER_NEAREST), margin


def test_aprilgrid_corner_numbering_matches_kalibr_print():
    cols = rows = 2
    bit_px, spacing = 6, 0.3
    tag_size = 0.1
    board = Board(pattern="aprilgrid", cols=cols, rows=rows, tag_size=tag_size, tag_spacing=spacing)
    flat, margin = kalibr_flat_board(cols, rows, bit_px, spacing)
    ppm = 10 * bit_px / tag_size  # flat-image pixels per metre
    hf = flat.shape[0]
    # Board (x, y) -> flat pixel: x right from the margin, y up from the bottom margin; pixel centres at integers.
    m0 = margin * bit_px
    A = np.array([[ppm, 0.0, m0 - 0.5], [0.0, -ppm, hf - m0 - 0.5], [0.0, 0.0, 1.0]])
    cam = CameraModel(346, 260, CAM.K, np.zeros(5))
    for rotvec in [(0.2, -0.3, 0.1), (-0.3, 0.2, 2.5)]:
        T = pose_facing(board, 0.45, rotvec, front_z=1)
        T_cb = inv_T(T)
        H_img_board = cam.K @ np.c_[T_cb[:3, 0], T_cb[:3, 1], T_cb[:3, 3]]
        img = cv2.warpPerspective(flat, H_img_board @ np.linalg.inv(A), (cam.width, cam.height), flags=cv2.INTER_AREA,
                                  borderValue=255)
        det = detect_aprilgrid(img, board, cam, detector=make_aruco_detector(border_bits=2), layout="kalibr")
        assert det.ok and det.n_seen == board.n_points
        truth = truth_pixels(T, board, cam)
        assert np.max(np.linalg.norm(det.uv - truth, axis=1)) < 0.6
        # The wrong print orientation for these tags does not pass.
        assert not detect_aprilgrid(img, board, cam, detector=make_aruco_detector(border_bits=2), layout="opencv").ok


def test_aprilgrid_on_simulator_kalibr_print():
    """The simulator's Kalibr print (2-bit border, codes turned) is read with the default Kalibr layout."""
    from plsgraph.sim.render import RenderParams

    T = pose_facing(GRID, 0.7, (-0.2, 0.3, 0.4), front_z=1)
    u8 = render_intensity_u8(T, CAM, GRID, RenderParams(tag_layout="kalibr"))
    det = detect_aprilgrid(u8, GRID, CAM, detector=make_aruco_detector(border_bits=2), layout="kalibr")
    assert det.ok
    seen = np.all(np.isfinite(det.uv), axis=1)
    assert seen.sum() >= 4 * 25
    assert np.median(np.linalg.norm(det.uv[seen] - truth_pixels(T, GRID)[seen], axis=1)) < 0.2


def test_aprilgrid_index_is_a_permutation():
    ids = np.arange(12)
    for layout in ("kalibr", "opencv"):
        idx = aprilgrid_corner_index(ids, 4, layout)
        assert sorted(idx.ravel().tolist()) == list(range(48))
    # Tag 0's Kalibr corner 0 (board origin) is point 0; on a 4 x 3 grid tag 5 sits in row 1, column 1.
    assert 0 in aprilgrid_corner_index(np.array([0]), 4)[0]
    assert set(aprilgrid_corner_index(np.array([5]), 4)[0]) == {18, 19, 26, 27}


def _board_view(board: Board, distance: float = 1.2) -> np.ndarray:
    """Image points of ``board`` seen straight on from ``distance`` (slightly turned)."""
    cam = davis346_default()
    T_cam_board = make_T(so3_exp(np.array([0.05, -0.08, 0.03])), np.array([0.0, 0.0, distance]) - board.points.mean(0))
    return cam.project(transform_points(T_cam_board, board.points))


def test_a_labelling_a_lattice_step_off_is_refused_when_the_image_allows_it():
    from plsgraph.frontend.detect import _shift_explains, _unused

    board = load_board("acircles_4x11_a2")
    uv = _board_view(board)
    assert not _shift_explains(uv, np.zeros((0, 2)), board)  # every circle seen, nothing beyond: unique
    two = 2 * board.cols  # two rows: the grid repeats itself every second row
    one_row_cut = uv.copy()
    one_row_cut[: board.cols] = np.nan  # one row missing: the alternating rows still fix the labels
    assert not _shift_explains(one_row_cut, np.zeros((0, 2)), board)
    # The board cut by the image border above its third row: a labelling two rows off fits as well.
    cut = uv.copy()
    cut[:two] = np.nan
    assert _shift_explains(cut, np.zeros((0, 2)), board)
    # Candidates two rows beyond an edge (e.g. holes between rims and the paper's edge): a labelling shifted
    # onto them would explain as many points, so the labelling does not stand.
    beyond = uv[:two] - (uv[two: 2 * two] - uv[:two])
    assert len(_unused(np.vstack([uv, beyond]), uv)) == two
    assert _shift_explains(uv, _unused(np.vstack([uv, beyond]), uv), board)


def test_a_detection_that_jumps_from_the_tracked_board_is_refused():
    from plsgraph.frontend.detect import neighbour_distance
    from plsgraph.frontend.track import _jumped

    board = load_board("acircles_4x11_a2")
    uv = _board_view(board)
    spacing = float(np.median(neighbour_distance(uv)))
    assert not _jumped(uv + 0.2 * spacing, uv)  # a board that moved a little more than predicted
    # The same circles labelled one row-step off (two lattice steps along a row: two circles apart).
    shifted = np.full_like(uv, np.nan)
    shifted[1:] = uv[:-1]
    rows = np.arange(board.n_points) // board.cols
    shifted[np.r_[False, rows[1:] != rows[:-1]]] = np.nan
    assert _jumped(shifted, uv)


def test_a_failed_detection_never_says_ok(monkeypatch):
    """When the lattice labelling succeeds but its refined centres fail the order check, the result is a failure
    with the check's reason (it once carried the labelling's "ok" with no points, which callers took for a find)."""
    import plsgraph.frontend.detect as detect_module

    T = pose_facing(CIRCLES, 0.7, (0.5, 0.3, 1.0), front_z=-1)
    img = render_log_intensity(T, CAM, CIRCLES)
    monkeypatch.setattr(detect_module.cv2, "findCirclesGrid", lambda *a, **k: (False, None))  # the lattice path
    assert detect_circle_grid(img, CIRCLES, CAM, foreground="dark").ok  # the labelling alone finds it
    rng = np.random.default_rng(0)
    monkeypatch.setattr(detect_module, "refine_centroids",
                        lambda w, uv, r, iterations=4: uv + rng.normal(0.0, 3.0, uv.shape))
    det = detect_circle_grid(img, CIRCLES, CAM, foreground="dark")
    assert not det.ok and det.reason == REASON_ORDER and not np.isfinite(det.uv).any()


def _broken_rims(uv: np.ndarray, radius: float, gap_deg: np.ndarray, shape=(260, 346)) -> np.ndarray:
    """Event-activity image of circle rims at ``uv`` with two breaks of ``gap_deg`` (per circle) each, left and
    right (where a circle's edge runs along a vertical motion it makes no events)."""
    img = np.zeros(shape, np.float32)
    for (u, v), g in zip(uv, gap_deg, strict=True):
        for a0, a1 in ((g / 2, 180 - g / 2), (180 + g / 2, 360 - g / 2)):
            cv2.ellipse(img, (int(round(u * 16)), int(round(v * 16))), (int(round(radius * 16)),) * 2, 0, a0, a1,
                        1.0, 1, cv2.LINE_8, 4)
    return img


def test_a_predicted_board_is_tracked_at_every_rim_thickness_before_any_full_labelling(monkeypatch):
    """Rims with wide breaks leak at the first thickness tried and close at the next: the board the previous
    windows predict is labelled by tracking at the thicker rims, without the full lattice labelling (which costs
    several times more) ever running, and the labels are right."""
    import plsgraph.frontend.detect as detect_module

    board = load_board("acircles_4x11_a2")
    uv = _board_view(board, 0.75)
    spacing = float(np.median(detect_module.neighbour_distance(uv)))
    radius = 0.5 * board.circle_diameter / (np.sqrt(2) * board.square_size) * spacing
    # Breaks ~6.5 px wide in two circles of three, ~2 px in the others: the first thickness closes a third.
    gap = np.where(np.arange(board.n_points) % 3 > 0, 3.2, 1.0)
    rims = _broken_rims(uv, radius, gap_deg=2 * np.degrees(np.arcsin(gap / radius)))
    calls = []
    real = detect_module.label_circle_grid
    monkeypatch.setattr(detect_module, "label_circle_grid", lambda *a, **k: calls.append(1) or real(*a, **k))
    thick = detect_module.RIM_THICKNESSES
    assert thick[0] < max(thick)
    # Too few circles closed at the first thickness for a labelling, but enough to try one.
    monkeypatch.setattr(detect_module, "RIM_THICKNESSES", thick[:1])
    assert not detect_circle_grid(rims, board, CAM, foreground="rims", rim_threshold=0.5).ok and calls
    monkeypatch.setattr(detect_module, "RIM_THICKNESSES", thick)
    calls.clear()
    roi = (int(uv[:, 0].min() - 20), int(uv[:, 1].min() - 20), int(uv[:, 0].max() + 20), int(uv[:, 1].max() + 20))
    det = detect_circle_grid(rims, board, CAM, foreground="rims", rim_threshold=0.5, roi=roi,
                             predicted_uv=uv + 0.2 * spacing)
    assert det.ok and np.nanmax(np.linalg.norm(det.uv - uv, axis=1)) < 0.5
    assert np.isfinite(det.uv).all() and not calls
    # Without a prediction the full labelling finds the same board.
    full = detect_circle_grid(rims, board, CAM, foreground="rims", rim_threshold=0.5)
    assert full.ok and calls and np.nanmax(np.linalg.norm(full.uv - det.uv, axis=1)) < 1e-9


def test_the_rim_thickness_that_worked_is_tried_first(monkeypatch):
    """A detection on rims says which rim thickness found the board; given back as ``rim_first`` (as the window loop
    does for the next window) that thickness is tried first, alone when it finds the board, with the same labels."""
    import plsgraph.frontend.detect as detect_module

    board = load_board("acircles_4x11_a2")
    uv = _board_view(board, 0.75)
    spacing = float(np.median(detect_module.neighbour_distance(uv)))
    radius = 0.5 * board.circle_diameter / (np.sqrt(2) * board.square_size) * spacing
    gap = np.where(np.arange(board.n_points) % 3 > 0, 3.2, 1.0)  # the first thickness leaks (see above)
    rims = _broken_rims(uv, radius, gap_deg=2 * np.degrees(np.arcsin(gap / radius)))
    tried = []
    real = detect_module._rim_candidates
    monkeypatch.setattr(detect_module, "_rim_candidates", lambda a, k, *r: tried.append(k) or real(a, k, *r))
    roi = (int(uv[:, 0].min() - 20), int(uv[:, 1].min() - 20), int(uv[:, 0].max() + 20), int(uv[:, 1].max() + 20))
    kw = dict(foreground="rims", rim_threshold=0.5, roi=roi, predicted_uv=uv + 0.2 * spacing)
    first = detect_circle_grid(rims, board, CAM, **kw)
    assert first.ok and first.rim_px in detect_module.RIM_THICKNESSES and first.rim_px != tried[0]
    assert tried[-1] == first.rim_px and len(tried) > 1
    tried.clear()
    again = detect_circle_grid(rims, board, CAM, rim_first=first.rim_px, **kw)
    assert again.ok and again.rim_px == first.rim_px and tried == [first.rim_px]
    assert np.nanmax(np.linalg.norm(again.uv - first.uv, axis=1)) < 1e-9
    # Without a prediction (the full labelling) too; an unknown thickness keeps the default order.
    tried.clear()
    full = detect_circle_grid(rims, board, CAM, foreground="rims", rim_threshold=0.5, rim_first=first.rim_px)
    assert full.ok and tried[0] == first.rim_px
    tried.clear()
    assert detect_circle_grid(rims, board, CAM, rim_first=7, **kw).ok and tried[0] == detect_module.RIM_THICKNESSES[0]
    # Other detectors leave it unset.
    assert detect_circle_grid(render_log_intensity(pose_facing(CIRCLES, 0.7, (0.5, 0.3, 1.0), front_z=-1), CAM,
                                                   CIRCLES), CIRCLES, CAM, foreground="dark").rim_px is None


def _ring_events(uv: np.ndarray, radius: float, per_ring: int, noise: int, rng, shape=(260, 346)) -> np.ndarray:
    """Event-count image of small circles as rings of events (``per_ring`` events each, 0.6 px radial spread)
    over ``noise`` uniformly scattered background events."""
    a = rng.uniform(0.0, 2.0 * np.pi, (len(uv), per_ring))
    r = radius + rng.normal(0.0, 0.6, a.shape)
    x = np.r_[(uv[:, :1] + r * np.cos(a)).ravel(), rng.uniform(0, shape[1], noise)]
    y = np.r_[(uv[:, 1:] + r * np.sin(a)).ravel(), rng.uniform(0, shape[0], noise)]
    xi, yi = np.rint(x).astype(int), np.rint(y).astype(int)
    ok = (xi >= 0) & (xi < shape[1]) & (yi >= 0) & (yi < shape[0])
    return np.bincount(yi[ok] * shape[1] + xi[ok], minlength=shape[0] * shape[1]).reshape(shape).astype(np.float32)


@pytest.mark.parametrize("distance,seed", [(1.6, 0), (1.6, 1), (1.8, 2), (1.8, 3)])
def test_small_ringed_circles_the_blob_detector_misses_are_found_as_peaks(distance, seed):
    """A distant board's circles are rings of events 5-6 px across, 9-10 px apart: thresholded at the blob
    detector's levels, neighbouring rings merge or break into arcs and the board is not found among its blobs.
    The smoothed image's peaks are one per ring, and they are labelled right."""
    from plsgraph.frontend.detect import neighbour_distance

    board, uv, radius = _distant_board(distance)
    assert 9.0 < float(np.median(neighbour_distance(uv))) < 11.0
    img = _ring_events(uv, radius, per_ring=100, noise=1500, rng=np.random.default_rng(seed))
    assert not detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, peaks=False).ok
    _assert_labelled_right(detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, peaks=True), uv, 40)


def _distant_board(distance: float):
    """The A2 board ``distance`` m away: (board, its circles' pixels, their radius in pixels)."""
    from plsgraph.frontend.detect import neighbour_distance

    board = load_board("acircles_4x11_a2")
    uv = _board_view(board, distance)
    spacing = float(np.median(neighbour_distance(uv)))
    return board, uv, 0.5 * board.circle_diameter / (np.sqrt(2) * board.square_size) * spacing


def _assert_labelled_right(det, uv: np.ndarray, min_seen: int) -> None:
    assert det.ok and det.n_seen >= min_seen
    err = np.linalg.norm(det.uv - uv, axis=1)
    assert np.nanmedian(err) < 0.3 and np.nanmax(err) < 1.5  # every label right: a wrong one is a spacing off


def test_peaks_on_noise_alone_label_no_board():
    """Uniform background events (no board) give peaks too; the labelling finds no board in them."""
    board = load_board("acircles_4x11_a2")
    for seed in range(3):
        rng = np.random.default_rng(seed)
        img = _ring_events(np.zeros((0, 2)), 2.5, per_ring=0, noise=6000, rng=rng)
        assert not detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, peaks=True).ok


def _with_texture(img: np.ndarray, streaks: int, rng) -> np.ndarray:
    """``img`` plus a textured background's events: short streaks of 5-30 events in random directions."""
    img = img.copy()
    h, w = img.shape
    for _ in range(streaks):
        x0, y0, length, a = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(2, 8), rng.uniform(0, np.pi)
        s = rng.uniform(0, length, int(rng.integers(5, 30)))
        xi, yi = np.rint(x0 + s * np.cos(a)).astype(int), np.rint(y0 + s * np.sin(a)).astype(int)
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        np.add.at(img, (yi[ok], xi[ok]), 1.0)
    return img


@pytest.mark.parametrize("distance,seed", [(1.6, 0), (1.6, 1), (1.8, 2), (1.8, 3), (2.0, 4)])
def test_faint_rings_over_a_textured_background_are_found_by_the_ring_filter(distance, seed):
    """A slow, distant board over half a second: its circles are faint rings of events among a textured
    background's streaks. Neither the blob detector nor the smoothed image's peaks give the board; the ring
    filter's strongest responses hold most circles, and they are labelled right, at their sub-pixel peaks."""
    board, uv, radius = _distant_board(distance)
    rng = np.random.default_rng(seed)
    img = _with_texture(_ring_events(uv, radius, per_ring=60, noise=2000, rng=rng), 300, rng)
    assert not detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, peaks=True).ok
    _assert_labelled_right(detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, rings=True), uv, 30)


def test_rings_in_texture_alone_label_no_board():
    board = load_board("acircles_4x11_a2")
    for seed in range(4):
        rng = np.random.default_rng(seed)
        img = _with_texture(_ring_events(np.zeros((0, 2)), 2.5, per_ring=0, noise=3000, rng=rng), 400, rng)
        assert not detect_circle_grid(img, board, CAM, foreground="bright", blur_sigma=0.8, rings=True).ok


def test_a_ring_labelling_of_the_gaps_between_the_circles_is_refused():
    """The ring filter answers weakly between four rings too; those gap sites form a lattice as regular as the
    circles' (the board turned by 180 degrees). A labelling of them is refused: its own gaps, the true circles,
    answer more strongly than its circles. The true labelling passes."""
    from plsgraph.frontend.detect import neighbour_distance, normalize_image, ring_gaps_weaker, ring_response

    board = load_board("acircles_4x11_a2")
    for distance, seed in [(1.6, 0), (1.8, 2), (2.0, 4)]:
        uv = _board_view(board, distance)
        radius = 0.5 * board.circle_diameter / (np.sqrt(2) * board.square_size) * float(
            np.median(neighbour_distance(uv)))
        rng = np.random.default_rng(seed)
        img = _with_texture(_ring_events(uv, radius, per_ring=60, noise=2000, rng=rng), 300, rng)
        resp = ring_response(normalize_image(img, "bright"))
        H, _ = cv2.findHomography(board.points[:, :2], uv, 0)
        gaps = board.points[:, :2] + np.array([board.square_size, 0.0])
        gap_uv = cv2.perspectiveTransform(gaps.reshape(-1, 1, 2), H).reshape(-1, 2)
        assert ring_gaps_weaker(resp, uv, board)
        assert not ring_gaps_weaker(resp, gap_uv, board)


@pytest.mark.parametrize("shape", [(260, 346), (101, 77), (19, 40), (8, 346), (1, 50), (5, 5)])
def test_ring_response_through_one_transform_equals_filtering_each_radius(shape):
    """The larger ring kernels share one Fourier transform of the image (zero-padded: a linear filter); the
    response equals filtering the image with each kernel directly, zero outside the image."""
    import cv2

    from plsgraph.frontend.detect import RING_RADII_PX, _ring_kernel, ring_margin, ring_response

    img = np.random.default_rng(shape[0]).poisson(0.5, shape).astype(np.float32)
    direct = np.max([cv2.filter2D(img, -1, _ring_kernel(r), borderType=cv2.BORDER_CONSTANT) for r in RING_RADII_PX],
                    axis=0)
    m = ring_margin()
    resp = ring_response(img)
    assert resp.shape == shape and np.all(resp[:m] == 0) and np.all(resp[:, -m:] == 0)
    np.testing.assert_allclose(resp[m:-m, m:-m], direct[m:-m, m:-m], atol=1e-5)


@pytest.mark.parametrize("shape", [(8, 346), (5, 5), (30, 30)])
def test_small_images_give_no_board_not_an_error(shape):
    from plsgraph.frontend.detect import REASON_OK

    img = np.random.default_rng(1).poisson(1.0, shape).astype(float)
    assert detect_circle_grid(img, load_board("acircles_4x11_a2"), CAM, rings=True).reason != REASON_OK


def test_rim_holes_are_the_compact_gaps_inside_rims_with_exact_centroids_and_areas():
    """rim_holes against a direct count on an image with known holes: two rings (their insides are holes, centroid and
    area exact), a C-shaped rim (open: its inside joins the background, no hole), and a small compact blob of active
    pixels on its own (the active pixels themselves are never a hole, however compact)."""
    from plsgraph.frontend.detect import rim_holes

    active = np.zeros((60, 90), dtype=bool)
    active[10:21, 10:21] = True
    active[12:19, 12:19] = False  # hole 1: 7 x 7 inside a square ring
    yy, xx = np.mgrid[0:60, 0:90]
    r = np.hypot(xx - 50.0, yy - 20.0)
    active |= (r >= 5) & (r <= 7)
    inside = r < 5  # hole 2: the disk inside the circular ring
    c_rim = (np.hypot(xx - 25.0, yy - 45.0) >= 4) & (np.hypot(xx - 25.0, yy - 45.0) <= 6) & (xx < 28)
    active |= c_rim  # open on the right: no hole
    active[44:47, 70:73] = True  # a compact blob of activity alone
    cent, area = rim_holes(active)
    order = np.argsort(cent[:, 0])
    cent, area = cent[order], area[order]
    assert cent.shape == (2, 2)
    assert area[0] == 49 and np.allclose(cent[0], (15.0, 15.0))
    assert area[1] == inside.sum()
    assert np.allclose(cent[1], (xx[inside].mean(), yy[inside].mean()))
    # Nothing active, or only a compact blob (its 16 pixels pass every test of a hole's size and shape): no holes,
    # in the shapes callers expect.
    blob = np.zeros((100, 100), bool)
    blob[40:44, 50:54] = True
    for img in (np.zeros((20, 20), bool), blob):
        c, a = rim_holes(img)
        assert c.shape == (0, 2) and a.shape == (0,)



def _moving_circle_events(centres: np.ndarray, radius: np.ndarray, shift: np.ndarray, on_gain: np.ndarray,
                          shape=(260, 346), ss: int = 4, blur: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """ON and OFF count images of dark circles moving by ``shift`` (px) over a light board: OFF events where a circle
    arrived (its leading edge), ON events where it left (its trailing edge), ``on_gain`` (per circle) ON events per
    OFF event. Pixels are sampled ``ss`` x ``ss`` times (pixel (x, y) covers [x - 0.5, x + 0.5]); ``blur`` (px) a
    Gaussian blur of both images."""
    h, w = shape
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    ys = (np.arange(h)[:, None] + sub[None, :]).ravel()
    xs = (np.arange(w)[:, None] + sub[None, :]).ravel()
    on = np.zeros((h * ss, w * ss), np.float32)
    off = np.zeros_like(on)
    for c, r, g in zip(centres, radius, on_gain, strict=True):
        start, end = c - shift / 2, c + shift / 2
        y0, y1 = np.searchsorted(ys, [c[1] - r - 4, c[1] + r + 4])
        x0, x1 = np.searchsorted(xs, [c[0] - r - 4, c[0] + r + 4])
        yy, xx = np.meshgrid(ys[y0:y1], xs[x0:x1], indexing="ij")
        at_start = (xx - start[0]) ** 2 + (yy - start[1]) ** 2 <= r * r
        at_end = (xx - end[0]) ** 2 + (yy - end[1]) ** 2 <= r * r
        off[y0:y1, x0:x1] += at_end & ~at_start
        on[y0:y1, x0:x1] += g * (at_start & ~at_end)
    on = on.reshape(h, ss, w, ss).sum(axis=(1, 3)) / ss**2
    off = off.reshape(h, ss, w, ss).sum(axis=(1, 3)) / ss**2
    if blur <= 0:
        return on, off
    return cv2.GaussianBlur(on, (0, 0), blur), cv2.GaussianBlur(off, (0, 0), blur)


@pytest.mark.parametrize("dist,shift", [(1.2, (3.0, 1.0)), (1.2, (1.0, 0.0)), (1.8, (1.0, 0.0))])
def test_blob_centres_by_polarity_are_unmoved_by_one_polarity_firing_more(dist, shift):
    """A moving circle's OFF events lie on its leading edge and its ON events on its trailing edge. Where one polarity
    fires more than the other, by a share that differs from circle to circle, the centroid of all events moves along
    the motion by half a pixel or more; the mean of the two polarities' centroids stays on the circle's centre (at the
    middle of the motion)."""
    from plsgraph.frontend.detect import neighbour_distance, polarity_centroids, refine_centroids

    board = load_board("acircles_4x11_a2")
    T = pose_facing(board, dist, (0.15, -0.2, 0.05), front_z=-1)
    uv = truth_pixels(T, board)
    radius = 0.5 * board.circle_diameter * CAM.fx / transform_points(inv_T(T), board.points)[:, 2]
    gain = np.random.default_rng(3).uniform(0.5, 2.0, len(uv))  # ON events per OFF event, circle by circle
    on, off = _moving_circle_events(uv, radius, np.asarray(shift), gain)
    start = uv + np.random.default_rng(1).normal(0.0, 0.4, uv.shape)  # where the blob detector put them
    disk = 0.5 * neighbour_distance(uv)
    plain = np.linalg.norm(refine_centroids(on + off, start, disk) - uv, axis=1)
    by_polarity = np.linalg.norm(polarity_centroids(on, off, start, disk) - uv, axis=1)
    assert np.median(plain) > 0.3
    assert np.median(by_polarity) < 0.05 and by_polarity.max() < 0.15
    # Balanced polarities: the plain centroid is right too, and the two agree.
    on1, off1 = _moving_circle_events(uv, radius, np.asarray(shift), np.ones(len(uv)))
    a, b = refine_centroids(on1 + off1, start, disk), polarity_centroids(on1, off1, start, disk)
    assert np.median(np.linalg.norm(a - uv, axis=1)) < 0.05 and np.max(np.linalg.norm(a - b, axis=1)) < 0.1
    # A circle whose disk holds events of one polarity only keeps the both-polarity centroid.
    lone = polarity_centroids(on, np.zeros_like(off), start, disk)
    assert np.allclose(lone, refine_centroids(on, start, disk))


def test_the_blob_detector_takes_its_centres_from_the_polarity_images(monkeypatch):
    """With polarity_images, the blobs' centres are polarity_centroids' (on a rendered board, as bright blobs); the
    images must have the image's shape."""
    import plsgraph.frontend.detect as detect_module

    T = pose_facing(CIRCLES, 0.7, (0.5, 0.3, 1.0), front_z=-1)
    img = 1.0 - render_log_intensity(T, CAM, CIRCLES)  # bright circles
    calls = []

    def spy(on, off, uv, radius):
        calls.append(uv.shape)
        return detect_module.refine_centroids(on + off, uv, radius)

    monkeypatch.setattr(detect_module, "polarity_centroids", spy)
    plain = detect_circle_grid(img, CIRCLES, CAM, foreground="bright", blur_sigma=0.8)
    assert plain.ok and not calls
    det = detect_circle_grid(img, CIRCLES, CAM, foreground="bright", blur_sigma=0.8,
                             polarity_images=(0.5 * img, 0.5 * img))
    assert det.ok and calls
    assert np.median(np.linalg.norm(det.uv - truth_pixels(T, CIRCLES), axis=1)) < 0.15
    with pytest.raises(InputError):
        detect_circle_grid(img, CIRCLES, CAM, foreground="bright", polarity_images=(img[:10], img))


def _reference_centroids(weight: np.ndarray, uv: np.ndarray, radius: np.ndarray, iterations: int = 4) -> np.ndarray:
    """refine_centroids written out point by point in float64: the weight of the pixels whose centres lie within the
    radius, their weighted centroid, iterated; all points stop once every one moved by less than 1e-3 px."""
    h, w = weight.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = np.asarray(uv, dtype=float).copy()
    for _ in range(iterations):
        steps = np.zeros_like(uv)
        for i, (u, v) in enumerate(uv):
            if not np.isfinite(u + v):
                continue
            m = (xx - u) ** 2 + (yy - v) ** 2 <= radius[i] ** 2
            s = float(weight[m].astype(np.float64).sum())
            if s > 1e-9:
                steps[i] = [float((weight[m] * xx[m]).sum()) / s - u, float((weight[m] * yy[m]).sum()) / s - v]
        uv += steps
        if np.max(np.abs(steps)) < 1e-3:
            break
    return uv


def test_centroids_match_the_point_by_point_reference_anywhere_and_stacked():
    """refine_centroids (a padded image, only the offsets a disk can reach, float32 reads) gives the reference's centres
    for points inside the image, on its edges, outside it and far outside, with NaN points kept; a stack of ON and OFF
    images in one call gives what one call per image gives (each image's points stop as their own call would), and
    ``support`` is the disk's weight at the start."""
    from plsgraph.frontend.detect import _disk_weight, _polarity_mean, refine_centroids

    rng = np.random.default_rng(7)
    worst = 0.0
    for trial in range(40):
        h, w = (int(v) for v in rng.integers(20, 70, 2))
        on = rng.poisson(rng.uniform(0.05, 2.0), (h, w)).astype(np.float32)
        off = rng.poisson(rng.uniform(0.05, 2.0), (h, w)).astype(np.float32)
        if trial % 2:
            on, off = cv2.GaussianBlur(on, (0, 0), 0.7), cv2.GaussianBlur(off, (0, 0), 0.7)
        n = 12
        uv = np.column_stack([rng.uniform(-8, w + 8, n), rng.uniform(-8, h + 8, n)])
        uv[:3] = [[-1e4, 5.0], [w - 0.5 + 0.3, h / 2], [np.nan, 3.0]]
        r = rng.uniform(1.0, 7.0, n)
        got = refine_centroids(on, uv, r)
        ref = _reference_centroids(on, uv, r)
        assert np.isnan(got[2, 0]) and got[2, 1] == 3.0
        worst = max(worst, float(np.nanmax(np.abs(got - ref))))
        both, support = refine_centroids(np.stack([on, off]), np.concatenate([uv, uv]), np.concatenate([r, r]),
                                         image=np.repeat([0, 1], n), support=True)
        separate = np.concatenate([refine_centroids(on, uv, r), refine_centroids(off, uv, r)])
        assert np.nanmax(np.abs(both - separate)) < 1e-5
        np.testing.assert_allclose(np.nan_to_num(support[:n]), np.nan_to_num(_disk_weight(on, uv, r)), atol=1e-3)
        mean, lone = _polarity_mean(on, off, uv, r, support=True)
        assert np.nanmax(np.abs(mean - 0.5 * (separate[:n] + separate[n:]))) < 1e-5
    assert worst < 1e-4
