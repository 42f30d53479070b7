"""The streaming front end sees the same windows as the single pass, in memory bounded by its span."""

import numpy as np
import pytest
from realdata import DATA_DIR

from plsgraph.core.board import load_board
from plsgraph.frontend.track import (
    camera_track_from_event_chunks,
    camera_track_from_events,
    time_order,
)
from plsgraph.io.events_reader import iter_event_chunks, read_events
from plsgraph.io.recording import read_recording

SAMPLE = DATA_DIR / "sample" / "rich_sample.mcap"


def test_streaming_matches_single_pass_on_the_sample():
    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    stream = read_events(SAMPLE).slice_time(0, read_events(SAMPLE).t_first + 4_000_000_000)  # first 4 s
    one = camera_track_from_events(stream, camera, board, kind="count")
    chunks = (c for c in iter_event_chunks(SAMPLE, chunk_events=100_000) if c.t_first < stream.t_last)
    streamed = camera_track_from_event_chunks(
        (c.slice_time(0, stream.t_last + 1) for c in chunks), camera, board, kind="count", span_s=1.0,
        history_s=0.5,
    )
    assert streamed.info["windows"] == one.info["windows"]  # the same window grid
    assert abs(len(streamed) - len(one)) <= 0.1 * len(one)
    for track in (one, streamed):  # per detection, as the track's frames
        assert len(track.info["span_windows"]) == len(track.info["detector"]) == len(track)
    # The board is found in the same windows.
    wa, wb = np.asarray(one.info["window_t"]), np.asarray(streamed.info["window_t"])
    both, i, j = np.intersect1d(wa, wb, return_indices=True)
    assert both.size >= 0.9 * len(one)
    # Which span of events a window's board is found on depends on the span that worked in the window before (the
    # ladder starts with it), and tracking restarts at each streamed span: for a stretch of windows after a restart
    # the two can keep different rungs, each finding the board (here 13-26 windows of 119, on 0.5 against 1 window's
    # events, or 4 against 1). Where both used the same span, they found the same board at the same stamp.
    same = np.asarray(one.info["span_windows"])[i] == np.asarray(streamed.info["span_windows"])[j]
    assert np.count_nonzero(same) >= 0.6 * len(one)
    assert np.median(np.abs(one.t[i[same]] - streamed.t[j[same]])) < 1e-9
    d = np.abs(one.T_board_cam[i[same], :3, 3] - streamed.T_board_cam[j[same], :3, 3]).max(axis=1)
    assert np.median(d) < 1e-6


def test_windows_longer_than_the_history_keep_all_their_events():
    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    full = read_events(SAMPLE)
    stream = full.slice_time(0, full.t_first + 3_000_000_000)
    one = camera_track_from_events(stream, camera, board, rate_hz=1.25, kind="count")  # 0.8 s windows
    streamed = camera_track_from_event_chunks(
        (c.slice_time(0, stream.t_last + 1) for c in iter_event_chunks(SAMPLE, chunk_events=100_000)
         if c.t_first < stream.t_last),
        camera, board, rate_hz=1.25, kind="count", span_s=0.5, history_s=0.2,
    )
    assert streamed.info["windows"] == one.info["windows"]
    assert streamed.info["events_used"] == one.info["events_used"]
    assert streamed.info["late_events"] == 0



def test_detections_out_of_order_across_spans_are_put_in_time_order():
    """A detection stamped before earlier ones (a long-span find, stamped half its span back, or its events inside a
    previous streamed span) keeps its place in time: the track is strictly increasing (a realistic recording once
    ended with 'times must be strictly increasing'), and of two detections with one stamp the shorter span's stays."""
    t = np.array([1.0, 3.0, 2.0, 2.5, 4.0, 3.0])
    span = np.array([1, 1, 8, 4, 1, 16])
    keep = time_order(t, span)
    assert t[keep].tolist() == [1.0, 2.0, 2.5, 3.0, 4.0]
    assert keep.tolist() == [0, 2, 3, 1, 4]  # stamp 3.0 from the one-window find, not the 16-window one
    # Stamps on an epoch clock that differ only by rounding (window-centre stamps of nested spans) are one stamp.
    t0 = 1_767_225_600.0
    near = np.array([t0 + 5.0, t0 + 5.0 + 4.8e-7, t0 + 5.1])
    assert time_order(near, np.array([4, 2, 1])).tolist() == [1, 2]
    assert time_order(np.zeros(0)).size == 0


