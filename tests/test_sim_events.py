"""Board renderer and ESIM-style event simulator: ground truth from projection, invariants, statistics."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from plsgraph.core.board import Board, load_board
from plsgraph.core.camera import CameraModel, davis346_default
from plsgraph.core.geometry import inv_T, make_T, so3_exp, transform_points
from plsgraph.errors import InputError
from plsgraph.sim.events import EventSimParams, _step_events, render_times, simulate_events
from plsgraph.sim.render import BoardRenderer, RenderParams, render_intensity_u8, render_log_intensity

T0 = 1_700_000_000.0  # epoch-like start: the simulator must keep sub-microsecond detail


@pytest.fixture(scope="module")
def board() -> Board:
    return load_board("acircles_4x11")


@pytest.fixture(scope="module")
def small_cam() -> CameraModel:
    K = np.array([[60.0, 0, 40.0], [0, 60.0, 30.0], [0, 0, 1]])
    return CameraModel(80, 60, K, np.array([-0.1, 0.02, 0.0, 0.0, 0.0]))


def _facing(board: Board, dist: float, rotvec=(0.0, 0.0, 0.0), offset=(0.0, 0.0, 0.0), flip: bool = False):
    """T_board_cam of a camera looking at the board centre from ``dist`` (from -z, or +z with ``flip``)."""
    R = so3_exp(np.asarray(rotvec, dtype=float))
    if flip:
        R = so3_exp([np.pi, 0.0, 0.0]) @ R
    c = board.points.mean(axis=0)
    return make_T(R, c + R @ np.array([0.0, 0.0, -dist]) + np.asarray(offset, dtype=float))


def _sweep(board: Board, dx: np.ndarray, dur: float, dist: float = 0.5, n: int = 41):
    """Camera translating sideways by dx(s) for s in [0, 1] over ``dur`` seconds."""
    s = np.linspace(0.0, 1.0, n)
    T = np.stack([_facing(board, dist, (0.1, -0.1, 0.05), (x, 0.0, 0.0)) for x in dx(s)])
    return T0 + s * dur, T


QUIET = dict(noise_rate_hz=0.0, contrast_sigma=0.0, refractory_s=0.0)


# -- renderer ----------------------------------------------------------------------------------------------


def test_rendered_circle_centres_match_projection(board):
    cam = davis346_default()
    T = _facing(board, 0.45, (0.2, -0.3, 0.1))
    img = render_intensity_u8(T, cam, board)
    ok, centres = cv2.findCirclesGrid(img, board.pattern_size, flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
    assert ok
    uv = cam.project(transform_points(inv_T(T), board.points))
    # Blob centroids of projected circles are biased by perspective by a small fraction of a pixel here.
    assert np.abs(centres.reshape(-1, 2) - uv).max() < 0.3


def test_a_circle_grid_seen_from_behind_is_blank(board):
    # A joystick drive of the third validation study went round the board and saw it from behind for 1.4 s; the
    # renderer drew the pattern mirrored there, and the front end labelled it (mirror check and all) as the board
    # seen from the front: 42 wrong detections. The back of a print is blank.
    cam = davis346_default()
    front = _facing(board, 0.45, (0.2, -0.3, 0.1))
    back = _facing(board, 0.45, (0.2, -0.3, 0.1), flip=True)
    assert front[2, 3] < 0 < back[2, 3]  # circle grids are printed on the board's -z face
    img_front, img_back = render_intensity_u8(front, cam, board), render_intensity_u8(back, cam, board)
    assert cv2.findCirclesGrid(img_front, board.pattern_size, flags=cv2.CALIB_CB_ASYMMETRIC_GRID)[0]
    assert not cv2.findCirclesGrid(img_back, board.pattern_size, flags=cv2.CALIB_CB_ASYMMETRIC_GRID)[0]
    uv = cam.project(transform_points(inv_T(back), board.points))
    inside = (uv[:, 0] > 5) & (uv[:, 0] < cam.width - 5) & (uv[:, 1] > 5) & (uv[:, 1] < cam.height - 5)
    assert inside.all()  # the board is in the image, and blank: no dark ink where the circles would be
    x, y = np.round(uv).astype(int).T
    assert img_back[y, x].min() > 0.8 * img_front.max()


def test_the_truth_counts_a_board_seen_from_behind_as_not_visible():
    from plsgraph.sim.robot import simulate_robot

    s = simulate_robot("rich", duration=4.0, seed=0, realism="ideal")
    uv, inside = s.project_truth()
    assert inside.any()
    z = s.T_board_cam[:, 2, 3]
    assert np.all(z < 0)  # this drive stays in front of the board
    import dataclasses

    flipped = s.T_board_cam.copy()
    # The same views turned by 180 degrees about the board's x axis: the camera on the other side, facing it.
    flipped[:, :3, :] = np.diag([1.0, -1.0, -1.0]) @ flipped[:, :3, :]
    assert not dataclasses.replace(s, T_board_cam=flipped).project_truth()[1].any()


def _tags_and_truth(img, T, cam, grid, border_bits: int = 1):
    """aruco tag36h11 corners and ids in ``img``, and the true corner pixels on a (2 rows, 2 cols) grid."""
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = border_bits
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), params)
    corners, ids, _ = det.detectMarkers(img)
    uv = cam.project(transform_points(inv_T(T), grid.points)).reshape(2 * grid.rows, 2 * grid.cols, 2)
    return corners, ids, uv, det


def test_rendered_aprilgrid_tags_decode_with_kalibr_corner_order():
    grid = Board(pattern="aprilgrid", cols=4, rows=3, tag_size=0.05, tag_spacing=0.3)
    cam = davis346_default()
    T = _facing(grid, 0.5, (0.15, 0.25, 0.1), flip=True)
    corners, ids, uv, det = _tags_and_truth(render_intensity_u8(T, cam, grid), T, cam, grid)
    assert ids is not None and sorted(ids.ravel().tolist()) == list(range(12))
    for c, k in zip(corners, ids.ravel(), strict=True):
        r, q = divmod(int(k), grid.cols)
        # aruco order: marker top-left, top-right, bottom-right, bottom-left (board y up on the print).
        expect = np.array([uv[2 * r + 1, 2 * q], uv[2 * r + 1, 2 * q + 1], uv[2 * r, 2 * q + 1], uv[2 * r, 2 * q]])
        # A wrong corner order would be off by a tag side (~25 px); aruco's corners sit ~0.4 px inside the
        # true square (its own bias on anti-aliased edges, also seen with supersampled renders).
        assert np.abs(c.reshape(4, 2) - expect).max() < 1.5
    # From behind, the print is mirrored and must not decode as tags.
    back = render_intensity_u8(_facing(grid, 0.5, (0.15, 0.25, 0.1)), cam, grid)
    _, ids_back, _ = det.detectMarkers(back)
    assert ids_back is None


def test_kalibr_tag_layout_has_a_two_bit_border_and_turned_codes():
    grid = Board(pattern="aprilgrid", cols=4, rows=3, tag_size=0.05, tag_spacing=0.3)
    cam = davis346_default()
    T = _facing(grid, 0.45, (0.1, 0.15, 0.05), flip=True)
    img = render_intensity_u8(T, cam, grid, RenderParams(tag_layout="kalibr"))
    corners, ids, uv, _ = _tags_and_truth(img, T, cam, grid, border_bits=2)
    assert ids is not None and sorted(ids.ravel().tolist()) == list(range(12))
    for c, k in zip(corners, ids.ravel(), strict=True):
        r, q = divmod(int(k), grid.cols)
        # Turned by 180 degrees: OpenCV's corner 0 is the printed tag's bottom-right.
        expect = np.array([uv[2 * r, 2 * q + 1], uv[2 * r, 2 * q], uv[2 * r + 1, 2 * q], uv[2 * r + 1, 2 * q + 1]])
        assert np.abs(c.reshape(4, 2) - expect).max() < 1.5


def test_analytic_antialiasing_agrees_with_supersampling(board, small_cam):
    T = _facing(board, 0.6, (0.3, 0.4, 0.2))
    one = BoardRenderer(small_cam, board, RenderParams(supersample=1)).intensity(T)
    many = BoardRenderer(small_cam, board, RenderParams(supersample=6)).intensity(T)
    diff = np.abs(one - many)
    assert diff.mean() < 0.01 and diff.max() < 0.2
    assert one.min() >= 0.05 * 0.99 and one.max() <= 0.9 * 1.01


def test_log_intensity_levels(board, small_cam):
    p = RenderParams(background_texture=0.0)
    L = render_log_intensity(_facing(board, 0.4), small_cam, board, p)
    assert L.dtype == np.float32 and L.shape == (60, 80)
    assert L.max() == pytest.approx(np.log(0.9 + 1e-3), abs=1e-5)  # white paper
    assert L.min() == pytest.approx(np.log(0.05 + 1e-3), abs=1e-5)  # black ink
    assert np.isclose(L, np.log(0.35 + 1e-3), atol=1e-5).any()  # the wall


def test_render_rejects_bad_pose(board, small_cam):
    with pytest.raises(InputError):
        render_log_intensity(np.full((4, 4), np.nan), small_cam, board)


# -- event generation ---------------------------------------------------------------------------------------


def test_step_events_by_hand():
    # One pixel whose log intensity rises 0 -> 1 over [0, 1] s with C = 0.25: crossings at 0.25, 0.5, 0.75, 1.0.
    L0, L1 = np.zeros(2, np.float32), np.array([1.0, 0.1], np.float32)
    c = np.full(2, 0.25, np.float32)
    ref, last = np.zeros(2, np.float32), np.full(2, -np.inf)
    ev = _step_events(L0, L1, 0.0, 1.0, ref, last, c, c, refractory=0.0)
    np.testing.assert_allclose(ev.t, [0.25, 0.5, 0.75, 1.0])
    assert ev.pix.tolist() == [0] * 4 and ev.p.tolist() == [1] * 4
    assert ref.tolist() == [1.0, 0.0] and last[0] == 1.0
    # With a 0.3 s refractory period only 0.25 and 0.75 survive, but the reference still moves by 4 C.
    ref, last = np.zeros(2, np.float32), np.full(2, -np.inf)
    ev = _step_events(L0, L1, 0.0, 1.0, ref, last, c, c, refractory=0.3)
    np.testing.assert_allclose(ev.t, [0.25, 0.75])
    assert ref[0] == 1.0
    # Falling by 0.6 from a reference 0.1 above L0: OFF crossings at levels -0.15 and -0.4.
    ref, last = np.array([0.1, 0.0], np.float32), np.full(2, -np.inf)
    ev = _step_events(L0, np.array([-0.6, 0.0], np.float32), 2.0, 3.0, ref, last, c, c, refractory=0.0)
    np.testing.assert_allclose(ev.t, [2.0 + 0.15 / 0.6, 2.0 + 0.4 / 0.6])
    assert ev.p.tolist() == [-1, -1] and ref[0] == pytest.approx(-0.4)


def test_events_integrate_to_the_log_intensity_change(board, small_cam):
    params = EventSimParams(contrast_on=0.2, contrast_off=0.3, **QUIET)
    t, T = _sweep(board, lambda s: 0.06 * s, 0.1)
    ev = simulate_events(t, T, small_cam, board, params)
    dL = (
        render_log_intensity(T[-1], small_cam, board, params.render)
        - render_log_intensity(T[0], small_cam, board, params.render)
    ).ravel()
    pix = ev.y.astype(np.intp) * small_cam.width + ev.x
    n_on = np.bincount(pix[ev.p > 0], minlength=dL.size)
    n_off = np.bincount(pix[ev.p < 0], minlength=dL.size)
    net = 0.2 * n_on - 0.3 * n_off
    # The reference stays within one threshold of the signal, so the emitted contrast tracks the change.
    assert np.all(net - dL < 0.3 + 1e-4) and np.all(dL - net < 0.2 + 1e-4)
    assert len(ev) > 1000


def test_stream_is_sorted_and_in_the_camera_clock(board, small_cam):
    t, T = _sweep(board, lambda s: 0.03 * s, 0.05)
    ev = simulate_events(t, T, small_cam, board, EventSimParams(noise_rate_hz=2.0), seed=3)
    assert ev.t.dtype == np.int64 and np.all(np.diff(ev.t) >= 0)
    assert ev.t[0] >= round(T0 * 1e9) and ev.t[-1] <= round(t[-1] * 1e9)
    assert ev.width == 80 and ev.height == 60
    again = simulate_events(t, T, small_cam, board, EventSimParams(noise_rate_hz=2.0), seed=3)
    assert np.array_equal(ev.t, again.t) and np.array_equal(ev.x, again.x) and np.array_equal(ev.p, again.p)


def test_event_count_grows_with_speed_and_contrast(board, small_cam):
    def count(dx: float, params: EventSimParams) -> int:
        t, T = _sweep(board, lambda s: dx * s, 0.1)
        return len(simulate_events(t, T, small_cam, board, params))

    base = EventSimParams(**QUIET)
    slow, fast = count(0.02, base), count(0.06, base)
    assert fast > 2.0 * slow  # over the same time, three times the path sweeps about three times the edges
    low_contrast = EventSimParams(render=RenderParams(black=0.4), **QUIET)
    assert count(0.04, low_contrast) < 0.6 * count(0.04, base)
    high_threshold = EventSimParams(contrast_on=0.5, contrast_off=0.5, **QUIET)
    assert count(0.04, high_threshold) < 0.6 * count(0.04, base)


def test_back_and_forth_motion_balances_polarities(board, small_cam):
    params = EventSimParams(noise_rate_hz=0.0, refractory_s=0.0, contrast_sigma=0.02)
    t, T = _sweep(board, lambda s: 0.05 * np.sin(2 * np.pi * s), 0.2, n=81)
    ev = simulate_events(t, T, small_cam, board, params, seed=1)
    assert len(ev) > 2000
    assert ev.n_on / ev.n_off == pytest.approx(1.0, abs=0.05)


def test_noise_rate_as_configured(board, small_cam):
    rate, dur = 5.0, 1.0
    t = T0 + np.array([0.0, dur])
    T = np.stack([_facing(board, 0.5)] * 2)  # static camera: only noise
    params = EventSimParams(noise_rate_hz=rate, noise_on_fraction=0.7)
    ev = simulate_events(t, T, small_cam, board, params, seed=2)
    expect = rate * small_cam.width * small_cam.height * dur
    assert abs(len(ev) - expect) < 4 * np.sqrt(expect)
    assert ev.n_on / len(ev) == pytest.approx(0.7, abs=0.02)
    quiet = simulate_events(t, T, small_cam, board, EventSimParams(noise_rate_hz=0.0))
    assert len(quiet) == 0


def test_refractory_period_is_respected(board, small_cam):
    refr = 2e-3
    params = EventSimParams(noise_rate_hz=0.0, refractory_s=refr)
    t, T = _sweep(board, lambda s: 0.08 * s, 0.1)
    ev = simulate_events(t, T, small_cam, board, params)
    pix = ev.y.astype(np.int64) * small_cam.width + ev.x
    order = np.lexsort((ev.t, pix))
    same = np.diff(pix[order]) == 0
    gaps = np.diff(ev.t[order])[same]
    assert gaps.size > 100 and gaps.min() >= refr * 1e9 - 2
    no_refr = simulate_events(t, T, small_cam, board, EventSimParams(noise_rate_hz=0.0, refractory_s=0.0))
    assert len(no_refr) > len(ev)


def test_adaptive_render_rate_follows_image_speed(board, small_cam):
    params = EventSimParams(max_px_per_step=0.5, min_rate_hz=10.0)
    t, T = _sweep(board, lambda s: 0.10 * s, 1.0)  # 0.1 m/s at 0.5 m: ~12 px/s with f = 60 px
    slow = render_times(t, T, small_cam, params)
    t, T = _sweep(board, lambda s: 0.40 * s, 1.0)
    fast = render_times(t, T, small_cam, params)
    assert fast.size > 3 * slow.size
    assert slow[0] == t[0] and slow[-1] == t[-1] and np.all(np.diff(slow) > 0)
    fixed = render_times(t, T, small_cam, EventSimParams(fixed_rate_hz=1000.0))
    assert fixed.size == 1001


def test_bad_trajectories_raise(board, small_cam):
    T = np.stack([_facing(board, 0.5)] * 3)
    with pytest.raises(InputError):
        simulate_events(np.array([0.0, 0.1, 0.1]), T, small_cam, board)
    with pytest.raises(InputError):
        simulate_events(np.array([0.0, 0.1]), T, small_cam, board)
    with pytest.raises(InputError):
        EventSimParams(contrast_on=0.0)


def test_leaky_surface_of_simulated_events_shows_the_board_where_it_is(board):
    # End to end: simulated events -> leaky integrator -> OpenCV's circle-grid finder, against the true pose.
    from plsgraph.frontend.surfaces import leaky_integrator, to_uint8

    cam = davis346_default()
    R = so3_exp([0.1, -0.2, 0.05])
    t = T0 + np.linspace(0.0, 0.15, 16)
    c = board.points.mean(axis=0)
    T = np.stack([make_T(R, c + R @ [0, 0, -0.5] + [0.4 * (s - t[0]) - 0.03, 0.1 * (s - t[0]), 0]) for s in t])
    ev = simulate_events(t, T, cam, board, EventSimParams(), seed=0)
    img = to_uint8(leaky_integrator(ev, tau_s=0.05))
    ok, centres = cv2.findCirclesGrid(img, board.pattern_size, flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
    assert ok
    uv = cam.project(transform_points(inv_T(T[-1]), board.points))
    assert np.abs(centres.reshape(-1, 2) - uv).max() < 1.0


def test_leaky_surface_of_simulated_events_shows_aprilgrid_tags():
    from plsgraph.frontend.surfaces import leaky_integrator, to_uint8

    grid = Board(pattern="aprilgrid", cols=4, rows=3, tag_size=0.05, tag_spacing=0.3)
    cam = davis346_default()
    t = T0 + np.linspace(0.0, 0.1, 11)
    T = np.stack([_facing(grid, 0.45, (0.1, -0.2, 0.05), (0.4 * (s - t[0]), 0.1 * (s - t[0]), 0), True) for s in t])
    ev = simulate_events(t, T, cam, grid, EventSimParams(), seed=0)
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11))
    _, ids, _ = det.detectMarkers(to_uint8(leaky_integrator(ev, tau_s=0.05)))
    assert ids is not None and len(ids) >= 6 and set(ids.ravel().tolist()) <= set(range(12))


def test_invalid_rotations_are_rejected(board, small_cam):
    T = np.stack([_facing(board, 0.5)] * 2)
    T[1, :3, :3] *= 1.1
    with pytest.raises(InputError):
        simulate_events(T0 + np.array([0.0, 0.1]), T, small_cam, board)


def test_warns_when_the_board_is_never_in_view(board, small_cam, caplog):
    away = make_T(so3_exp([0.0, np.pi, 0.0]), board.points.mean(axis=0) + [0.0, 0.0, -0.5])
    T = np.stack([away] * 2)  # in front of the board, looking away from it
    with caplog.at_level("WARNING", logger="plsgraph.sim.events"):
        simulate_events(T0 + np.array([0.0, 0.05]), T, small_cam, board, EventSimParams(noise_rate_hz=0.0))
    assert "never in view" in caplog.text
