"""Truncated and bit-flipped recordings give a clean RecordingError or a result with warnings, never a crash.

Files written by plsgraph carry chunk CRCs, so for them a result *without* warnings must equal the clean
read exactly (no silent wrong numbers). The real DAVIS sample has no CRCs: a flipped bit inside its raw
event payload is undetectable in principle, so there only "no crash, no hang" is required.
"""

from __future__ import annotations

import logging
import signal
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from realdata import SHARED_REAL_DIR
from recordings import damaged_copies, random_streams

from plsgraph.errors import RecordingError
from plsgraph.io import inspect_recording, read_events, read_recording, write_recording


def _sim(n: int, seconds: float, seed: int):
    return random_streams(n, seconds, seed)


@contextmanager
def _deadline(seconds: int):
    def boom(*_):
        raise TimeoutError(f"reader took more than {seconds} s: hang?")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _same(a, b) -> bool:
    if (a.events is None) != (b.events is None) or (a.joints is None) != (b.joints is None):
        return False
    if a.events is not None and not all(np.array_equal(getattr(a.events, f), getattr(b.events, f)) for f in "txyp"):
        return False
    if a.odometry is not None and (b.odometry is None or not np.array_equal(a.odometry.position, b.odometry.position)):
        return False
    return a.joints is None or np.array_equal(a.joints.position, b.joints.position, equal_nan=True)


@pytest.mark.parametrize("fmt", ["dvs", "libcaer_cmp", "evt3"])
def test_fuzz_written_recordings(tmp_path, fmt, caplog):
    caplog.set_level(logging.ERROR)
    ev, js, od, cam = _sim(n=3000, seconds=0.3, seed=3)
    src = tmp_path / "clean.mcap"
    # Small chunks, so a damaged chunk loses only part of the file and recovery is exercised.
    write_recording(src, ev, js, od, cam, event_format=fmt, packet_ns=5_000_000, chunk_bytes=8192)
    clean = read_recording(src)
    data = src.read_bytes()
    outcomes = {"error": 0, "warned": 0, "same": 0}
    for p, how in damaged_copies(tmp_path, data, {"dvs": 1, "libcaer_cmp": 2, "evt3": 3}[fmt], 20, ".mcap"):
        with _deadline(20):
            try:
                rec = read_recording(p)
                inspect_recording(p)
            except RecordingError:
                outcomes["error"] += 1
                continue
        if rec.warnings:
            outcomes["warned"] += 1
        else:
            assert _same(rec, clean), f"{how}: data changed without a warning"
            outcomes["same"] += 1
    assert outcomes["error"] + outcomes["warned"] > 0


def test_truncated_mcap_keeps_what_was_read(tmp_path, caplog):
    caplog.set_level(logging.ERROR)
    ev, js, od, cam = _sim(n=20_000, seconds=1.0, seed=4)
    src = tmp_path / "clean.mcap"
    write_recording(src, ev, js, od, cam, event_format="libcaer_cmp", chunk_bytes=32768)
    data = src.read_bytes()
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[: int(len(data) * 0.6)])
    rec = read_recording(p)
    assert any("truncated" in w for w in rec.warnings)
    assert 0 < len(rec.events) < len(ev)
    # What was kept is exactly the start of the recording.
    n = len(rec.events)
    np.testing.assert_array_equal(rec.events.t, ev.t[:n])
    np.testing.assert_array_equal(rec.events.x, ev.x[:n])


