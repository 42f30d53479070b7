"""Tracking by fitting circles at their predicted positions: small rims followed, shifted labels refused."""

from __future__ import annotations

import cv2
import numpy as np

from plsgraph.core.board import load_board
from plsgraph.frontend.detect import REASON_OK, detect_circle_grid, track_by_fitting

BOARD = load_board("acircles_4x11_a2")
W, H = 346, 260


def _board_pixels(scale: float, offset=(120.0, 40.0), shear: float = 0.05) -> np.ndarray:
    """Board points mapped into the image by a mild affine map (pixels per metre ``scale``)."""
    P = BOARD.points[:, :2]
    A = np.array([[scale, shear * scale], [-0.5 * shear * scale, scale]])
    return P @ A.T + np.asarray(offset)


def _rim_image(uv: np.ndarray, radius: float, gap_deg: float = 50.0) -> np.ndarray:
    """Activity image of one-pixel rims with two breaks where the edge runs along a horizontal motion."""
    img = np.zeros((H, W), np.uint8)
    S = 16  # sub-pixel drawing
    for u, v in uv:
        c = (int(round(u * S)), int(round(v * S)))
        r = int(round(radius * S))
        for a0, a1 in ((gap_deg / 2, 180 - gap_deg / 2), (180 + gap_deg / 2, 360 - gap_deg / 2)):
            cv2.ellipse(img, c, (r, r), 90, a0, a1, 1, 1, cv2.LINE_8, 4)
    return img.astype(bool)


def _spacing(uv: np.ndarray) -> float:
    d = np.linalg.norm(uv[:, None] - uv[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def test_small_rims_are_tracked_from_a_rough_prediction():
    uv = _board_pixels(220.0)  # circles ~9 px across at this scale: ~1.5 m for a DAVIS346
    img = _rim_image(uv, radius=0.5 * 0.04 * 220.0 * 0.9)
    s = _spacing(uv)
    pred = uv + np.array([0.2 * s, -0.1 * s])  # the board moved since the prediction
    det = track_by_fitting(img, pred, BOARD)
    assert det.ok, det.reason
    err = np.linalg.norm(det.uv - uv, axis=1)
    assert np.nanmedian(err) < 0.3 and det.n_seen >= 40
    # Through detect_circle_grid, as the front end calls it, with a region of interest.
    det2 = detect_circle_grid(img.astype(np.float32), BOARD, foreground="rims", rim_threshold=0.5,
                              roi=(60, 0, 346, 260), predicted_uv=pred)
    assert det2.reason == REASON_OK and np.nanmedian(np.linalg.norm(det2.uv - uv, axis=1)) < 0.3


def test_a_prediction_off_by_a_lattice_step_is_refused():
    uv = _board_pixels(220.0)
    img = _rim_image(uv, radius=0.5 * 0.04 * 220.0 * 0.9)
    step = BOARD.square_size * 220.0  # one lattice step (s, s) on the board
    for shift in ([step, step], [-step, step], [2 * step, 0.0], [0.0, 2 * step]):
        pred = uv + np.asarray(shift)
        det = track_by_fitting(img, pred, BOARD)
        if det.ok:  # only acceptable if it is right (it cannot be: the labels would be shifted)
            assert np.nanmedian(np.linalg.norm(det.uv - uv, axis=1)) < 0.5
        assert not det.ok


def test_board_cut_by_the_image_border_is_not_tracked_blindly():
    uv = _board_pixels(220.0, offset=(200.0, 40.0))  # right columns outside the image
    img = _rim_image(uv, radius=0.5 * 0.04 * 220.0 * 0.9)
    step = BOARD.square_size * 220.0
    det = track_by_fitting(img, uv + np.array([step, step]), BOARD)
    assert not det.ok
