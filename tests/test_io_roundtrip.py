"""Writer -> reader round trips on simulated data, and the written files against independent decoders."""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.core.camera import CameraModel
from plsgraph.core.events import EventStream
from plsgraph.errors import InputError, RecordingError
from plsgraph.io import (
    JointStates,
    OdometryMsgs,
    inspect_recording,
    iter_event_chunks,
    read_events,
    read_recording,
    read_truth,
    write_recording,
)

T0 = 1_700_000_000_123_456_000


def _sim(n=30_000, seconds=1.5, seed=0, whole_us=True):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, int(seconds * 1e6), n)) * 1000 + T0
    if not whole_us:
        t = np.sort(t + rng.integers(0, 1000, n))
    ev = EventStream.from_arrays(t, rng.integers(0, 346, n), rng.integers(0, 260, n), rng.random(n) < 0.5, 346, 260)
    tj = T0 + np.arange(0, int(seconds * 1e9), 20_000_000)
    names = ("front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel")
    js = JointStates(tj, names, rng.normal(size=(tj.size, 4)), rng.normal(size=(tj.size, 4)))
    q = rng.normal(size=(tj.size, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v3 = lambda: rng.normal(size=(tj.size, 3))
    od = OdometryMsgs(tj, v3(), q, v3(), v3())
    K = np.array([[320.5, 0, 171.2], [0, 321.0, 129.9], [0, 0, 1]])
    cam = CameraModel(346, 260, K, [-0.2, 0.05, 1e-3, -2e-3, 0])
    return ev, js, od, cam


@pytest.mark.parametrize("fmt", ["dvs", "libcaer_cmp", "evt3", "libcaer", "mono"])
def test_round_trip_bit_exact(tmp_path, fmt):
    ev, js, od, cam = _sim()
    p = tmp_path / f"sim_{fmt}.mcap"
    truth = {"T_base_cam": np.eye(4), "td": 0.012}
    # evt3's sensor clock starts 0.5 s before its 24-bit rollover, so the recording crosses it.
    rep = write_recording(p, ev, js, od, cam, truth, event_format=fmt, evt3_sensor_start_us=2**24 - 500_000)
    assert rep["warnings"] == []
    rec = read_recording(p)
    assert rec.warnings == () and rec.lost == {}
    assert rec.event_encoding == fmt
    for a in "txyp":
        np.testing.assert_array_equal(getattr(rec.events, a), getattr(ev, a))
    assert (rec.events.width, rec.events.height) == (346, 260)
    np.testing.assert_array_equal(rec.joints.t, js.t)
    assert rec.joints.names == js.names
    np.testing.assert_array_equal(rec.joints.position, js.position)
    np.testing.assert_array_equal(rec.joints.velocity, js.velocity)
    left, right, _, _ = rec.joints.wheels()
    np.testing.assert_allclose(left, js.position[:, [0, 2]].mean(axis=1))
    np.testing.assert_allclose(right, js.position[:, [1, 3]].mean(axis=1))
    for a in ("t", "position", "orientation", "linear", "angular"):
        np.testing.assert_array_equal(getattr(rec.odometry, a), getattr(od, a))
    np.testing.assert_array_equal(rec.camera.K, cam.K)
    np.testing.assert_array_equal(rec.camera.dist, cam.dist)
    assert read_truth(p)["td"] == 0.012
    np.testing.assert_array_equal(read_truth(p)["T_base_cam"], np.eye(4))


def test_written_file_decodes_with_mcap_ros2(tmp_path):
    """The generic ROS 2 decoder (schema text + CDR) reads what we wrote: the file is standard ROS 2 MCAP."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    ev, js, od, cam = _sim(n=3000, seconds=0.2)
    p = tmp_path / "dvs.mcap"
    write_recording(p, ev, js, od, cam, event_format="dvs")
    xs, seen = [], set()
    with open(p, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        assert r.get_header().profile == "ros2"
        for schema, _ch, _m, msg in r.iter_decoded_messages():
            assert schema.encoding == "ros2msg"
            seen.add(schema.name)
            if schema.name == "dvs_msgs/msg/EventArray":
                xs += [e.x for e in msg.events]
                assert msg.events[-1].ts.sec * 10**9 + msg.events[-1].ts.nanosec == msg.header.stamp.sec * 10**9 + (
                    msg.header.stamp.nanosec
                )
            elif schema.name == "sensor_msgs/msg/JointState":
                assert list(msg.name) == list(js.names)
            elif schema.name == "sensor_msgs/msg/CameraInfo":
                assert msg.k[0] == cam.fx and msg.d[0] == cam.dist[0]
    assert seen == {"dvs_msgs/msg/EventArray", "sensor_msgs/msg/JointState", "nav_msgs/msg/Odometry",
                    "sensor_msgs/msg/CameraInfo"}
    np.testing.assert_array_equal(xs, ev.x)


def test_packet_formats_round_sub_microsecond_times_with_warning(tmp_path):
    ev, _, _, _ = _sim(n=2000, seconds=0.1, whole_us=False)
    rep = write_recording(tmp_path / "a.mcap", ev, None, None, None, event_format="libcaer_cmp")
    assert any("microsecond" in w for w in rep["warnings"])
    back = read_events(tmp_path / "a.mcap")
    assert np.max(np.abs(back.t - ev.t)) <= 500
    np.testing.assert_array_equal(back.x, ev.x)
    # The dvs format keeps nanoseconds.
    write_recording(tmp_path / "b.mcap", ev, None, None, None, event_format="dvs")
    np.testing.assert_array_equal(read_events(tmp_path / "b.mcap").t, ev.t)


def test_overwrite_refused_and_bad_arguments(tmp_path):
    ev, _, _, _ = _sim(n=100, seconds=0.05)
    p = tmp_path / "x.mcap"
    write_recording(p, ev, None, None, None)
    size = p.stat().st_size
    with pytest.raises(InputError, match="overwrite=True"):
        write_recording(p, ev, None, None, None)
    assert p.stat().st_size == size
    write_recording(p, ev, None, None, None, event_format="evt3", overwrite=True)
    assert read_recording(p).event_encoding == "evt3"
    with pytest.raises(InputError):
        write_recording(tmp_path / "y.mcap", ev, None, None, None, event_format="evt2")
    with pytest.raises(InputError):
        write_recording(tmp_path / "z.mcap", None, None, None, None)


def test_chunks_bounded_and_window(tmp_path):
    ev, _, _, _ = _sim(n=40_000, seconds=1.0)
    p = tmp_path / "c.mcap"
    write_recording(p, ev, None, None, None, event_format="libcaer_cmp")
    chunks = list(iter_event_chunks(p, chunk_events=5000))
    # A chunk closes at the first message that reaches the size: at most one 10 ms packet (~400 events) over.
    assert len(chunks) >= 7 and max(len(c) for c in chunks) < 5000 + 1000
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), ev.t)
    t0, t1 = T0 + 300_000_000, T0 + 420_000_000
    np.testing.assert_array_equal(read_events(p, t0=t0, t1=t1).t, ev.slice_time(t0, t1).t)


def test_topic_errors_list_the_file(tmp_path):
    ev, js, _, _ = _sim(n=500, seconds=0.1)
    p = tmp_path / "t.mcap"
    write_recording(p, ev, js, None, None)
    with pytest.raises(RecordingError, match="/joint_states"):
        read_events(p, topic="/nope")
    with pytest.raises(RecordingError, match="not an event type plsgraph reads"):
        read_events(p, topic="/joint_states")
    with pytest.raises(RecordingError, match="/dvs/events"):
        read_recording(p, topics={"odometry": "/odom"})
    rec = read_recording(p)
    assert rec.odometry is None and rec.camera is None and len(rec.joints) == len(js)
    with pytest.raises(RecordingError, match="no event topic"):
        p2 = tmp_path / "j.mcap"
        write_recording(p2, None, js, None, None)
        read_events(p2)


def test_inspect_counts(tmp_path):
    ev, js, od, cam = _sim(n=5000, seconds=0.5)
    p = tmp_path / "i.mcap"
    rep = write_recording(p, ev, js, od, cam, event_format="evt3")
    info = inspect_recording(p)
    rows = {r["topic"]: r for r in info["topics"]}
    e = rows["/event_camera/events"]
    assert e["messages"] == rep["messages"]["/event_camera/events"]
    assert (e["events"], e["events_on"], e["events_off"]) == (len(ev), ev.n_on, ev.n_off)
    assert (e["t_first_ns"], e["t_last_ns"], e["width"], e["height"]) == (ev.t_first, ev.t_last, 346, 260)
    assert rows["/odom"]["messages"] == len(od) and "events" not in rows["/odom"]
    assert rows["/joint_states"]["t_first_ns"] == js.t[0]


@pytest.mark.parametrize("fmt", ["dvs", "libcaer_cmp"])
def test_events_outside_sensor_dropped_with_warning(tmp_path, fmt):
    ev, _, _, _ = _sim(n=2000, seconds=0.1)
    # Declare a smaller sensor than the events cover (validate=False skips the constructor's own check).
    small = EventStream.from_arrays(ev.t, ev.x, ev.y, ev.p, 200, 260, validate=False)
    p = tmp_path / "o.mcap"
    write_recording(p, small, None, None, None, event_format=fmt)
    rec = read_recording(p)
    inside = ev.x < 200
    np.testing.assert_array_equal(rec.events.t, ev.t[inside])
    np.testing.assert_array_equal(rec.events.x, ev.x[inside])
    assert any(f"dropped {int((~inside).sum())} events outside the sensor" in w for w in rec.warnings)


def test_streaming_memory_does_not_grow_with_recording_length(tmp_path):
    import tracemalloc

    peaks = []
    for n in (100_000, 400_000):
        ev, _, _, _ = _sim(n=n, seconds=n / 1e6)
        p = tmp_path / f"m{n}.mcap"
        write_recording(p, ev, None, None, None, event_format="libcaer_cmp", chunk_bytes=1 << 16)
        del ev
        tracemalloc.start()
        total = sum(len(c) for c in iter_event_chunks(p, chunk_events=20_000))
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert total == n
    # 4x the events, about the same peak (one event chunk plus one 64 kB container chunk); a whole-stream
    # read would need 13 bytes per event, i.e. over 5 MB for the longer file.
    assert peaks[1] < 1.3 * peaks[0] and peaks[1] < 3e6


def test_a_recording_without_camera_info_says_so_without_pointing_at_warnings_it_does_not_have(tmp_path):
    # Before: "no usable sensor_msgs/CameraInfo (...: see the warnings)" where there was no such topic and no warning.
    from plsgraph.errors import InputError
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, read_inputs

    ev, js, od, _ = _sim(n=3000, seconds=0.5)
    p = tmp_path / "nocam.mcap"
    write_recording(p, ev, js, None, None, event_format="dvs")
    run = Run(p, CalibrationOptions(board="acircles_4x11"))
    with pytest.raises(InputError) as e:
        read_inputs(run)
    msg = str(e.value)
    assert "has no sensor_msgs/CameraInfo topic" in msg and "--camera-info" in msg
    assert "see the warnings" not in msg and "odometry file" not in msg
    # A topic whose every message is unusable: named once, with what the reader said of it (it said
    # "/dvs/camera_info: /dvs/camera_info: none of ...").
    bad = CameraModel(346, 260, np.array([[320.5, 0, 171.2], [0, 321.0, 129.9], [0, 0, 1]]), [0, 0, 0, 0, 0])
    object.__setattr__(bad, "K", np.array([[np.nan, 0, 171.2], [0, 321.0, 129.9], [0, 0, 1]]))  # past its checks
    q = tmp_path / "nancam.mcap"
    write_recording(q, ev, js, None, bad, event_format="dvs")
    with pytest.raises(InputError) as e:
        read_inputs(Run(q, CalibrationOptions(board="acircles_4x11")))
    msg = str(e.value)
    assert msg.count("/dvs/camera_info") == 1 and "none of its" in msg, msg



class _Recorder:
    """A progress factory (label -> context manager that is also ``progress(done, total)``) that keeps what it is
    told: ``calls`` [(label, [(done, total), ...]), ...]."""

    def __init__(self):
        self.calls: list = []

    def __call__(self, label):
        seen: list = []
        self.calls.append((label, seen))

        class _Bar:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                pass

            def __call__(self, done, total):
                seen.append((done, total))

        return _Bar()


def test_inspect_reports_progress_against_the_files_index_and_nothing_without_one(tmp_path, monkeypatch):
    from plsgraph.io import inspect as inspect_module

    monkeypatch.setattr(inspect_module, "PROGRESS_EVERY", 8)
    ev, js, od, cam = _sim(n=5000, seconds=0.5)
    p = tmp_path / "i.mcap"
    rep = write_recording(p, ev, js, od, cam, event_format="evt3")
    total = sum(rep["messages"].values())
    bars = _Recorder()
    info = inspect_recording(p, progress=bars)
    ((label, seen),) = bars.calls
    assert label == "reading recording" and seen[-1] == (total, total) and len(seen) > 2
    assert all(t == total for _, t in seen) and all(a < b for (a, _), (b, _) in zip(seen, seen[1:], strict=False))
    assert info == inspect_recording(p)  # the same summary with or without a bar
    # Cut short: no index, so no count to measure against; what is left is listed (with warnings), without a bar.
    q = tmp_path / "cut.mcap"
    q.write_bytes(p.read_bytes()[: p.stat().st_size * 2 // 3])
    bars = _Recorder()
    assert any("truncated" in w for w in inspect_recording(q, progress=bars)["warnings"])
    ((_, seen),) = bars.calls
    assert seen == []


def test_nan_joint_positions_are_said_not_filled_in_silently(tmp_path):
    ev, js, od, cam = _sim(n=2000, seconds=1.0)
    pos = js.position.copy()
    pos[[3, 7, 8], 0] = np.nan  # front_left_wheel: three messages with a NaN angle
    pos[12, 2] = np.inf
    pos[:, 3] = np.nan  # rear_right_wheel: no position at all (a joint without a position interface), not damage
    p = tmp_path / "nan.mcap"
    write_recording(p, None, JointStates(js.t, js.names, pos, js.velocity), None, cam)
    rec = read_recording(p, with_events=False)
    (w,) = [w for w in rec.warnings if "NaN or infinite" in w]
    assert "'front_left_wheel' in 3" in w and "'rear_left_wheel' in 1" in w and f"of {js.t.size} messages" in w
    assert "rear_right_wheel" not in w
    # The values themselves stay what the messages said (the wheel track fills them in).
    assert np.isnan(rec.joints.position[3, 0]) and np.isinf(rec.joints.position[12, 2])
    clean = tmp_path / "clean.mcap"
    write_recording(clean, None, js, None, cam)
    assert not any("NaN" in w for w in read_recording(clean, with_events=False).warnings)


def test_events_too_short_to_calibrate_are_said_to_be_so_with_advice_to_record_longer(tmp_path):
    # Before: a 1 s event file was searched for the board and refused with "no board detected ... try another surface
    # kind", advice that cannot help.
    from plsgraph.api import diagnose
    from plsgraph.errors import InsufficientDataError
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, build_tracks

    ev, js, _, cam = _sim(n=20_000, seconds=1.2)
    tj = (js.t - js.t[0]) * 1e-9
    wheels = np.column_stack([2.0 * tj, 2.5 * tj, 2.0 * tj, 2.5 * tj])  # a robot driving an arc
    p = tmp_path / "short.mcap"
    write_recording(p, ev, JointStates(js.t, js.names, wheels, np.zeros_like(wheels)), None, cam, event_format="evt3")
    with pytest.raises(InsufficientDataError, match=r"the events \(/event_camera/events\) span only 1\.\d\d s; a "
                                                    r"calibration needs .*at least 2 s") as e:
        build_tracks(Run(p, CalibrationOptions(board="acircles_4x11")))
    assert e.value.advice.startswith("record longer")
    d = diagnose(p, board="acircles_4x11")
    assert not d.ok and "span only" in d.problems[0] and d.advice[0].startswith("record longer")


@pytest.mark.parametrize("fmt", ["evt3", "dvs"])
def test_event_messages_recorded_twice_are_read_once_and_said(tmp_path, fmt):
    # Before: a recording holding each event message twice gave every event twice (evt3's stateful decoding read
    # the copy on) and "N messages start before the previous one ended (overlapping packets)".
    from recordings import copy_mcap

    ev, js, _, cam = _sim(n=20_000, seconds=0.5)
    p = tmp_path / "once.mcap"
    write_recording(p, ev, js, None, cam, event_format=fmt)
    twice = tmp_path / "twice.mcap"
    copy_mcap(p, twice, lambda topic: 2 if topic.endswith("events") else 1)
    once, again = read_recording(p), read_recording(twice)
    np.testing.assert_array_equal(again.events.t, once.events.t)
    np.testing.assert_array_equal(again.events.x, once.events.x)
    (said,) = [w for w in again.warnings if "byte for byte" in w]
    (row,) = [r for r in inspect_recording(p)["topics"] if "events" in r]
    assert f"{row['messages']} event messages were byte for byte" in said
    assert not any("overlapping" in w for w in again.warnings) and not once.warnings
    (row,) = [r for r in inspect_recording(twice)["topics"] if "events" in r]
    assert row["events"] == len(ev)


def test_quick_inspect_lists_the_same_topics_and_messages_without_decoding_the_events(tmp_path, monkeypatch, capsys):
    from plsgraph.cli.main import main
    from plsgraph.io import event_codecs

    ev, js, od, cam = _sim(n=5000, seconds=0.5)
    p = tmp_path / "q.mcap"
    write_recording(p, ev, js, od, cam, event_format="evt3")
    full = inspect_recording(p)
    monkeypatch.setattr(event_codecs.Evt3Decoder, "decode", lambda *a, **k: pytest.fail("decoded"))
    quick = inspect_recording(p, count_events=False)
    f, q = ({r["topic"]: r for r in x["topics"]} for x in (full, quick))
    assert f.keys() == q.keys() and all(f[k]["messages"] == q[k]["messages"] for k in f)
    e = q["/event_camera/events"]
    assert e["events"] is None and e["events_on"] is None and e["t_first_ns"] is not None
    assert q["/odom"] == f["/odom"]  # the other topics as before
    assert main(["inspect", "--quick", str(p)]) == 0
    assert "not counted" in capsys.readouterr().out


def test_events_long_enough_in_few_packets_are_not_refused_as_short(tmp_path):
    # A review found a check on the file's index (a bare ROS 2 .db3 lists its messages' first and last times) refusing
    # 3.0 s of events in 1.5 s packets as "span only 1.50 s": the span is judged on the decoded events' times only.
    import sqlite3

    from plsgraph.errors import InsufficientDataError
    from plsgraph.io.source import open_source
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, build_tracks

    ev, js, _, cam = _sim(n=20_000, seconds=3.0)
    tj = (js.t - js.t[0]) * 1e-9
    wheels = np.column_stack([2.0 * tj, 2.5 * tj, 2.0 * tj, 2.5 * tj])
    p = tmp_path / "packets.mcap"
    write_recording(p, ev, JointStates(js.t, js.names, wheels, np.zeros_like(wheels)), None, cam, event_format="evt3",
                    packet_ns=1_500_000_000)
    db = tmp_path / "packets.db3"
    src = open_source(p)
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT, type TEXT, serialization_format TEXT, "
                "offered_qos_profiles TEXT)")
    con.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER, timestamp INTEGER, data BLOB)")
    ids = {name: k + 1 for k, name in enumerate(src.topics())}
    for name, info in src.topics().items():
        con.execute("INSERT INTO topics VALUES (?,?,?,?,?)", (ids[name], name, info.msgtype, "cdr", ""))
    for m in src.iter_raw(None):
        con.execute("INSERT INTO messages(topic_id,timestamp,data) VALUES (?,?,?)",
                    (ids[m.topic], m.log_time_ns, bytes(m.data)))
    con.commit()
    con.close()
    with pytest.raises(InsufficientDataError) as e:  # random events: no board, but not "too short"
        build_tracks(Run(db, CalibrationOptions.build(board="acircles_4x11", frontend_workers=1)))
    assert "span only" not in str(e.value) and "no board detected" in str(e.value)


def test_an_event_topic_of_a_type_plsgraph_does_not_read_is_named(tmp_path):
    # A review: a ROS 1 Prophesee driver's prophesee_event_msgs/EventArray topic gave "has no events ... name a topic
    # with --events-topic if plsgraph did not recognise it", and doing so "has type ..., not event (...)".
    from mcap.writer import Writer

    from plsgraph.errors import RecordingError
    from plsgraph.io.events_reader import pick_topic
    from plsgraph.io.messages import EVENT_TYPES
    from plsgraph.io.source import open_source
    from plsgraph.io.writer import _joint_bytes, message_definition
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, read_inputs

    p = tmp_path / "foreign.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        js = w.register_schema("sensor_msgs/msg/JointState", "ros2msg",
                               message_definition("sensor_msgs/msg/JointState").encode())
        ev = w.register_schema("my_msgs/msg/Events", "ros2msg", b"uint8[] data")
        cj, ce = w.register_channel("/joint_states", "cdr", js), w.register_channel("/camera/events", "cdr", ev)
        for k in range(20):
            t = T0 + k * 20_000_000
            w.add_message(cj, log_time=t, publish_time=t, sequence=k,
                          data=_joint_bytes(t, ("left_wheel", "right_wheel"), np.array([0.1 * k, 0.1 * k]),
                                            np.zeros(2)))
            w.add_message(ce, log_time=t, publish_time=t, sequence=k, data=b"\x00\x01\x00\x00" + bytes(8))
        w.finish()
    with pytest.raises(RecordingError, match=r"/camera/events \(my_msgs/msg/Events\) is named like events but of a "
                                             r"type plsgraph does not read") as e:
        read_inputs(Run(p, CalibrationOptions(board="acircles_4x11")))
    assert "--odometry FILE" in str(e.value)  # an odometry-only file: the two-file form is named
    with pytest.raises(RecordingError, match=r"has type my_msgs/msg/Events, not an event type plsgraph reads"):
        pick_topic(open_source(p), EVENT_TYPES, "/camera/events", "event")


def test_the_camera_info_of_the_events_camera_is_taken_and_another_cameras_is_warned_of(tmp_path):
    # A review: events of a second camera (/rear_dvs/events) were calibrated with the first camera's CameraInfo
    # (/event_camera/camera_info) without a word.
    ev, js, od, cam = _sim(n=3000, seconds=0.5)
    p = tmp_path / "rear.mcap"
    write_recording(p, ev, js, None, cam, event_format="dvs",
                    topics={"dvs": "/rear_dvs/events", "camera_info": "/front/camera_info"})
    rec = read_recording(p)
    assert rec.used_topics["camera_info"] == "/front/camera_info"
    assert any("camera info /front/camera_info is not in the namespace of the events topic /rear_dvs/events" in w
               for w in rec.warnings)
    # As the calibration reads it (the events streamed later, not read here): the same choice and warning.
    from plsgraph.options import CalibrationOptions
    from plsgraph.pipeline import Run, read_inputs

    run = Run(p, CalibrationOptions(board="acircles_4x11"))
    assert read_inputs(run).used_topics["camera_info"] == "/front/camera_info"
    assert any("is not in the namespace of the events topic /rear_dvs/events" in w for w in run.warnings)
    # Two cameras' infos, the rear one's in the events' namespace: that one is taken, without a warning.
    from recordings import copy_mcap

    two = tmp_path / "two.mcap"
    copy_mcap(p, two, also={"/front/camera_info": "/rear_dvs/camera_info"})
    rec = read_recording(two, with_events=False)
    assert rec.used_topics["camera_info"] == "/rear_dvs/camera_info"
    assert not any("namespace" in w or "several camera info" in w for w in rec.warnings)
    plain = tmp_path / "plain.mcap"
    write_recording(plain, ev, js, None, cam, event_format="dvs")
    rec = read_recording(plain)
    assert rec.used_topics["camera_info"] == "/dvs/camera_info" and not any("namespace" in w for w in rec.warnings)