def test_corrupt_chunk_is_skipped_and_reported(tmp_path, caplog):
    caplog.set_level(logging.ERROR)
    ev, _, _, _ = _sim(n=60_000, seconds=1.0, seed=5)
    src = tmp_path / "clean.mcap"
    write_recording(src, ev, None, None, None, event_format="dvs", chunk_bytes=65536)
    data = bytearray(src.read_bytes())
    data[len(data) // 3] ^= 0x10  # inside a compressed chunk: CRC or decompression fails
    p = tmp_path / "flip.mcap"
    p.write_bytes(bytes(data))
    rec = read_recording(p)
    assert rec.warnings
    assert any("lost" in w for w in rec.warnings)
    assert 0 < len(rec.events) < len(ev)
    assert np.all(np.isin(rec.events.t, ev.t))


@pytest.mark.skipif(not (SHARED_REAL_DIR / "davis346_tagboard.mcap").exists(), reason="no real data")
def test_fuzz_real_davis_no_crash(tmp_path, caplog):
    caplog.set_level(logging.ERROR)
    data = (SHARED_REAL_DIR / "davis346_tagboard.mcap").read_bytes()
    for p, _ in damaged_copies(tmp_path, data, 11, 8, ".mcap"):
        with _deadline(20):
            try:
                ev = read_events(p)
                assert np.all(np.diff(ev.t) >= 0) and ev.x.max(initial=0) < 346 and ev.y.max(initial=0) < 260
            except RecordingError:
                pass


@pytest.mark.skipif(not (SHARED_REAL_DIR / "jackal_odometry.bag").exists(), reason="no real data")
def test_damaged_ros1_bag(tmp_path, caplog):
    caplog.set_level(logging.ERROR)
    data = (SHARED_REAL_DIR / "jackal_odometry.bag").read_bytes()
    for p, _ in damaged_copies(tmp_path, data, 12, 6, ".bag"):
        with _deadline(20):
            try:
                rec = read_recording(p)
                assert rec.odometry is not None or rec.imu is not None or rec.warnings
            except RecordingError as exc:
                assert str(exc)


@pytest.mark.skipif(not (SHARED_REAL_DIR / "jackal_odometry.bag").exists(), reason="no real data")
def test_cut_ros1_bag_read_front_to_back(tmp_path, caplog):
    caplog.set_level(logging.ERROR)
    data = (SHARED_REAL_DIR / "jackal_odometry.bag").read_bytes()
    full = read_recording(SHARED_REAL_DIR / "jackal_odometry.bag")
    p = tmp_path / "cut.bag"
    p.write_bytes(data[: len(data) * 6 // 10])  # the index at the end is gone
    rec = read_recording(p)
    assert any("front to back" in w for w in rec.warnings) and any("cut short" in w for w in rec.warnings)
    n = len(rec.odometry)
    assert 0.4 * len(full.odometry) < n < 0.7 * len(full.odometry)
    np.testing.assert_array_equal(rec.odometry.t, full.odometry.t[:n])
    np.testing.assert_array_equal(rec.odometry.position, full.odometry.position[:n])
    np.testing.assert_array_equal(rec.imu.gyro, full.imu.gyro[: len(rec.imu)])
    assert rec.lost == {"/jackal_velocity_controller/odom": None, "/imu/data": None}


@pytest.mark.skipif(not (SHARED_REAL_DIR / "davis346_tagboard.mcap").exists(), reason="no real data")
def test_cut_real_mcap_keeps_readable_start_of_last_chunk(tmp_path, caplog):
    """The sample's chunks are ~800 kB; a recording cut mid-chunk keeps the whole messages before the cut."""
    caplog.set_level(logging.ERROR)
    src = SHARED_REAL_DIR / "davis346_tagboard.mcap"
    full = read_events(src)
    data = src.read_bytes()
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[: len(data) // 10])  # inside the first chunk
    rec = read_recording(p)
    n = len(rec.events)
    assert n > 30_000  # without salvage nothing of the first chunk would survive
    np.testing.assert_array_equal(rec.events.t, full.t[:n])
    np.testing.assert_array_equal(rec.events.y, full.y[:n])
    assert any("damaged chunk's readable start" in w for w in rec.warnings)
    assert rec.lost == {"/event_camera/events": None}


@pytest.mark.parametrize("name", ["run.mcap", "run.bag", "run.db3", "run.raw", "run.aedat4", "run.unknown"])
def test_an_empty_file_is_said_to_be_empty_whatever_its_name(tmp_path, name):
    # Before: "bad magic", "not a ROS 1 bag", "an sqlite file but not a ROS 2 bag", ... for a file of 0 bytes.
    p = tmp_path / name
    p.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"is empty \(0 bytes\)"):
        inspect_recording(p)
    with pytest.raises(RecordingError, match=r"is empty \(0 bytes\)"):
        read_recording(p)


def test_an_empty_folder_is_said_to_be_empty(tmp_path):
    d = tmp_path / "bag"
    d.mkdir()
    with pytest.raises(RecordingError, match="is an empty folder, not a ROS 2 bag"):
        inspect_recording(d)


def test_a_folder_that_is_not_a_bag_is_named_for_what_it_holds(tmp_path):
    # A review: a folder of recordings (or of notes) got "cannot be opened as a ROS bag ... ros2 bag reindex".
    sample = Path(__file__).resolve().parents[1] / "data" / "sample" / "rich_sample.mcap"
    many, one, none = (tmp_path / n for n in ("many", "one", "none"))
    for d in (many, one, none):
        d.mkdir()
    for name in ("a.mcap", "b.mcap"):
        (many / name).symlink_to(sample)
    (one / "run_0.mcap").symlink_to(sample)
    (none / "notes.txt").write_text("drive 3")
    with pytest.raises(RecordingError, match=r"is a folder of 2 recordings \(a.mcap, b.mcap\), not a ROS 2 bag.*"
                                             "plsgraph batch"):
        inspect_recording(many)
    with pytest.raises(RecordingError, match="is a folder without a recording"):
        inspect_recording(none)
    rec = inspect_recording(one, count_events=False)  # a bag folder that lost its metadata.yaml: its MCAP is read
    assert Path(rec["path"]).name == "run_0.mcap" and any("no metadata.yaml" in w for w in rec["warnings"])


@pytest.mark.parametrize("name", ["bag.db3.zstd", "run.mcap.gz", "x.bag.bz2"])
def test_a_compressed_recording_file_is_said_to_be_compressed(tmp_path, name):
    # A review: a ROS 2 bag's file-compressed .db3.zstd without its metadata.yaml gave "cannot tell the container type".
    p = tmp_path / name
    p.write_bytes(b"\x28\xb5\x2f\xfd" + bytes(64))
    with pytest.raises(RecordingError, match="is a compressed file .*decompress it first"):
        inspect_recording(p)


def test_an_mcap_bag_copied_in_part_is_said_to_be_incomplete(tmp_path):
    # A review: a ROS 2 bag with MCAP storage whose second split file was not copied got "cannot be opened ... run
    # 'ros2 bag reindex'".
    import yaml

    sample = Path(__file__).resolve().parents[1] / "data" / "sample" / "rich_sample.mcap"
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.mcap").symlink_to(sample)
    meta = {"rosbag2_bagfile_information": {
        "version": 8, "storage_identifier": "mcap", "relative_file_paths": ["bag_0.mcap", "bag_1.mcap"],
        "duration": {"nanoseconds": 10}, "starting_time": {"nanoseconds_since_epoch": 0}, "message_count": 1,
        "topics_with_message_count": [], "compression_format": "", "compression_mode": "",
        "files": [], "custom_data": {}, "ros_distro": "humble"}}
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(RecordingError, match="bag .* is incomplete: its metadata.yaml lists bag_1.mcap"):
        inspect_recording(bag, count_events=False)