def test_spans_detected_in_parallel_give_the_same_track():
    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    full = read_events(SAMPLE)
    t_end = full.t_first + 4_000_000_000

    def streamed(workers):
        chunks = (c.slice_time(0, t_end + 1) for c in iter_event_chunks(SAMPLE, chunk_events=100_000)
                  if c.t_first < t_end)
        return camera_track_from_event_chunks(chunks, camera, board, kind="count", span_s=1.0, history_s=0.5,
                                              workers=workers)

    one, two = streamed(1), streamed(2)
    assert np.array_equal(one.t, two.t)
    assert np.array_equal(one.T_board_cam, two.T_board_cam)
    assert one.info["window_outcomes"] == two.info["window_outcomes"]
    assert one.info["skipped"] == two.info["skipped"] and one.info["detector"] == two.info["detector"]
    assert one.info["span_windows"] == two.info["span_windows"]
    # The spans' bookkeeping is summed over all of them (it held the first span's alone): every detection made is
    # counted by its span, including the few the track drops afterwards (same stamp, no pose).
    ladder = one.info["detected_at_window_fraction"]
    assert len(one) <= sum(ladder.values()) <= len(one) + 3 and ladder == two.info["detected_at_window_fraction"]


def test_work_done_while_the_workers_finish_costs_the_front_end_nothing():
    """``while_waiting`` runs once, after the whole stream is read and while the workers still detect; what it raises
    is logged and the track is the same (the pipeline imports the refinement there)."""
    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    full = read_events(SAMPLE)
    t_end = full.t_first + 3_000_000_000
    calls = []

    def streamed(while_waiting):
        chunks = (c.slice_time(0, t_end + 1) for c in iter_event_chunks(SAMPLE, chunk_events=100_000)
                  if c.t_first < t_end)
        return camera_track_from_event_chunks(chunks, camera, board, kind="count", span_s=1.0, history_s=0.5,
                                              workers=2, while_waiting=while_waiting)

    def fails():
        calls.append("fails")
        raise RuntimeError("boom")

    plain = streamed(lambda: calls.append("ok"))
    failing = streamed(fails)
    assert calls == ["ok", "fails"]
    assert np.array_equal(plain.t, failing.t) and np.array_equal(plain.T_board_cam, failing.T_board_cam)

    # An interrupt inside the import of a compiled module comes out as its ImportError: the interrupt, not logged.
    def interrupted_import():
        calls.append("interrupted")
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    with pytest.raises(KeyboardInterrupt):
        streamed(interrupted_import)
    assert calls[-1] == "interrupted"


def test_a_span_handed_over_as_chunks_lets_them_go_once_joined():
    """A worker joins the span's chunks and empties the list it was handed (the task holds that list until it returns:
    otherwise every span was in the worker's memory twice); the detections are those of the joined span."""
    import numpy as np

    from plsgraph.core.events import EventStream
    from plsgraph.frontend.track import _detect_span

    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    chunks = []
    for c in iter_event_chunks(SAMPLE, chunk_events=50_000):
        chunks.append(c)
        if c.t_last - chunks[0].t_first > 2_000_000_000:
            break
    joined = EventStream.concatenate(list(chunks))
    q = np.arange(joined.t_first + 33_333_333, joined.t_first + 2_000_000_000, 33_333_333, dtype=np.int64)
    handed = list(chunks)
    a = _detect_span((handed, camera, board, 30.0, "count", q, {}, None))
    b = _detect_span((joined, camera, board, 30.0, "count", q, {}, None))
    assert handed == [] and len(chunks) > 1
    assert np.array_equal(a[0].t, b[0].t) and np.array_equal(a[0].uv, b[0].uv, equal_nan=True)


def test_poses_solved_in_the_workers_are_those_solved_after_them():
    """With two worker processes each detection's PnP is solved in the worker that found it (streamed or in memory):
    the track is the one PnP in the calling process gives, bit for bit."""
    from plsgraph.frontend.track import _track_from_detections, detect_in_events

    board = load_board("acircles_4x11_a2")
    camera = read_recording(SAMPLE, with_events=False).camera
    stream = read_events(SAMPLE).slice_time(0, read_events(SAMPLE).t_first + 3_000_000_000)
    beside = camera_track_from_events(stream, camera, board, kind="count", workers=2)
    dets, info = detect_in_events(stream, camera, board, 30.0, "count", workers=2)
    after = _track_from_detections(dets, info, camera, 1.5, None)
    assert len(beside) == len(after) > 50 and "_poses" not in beside.info
    for a, b in [(beside.t, after.t), (beside.T_board_cam, after.T_board_cam), (beside.cov, after.cov),
                 (beside.rms_px, after.rms_px), (beside.detections.uv, after.detections.uv)]:
        np.testing.assert_array_equal(a, b)
    chunks = (c for c in iter_event_chunks(SAMPLE, chunk_events=100_000) if c.t_first < stream.t_last)
    streamed = camera_track_from_event_chunks((c.slice_time(0, stream.t_last + 1) for c in chunks), camera, board,
                                              kind="count", span_s=1.0, history_s=0.5, workers=2)
    single = camera_track_from_event_chunks(
        (c.slice_time(0, stream.t_last + 1) for c in iter_event_chunks(SAMPLE, chunk_events=100_000)
         if c.t_first < stream.t_last), camera, board, kind="count", span_s=1.0, history_s=0.5, workers=1)
    for a, b in [(streamed.t, single.t), (streamed.T_board_cam, single.T_board_cam), (streamed.cov, single.cov)]:
        np.testing.assert_array_equal(a, b)
