"""ROS 2 sqlite bags read from their tables alone: a bare .db3, or a bag folder that lost metadata.yaml."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
import yaml
from recordings import random_streams

from plsgraph.errors import RecordingError
from plsgraph.io import inspect_recording, read_events, read_recording, write_recording
from plsgraph.io.db3_reader import Db3Source
from plsgraph.io.mcap_reader import McapSource
from plsgraph.io.messages import typestore
from plsgraph.io.source import open_source


def _mcap(tmp_path, event_format="dvs"):
    ev, js, od, cam = random_streams(3000, 0.5, 3, fy=321.0, dist=[0.1, -0.01, 0, 0, 0])
    p = tmp_path / f"rec_{event_format}.mcap"
    write_recording(p, ev, js, od, cam, event_format=event_format)
    return p


def _to_db3(mcap, folder, version=8, split=1):
    """Copy every message of an MCAP file into a rosbags-written ROS 2 sqlite bag; return the .db3 files."""
    from rosbags.rosbag2 import Writer

    src = McapSource(mcap)
    msgs = list(src.iter_raw())
    ts = typestore()
    parts = np.array_split(np.arange(len(msgs)), split)
    files = []
    for k, idx in enumerate(parts):
        d = folder / f"part{k}"
        with Writer(d, version=version) as w:
            conns = {tp: w.add_connection(tp, info.msgtype, typestore=ts) for tp, info in src.topics().items()}
            for i in idx:
                m = msgs[i]
                w.write(conns[m.topic], m.log_time_ns, bytes(m.data))
        (f,) = d.glob("*.db3")
        files.append(f)
    return files


def _same_recording(a, b):
    np.testing.assert_array_equal(a.events.t, b.events.t)
    np.testing.assert_array_equal(a.events.x, b.events.x)
    np.testing.assert_array_equal(a.events.p, b.events.p)
    np.testing.assert_array_equal(a.joints.position, b.joints.position)
    np.testing.assert_array_equal(a.odometry.linear, b.odometry.linear)
    np.testing.assert_array_equal(a.camera.K, b.camera.K)
    np.testing.assert_array_equal(a.camera.dist, b.camera.dist)
    assert a.used_topics == b.used_topics


@pytest.mark.parametrize("version", [8, 9])
def test_bare_db3_reads_like_the_mcap(tmp_path, version):
    mcap = _mcap(tmp_path)
    (db3,) = _to_db3(mcap, tmp_path, version=version)
    with_meta = read_recording(db3.parent)  # rosbags, through metadata.yaml
    (db3.parent / "metadata.yaml").unlink()
    src = open_source(db3)
    assert isinstance(src, Db3Source)
    bare = read_recording(db3)
    assert bare.warnings == ()
    ref = read_recording(mcap)
    _same_recording(bare, ref)
    _same_recording(with_meta, ref)
    # The folder without metadata.yaml reads the same.
    _same_recording(read_recording(db3.parent), ref)
    assert bare.topics["/joint_states"].messages == len(ref.joints)


def test_bare_db3_event_packets_and_inspect(tmp_path):
    mcap = _mcap(tmp_path, event_format="libcaer_cmp")
    (db3,) = _to_db3(mcap, tmp_path)
    (db3.parent / "metadata.yaml").unlink()
    ev = read_events(db3)
    ref = read_events(mcap)
    np.testing.assert_array_equal(ev.t, ref.t)
    info = inspect_recording(db3)
    json.dumps(info)
    rows = {r["topic"]: r for r in info["topics"]}
    ev_row = next(r for r in rows.values() if "events" in r)
    assert ev_row["events"] == len(ref) and ev_row["encoding"] == "libcaer_cmp"
    assert (ev_row["width"], ev_row["height"]) == (346, 260)
    assert ev_row["t_first_ns"] == int(ref.t[0]) and ev_row["t_last_ns"] == int(ref.t[-1])
    assert rows["/joint_states"]["messages"] == 25


def test_folder_of_split_db3_files_without_metadata(tmp_path):
    mcap = _mcap(tmp_path)
    files = _to_db3(mcap, tmp_path, split=3)
    folder = tmp_path / "bag"
    folder.mkdir()
    for k, f in enumerate(files):
        f.rename(folder / f"bag_{k}.db3")
    rec = read_recording(folder)
    _same_recording(rec, read_recording(mcap))


def test_damaged_db3_gives_recording_error_or_warned_result(tmp_path):
    mcap = _mcap(tmp_path)
    (db3,) = _to_db3(mcap, tmp_path)
    (db3.parent / "metadata.yaml").unlink()
    data = db3.read_bytes()
    ref = read_recording(db3)
    rng = np.random.default_rng(7)
    outcomes = set()
    for i in range(12):
        b = bytearray(data)
        if i % 2 == 0:
            b = b[: int(rng.integers(0, len(b)))]
        else:
            for _ in range(3):
                j = int(rng.integers(0, len(b)))
                b[j] ^= 1 << int(rng.integers(0, 8))
        p = tmp_path / f"bad{i}.db3"
        p.write_bytes(bytes(b))
        try:
            rec = read_recording(p)
        except RecordingError as exc:
            outcomes.add("error")
            assert str(p) in str(exc) or p.name in str(exc)
            continue
        outcomes.add("read")
        if rec.events is not None and rec.warnings == () and len(rec.events) == len(ref.events):
            assert rec.used_topics == ref.used_topics
    assert "error" in outcomes


def test_not_a_bag_sqlite_file(tmp_path):
    p = tmp_path / "other.db3"
    con = sqlite3.connect(p)
    con.execute("CREATE TABLE things (a INTEGER)")
    con.commit()
    con.close()
    with pytest.raises(RecordingError, match="not a ROS 2 bag"):
        read_recording(p)
    q = tmp_path / "text.db3"
    q.write_text("hello")
    with pytest.raises(RecordingError, match="cannot be read as a ROS 2 sqlite bag"):
        inspect_recording(q)


@pytest.mark.parametrize("damage", ["", "garbage: [\x00", "rosbag2_bagfile_information:\n  version: 5\n  relative_"])
def test_a_bag_folder_with_a_damaged_metadata_file_is_read_from_its_db3_files(tmp_path, damage):
    # A review: an empty, garbled or cut metadata.yaml refused the bag ("run `ros2 bag reindex`", which needs ROS 2),
    # though plsgraph reads a bag folder without one from its .db3 files.
    mcap = _mcap(tmp_path)
    (db3,) = _to_db3(mcap, tmp_path)
    (db3.parent / "metadata.yaml").write_text(damage)
    for given in (db3.parent, db3):
        src = open_source(given)
        assert isinstance(src, Db3Source)
        rec = read_recording(given)
        assert any("metadata.yaml could not be used" in w and "\n" not in w for w in rec.warnings)
        _same_recording(rec, read_recording(mcap))


def test_a_bag_copied_in_part_is_said_to_be_incomplete(tmp_path):
    # A review: a split bag whose second .db3 was missing calibrated on half the data, with only "metadata.yaml could
    # not be used (Some database files are missing ...)".
    from rosbags.rosbag2 import Writer

    mcap = _mcap(tmp_path)
    src = McapSource(mcap)
    msgs = list(src.iter_raw())
    bag = tmp_path / "split"
    with Writer(bag, version=8) as w:
        conns = {tp: w.add_connection(tp, info.msgtype, typestore=typestore()) for tp, info in src.topics().items()}
        for m in msgs:
            w.write(conns[m.topic], m.log_time_ns, bytes(m.data))
    meta = bag / "metadata.yaml"
    (db3,) = bag.glob("*.db3")
    info = yaml.safe_load(meta.read_text())
    info["rosbag2_bagfile_information"]["relative_file_paths"].append("split_1.db3")  # listed, never copied
    meta.write_text(yaml.safe_dump(info))
    rec = read_recording(bag)
    (said,) = [w for w in rec.warnings if "is incomplete" in w]
    assert "lists split_1.db3, which is not there" in said and db3.name in said


def test_a_metadata_file_that_names_a_topics_type_otherwise_than_the_db3_is_not_trusted(tmp_path):
    # A review: metadata.yaml edited to call /joint_states sensor_msgs/msg/Imu hid its 601 messages without a word
    # ("has no odometry"). The .db3's own tables are read then, with a warning naming the disagreement.
    mcap = _mcap(tmp_path)
    (db3,) = _to_db3(mcap, tmp_path)
    meta = db3.parent / "metadata.yaml"
    assert not isinstance(open_source(db3.parent), Db3Source)  # metadata that agrees: read through it, as before
    meta.write_text(meta.read_text().replace("sensor_msgs/msg/JointState", "sensor_msgs/msg/Imu"))
    src = open_source(db3.parent)
    assert isinstance(src, Db3Source)
    rec = read_recording(db3.parent)
    assert any("names the type of /joint_states otherwise than the bag's .db3" in w for w in rec.warnings)
    _same_recording(rec, read_recording(mcap))
