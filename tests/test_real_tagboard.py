"""Tag detection on a real DAVIS346 recording of a 4 x 3 tag36h11 board (shared/data/real, 1 s, 0.57 M events).

No ground truth exists for this recording; the tests check invariants: ids belong to the board, the
corners of all tags seen together fit the Kalibr layout with one homography (and not the other print
orientation), and the front end turns the recording into poses in front of the board.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from realdata import SHARED_REAL_DIR

from plsgraph.core.board import aprilgrid_points, load_board
from plsgraph.core.camera import davis346_default
from plsgraph.frontend import surfaces
from plsgraph.frontend.detect import aprilgrid_corner_index, detect_tags, make_aruco_detector
from plsgraph.frontend.track import camera_track_from_events

MCAP = SHARED_REAL_DIR / "davis346_tagboard.mcap"
pytestmark = pytest.mark.skipif(not MCAP.is_file(), reason="real recording not available")
BOARD = load_board("aprilgrid_4x3_tagboard")


def test_the_board_file_says_the_tags_border():
    assert BOARD.tag_border_bits == 1 and load_board("aprilgrid_6x6").tag_border_bits == 2


@pytest.fixture(scope="module")
def events():
    from plsgraph.io.events_reader import read_events

    return read_events(MCAP)


def query_times(ev, rate=30.0):
    period = int(round(1e9 / rate))
    return np.arange(ev.t_first + period, ev.t_last + 1, period, dtype=np.int64)


def tags_per_window(ev, kind, blur=0.0, **kw):
    det = make_aruco_detector(border_bits=BOARD.tag_border_bits)
    out = []
    for t in query_times(ev):
        img = surfaces.surface_at(ev, int(t), kind, **kw)
        if blur:
            img = cv2.GaussianBlur(img, (0, 0), blur)
        out.append(detect_tags(surfaces.to_uint8(img), det))
    return out


def homography_rms(ids, corners, layout, spacing):
    P = aprilgrid_points(BOARD.cols, BOARD.rows, 1.0, spacing)[aprilgrid_corner_index(ids, BOARD.cols, layout).ravel()]
    img = corners.reshape(-1, 2)
    H, _ = cv2.findHomography(P[:, :2], img, 0)
    ph = np.c_[P[:, :2], np.ones(len(P))] @ H.T
    return float(np.sqrt(np.mean(np.sum((ph[:, :2] / ph[:, 2:] - img) ** 2, axis=1))))


def test_intensity_like_surface_reveals_board_layout(events):
    found = tags_per_window(events, "leaky", blur=1.0, tau_s=0.3, window_ns=900_000_000)
    ids = np.concatenate([f.ids for f in found])
    assert ids.size >= 15  # measured: 29 tags in 30 windows (scripts/measure_frontend.py)
    assert np.all((ids >= 0) & (ids < BOARD.cols * BOARD.rows))
    multi = [f for f in found if f.ids.size >= 3]
    assert len(multi) >= 2
    for f in multi:
        # Kalibr's layout (tag 0 bottom-left, OpenCV's corner 0 at the printed tag's bottom-right) fits to
        # about a pixel without intrinsics; the OpenCV-upright layout does not fit at all.
        assert homography_rms(f.ids, f.corners, "kalibr", BOARD.tag_spacing) < 2.5
        assert homography_rms(f.ids, f.corners, "opencv", BOARD.tag_spacing) > 20.0


def test_edge_surfaces_find_fewer_tags(events):
    """Event edges alone (no filled black and white cells) hardly ever decode as tags."""
    leaky = sum(f.ids.size for f in tags_per_window(events, "leaky", blur=1.0, tau_s=0.3, window_ns=900_000_000))
    for kind, kw in [("count", {"window_ns": 33_333_333}), ("polarity_aware", {"window_ns": 33_333_333})]:
        assert sum(f.ids.size for f in tags_per_window(events, kind, **kw)) < leaky


def test_front_end_on_real_tags(events):
    cam = davis346_default()  # the recording has no intrinsics; the nominal preset stands in
    track = camera_track_from_events(
        events, cam, BOARD, 30.0, "leaky", surface_params={"tau_s": 0.3}, window_s=0.9,
        tag_layout="kalibr", max_rms_px=5.0,  # the board file says its tags' 1-bit border
    )
    assert len(track) >= 3
    assert track.info["poses"] + sum(track.info["skipped"].values()) == track.info["windows"]
    # Kalibr boards face +z: every camera must be in front of the board, a few tag sizes away.
    z = track.T_board_cam[:, 2, 3]
    assert np.all(z > 1.0) and np.all(z < 20.0)
    assert np.all(track.rms_px < 5.0)
