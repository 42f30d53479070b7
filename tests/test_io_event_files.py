"""Event-camera files without ROS: Prophesee Metavision .raw (EVT 2.0 / 3.0) and iniVation AEDAT4."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from recordings import damaged_copies

from plsgraph.errors import RecordingError
from plsgraph.io import (
    inspect_recording,
    iter_event_chunks,
    prophesee,
    read_events,
    read_events_with_log,
    read_recording,
)
from plsgraph.io.event_codecs import Evt2Decoder, encode_evt2, encode_evt3

HEADERS = {
    "evt3": b"% camera_integrator_name Prophesee\n% evt 3.0\n% format EVT3;height=720;width=1280\n"
    b"% geometry 1280x720\n% sensor_generation 4.2\n% end\n",
    "evt2": b"% Date 2020-01-01 00:00:00\n% evt 2.0\n% geometry 640x480\n% end\n",
}
SIZE = {"evt3": (1280, 720), "evt2": (640, 480)}


def _truth(n, seconds, w, h, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, int(seconds * 1e6), n))
    return t, rng.integers(0, w, n), rng.integers(0, h, n), rng.random(n) < 0.5


def _raw(tmp_path, enc, n=20_000, seconds=20.0, header=None, seed=0):
    w, h = SIZE[enc]
    t, x, y, p = _truth(n, seconds, w, h, seed)
    body, _ = (encode_evt3 if enc == "evt3" else encode_evt2)(t, x, y, p)
    path = tmp_path / f"rec_{enc}.raw"
    path.write_bytes((HEADERS[enc] if header is None else header) + body)
    return path, (t * 1000, x, y, np.where(p, 1, -1))


def _check(ev, truth):
    t, x, y, p = truth
    np.testing.assert_array_equal(ev.t, t)
    np.testing.assert_array_equal(ev.x, x)
    np.testing.assert_array_equal(ev.y, y)
    np.testing.assert_array_equal(ev.p, p)


@pytest.mark.parametrize("enc", ["evt2", "evt3"])
def test_raw_round_trip_across_blocks_and_rollover(tmp_path, monkeypatch, enc):
    # 20 s spans an EVT3 24-bit µs rollover (16.8 s); small blocks put block edges inside the word stream.
    monkeypatch.setattr(prophesee, "BLOCK_BYTES", 4 * 1021)
    path, truth = _raw(tmp_path, enc)
    res = read_events_with_log(path)
    _check(res.events, truth)
    assert res.warnings == () and res.encoding == enc and res.topic == "events"
    assert (res.events.width, res.events.height) == SIZE[enc]
    chunks = list(iter_event_chunks(path, chunk_events=3000))
    assert len(chunks) > 3 and all(np.all(np.diff(c.t) >= 0) for c in chunks)
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), truth[0])
    rec = read_recording(path)
    assert rec.event_encoding == enc and rec.joints is None and rec.odometry is None and rec.camera is None


@pytest.mark.parametrize("enc", ["evt2", "evt3"])
def test_raw_inspect_counts(tmp_path, enc):
    path, (t, _x, _y, p) = _raw(tmp_path, enc, n=5000, seconds=2.0)
    info = inspect_recording(path)
    json.dumps(info)
    (row,) = info["topics"]
    assert row["type"] == f"prophesee/raw/{enc}" and row["encoding"] == enc
    assert row["events"] == t.size and row["events_on"] == int(np.sum(p > 0))
    assert (row["width"], row["height"]) == SIZE[enc]
    assert (row["t_first_ns"], row["t_last_ns"]) == (int(t[0]), int(t[-1]))
    assert info["warnings"] == []


def test_evt2_decoder_triggers_unknown_words_and_time_rollover():
    t = np.array([5, 70, (1 << 34) - 10])
    body, hi = encode_evt2(t, [1, 2, 3], [4, 5, 6], [True, False, True])
    words = list(np.frombuffer(body, "<u4"))
    # A trigger word and a word of an unknown type in the middle; then a rollover of the 34-bit clock.
    words[2:2] = [np.uint32(0xA << 28), np.uint32(0x3 << 28)]
    after, _ = encode_evt2(np.array([3]), [7], [8], [False], prev_high=-1)
    d = Evt2Decoder(64, 64)
    tt, x, y, p = d.decode(np.array(words, "<u4").tobytes())
    t2, x2, *_ = d.decode(after)
    np.testing.assert_array_equal(tt, t * 1000)
    assert t2[0] == ((1 << 34) + 3) * 1000 and x2[0] == 7
    assert d.stats.triggers == 1 and d.stats.unknown_codes == 1 and d.stats.time_backwards == 0


def test_raw_header_variants(tmp_path):
    # Older EVT 2.0 files state the size as Width / Height lines.
    path, truth = _raw(tmp_path, "evt2", n=500, header=b"% evt 2.0\n% Width 640\n% Height 480\n% end\n")
    assert (read_events(path).width, read_events(path).height) == (640, 480)
    # No size at all: read with an 11-bit fallback and a warning.
    path, truth = _raw(tmp_path, "evt3", n=500, header=b"% evt 3.0\n% end\n")
    res = read_events_with_log(path)
    _check(res.events, truth)
    assert any("no usable sensor size" in w for w in res.warnings)
    # A format plsgraph does not decode, and no format at all.
    for header, match in ((b"% format EVT21;height=720;width=1280\n% end\n", "evt21"),
                          (b"% geometry 640x480\n% end\n", "no '% evt'")):
        p = tmp_path / "other.raw"
        p.write_bytes(header + b"\0" * 64)
        with pytest.raises(RecordingError, match=match):
            read_events(p)


def test_damaged_raw_files(tmp_path):
    path, truth = _raw(tmp_path, "evt3", n=4000, seconds=2.0)
    data = path.read_bytes()
    hdr = len(HEADERS["evt3"])
    # Cut inside the header: a clear error.
    p = tmp_path / "cut_header.raw"
    p.write_bytes(data[: hdr - 7])
    with pytest.raises(RecordingError, match="header is cut off"):
        read_events(p)
    # Cut inside a word: everything before, and a warning that the file is truncated.
    p = tmp_path / "cut.raw"
    p.write_bytes(data[: hdr + 2001])
    res = read_events_with_log(p)
    assert any("truncated" in w for w in res.warnings)
    n = len(res.events)
    assert 0 < n < truth[0].size
    np.testing.assert_array_equal(res.events.t, truth[0][:n])
    # Random damage: a RecordingError or a result (sorted, inside the sensor), never another exception.
    for q, _ in damaged_copies(tmp_path, data, seed=11, n=20, suffix=".raw"):
        try:
            info = inspect_recording(q)
            ev = read_events(q)
        except RecordingError:
            continue
        assert np.all(np.diff(ev.t) >= 0)
        assert ev.x.max(initial=0) < ev.width and ev.y.max(initial=0) < ev.height
        assert sum(r.get("events", 0) for r in info["topics"]) == len(ev)


# ------------------------------------------------------------------------------------------------ AEDAT4


def _aedat4(tmp_path, n=30_000, seconds=1.5, extra_streams=False):
    dv = pytest.importorskip("dv_processing")
    pytest.importorskip("aedat")
    w, h = 346, 260
    t, x, y, p = _truth(n, seconds, w, h, seed=4)
    t = t + 1_700_000_000_000_000  # AEDAT4 stamps are µs since the Unix epoch
    path = tmp_path / "rec.aedat4"
    cfg = (dv.io.MonoCameraWriter.DAVISConfig if extra_streams else dv.io.MonoCameraWriter.EventOnlyConfig)(
        "DAVIS346_00000001", (w, h)
    )
    writer = dv.io.MonoCameraWriter(str(path), cfg)
    for i0 in range(0, n, 5000):
        store = dv.EventStore()
        for k in range(i0, min(n, i0 + 5000)):
            store.push_back(int(t[k]), int(x[k]), int(y[k]), bool(p[k]))
        writer.writeEvents(store)
    if extra_streams:
        writer.writeFrame(dv.Frame(int(t[10]), np.zeros((h, w), np.uint8)))
        writer.writeImu(dv.IMU(int(t[20]), 20.0, 0, 0, 9.8, 0.1, 0, 0, 0, 0, 0))
    del writer
    return path, (t * 1000, x, y, np.where(p, 1, -1))


def test_aedat4_events_and_inspect(tmp_path):
    path, truth = _aedat4(tmp_path, extra_streams=True)
    res = read_events_with_log(path)
    _check(res.events, truth)
    assert res.encoding == "aedat4" and res.warnings == ()
    assert (res.events.width, res.events.height) == (346, 260)
    info = inspect_recording(path)
    json.dumps(info)
    rows = {r["topic"]: r for r in info["topics"]}
    assert rows["events"]["events"] == truth[0].size
    assert rows["events"]["events_on"] == int(np.sum(truth[3] > 0))
    assert (rows["events"]["t_first_ns"], rows["events"]["t_last_ns"]) == (int(truth[0][0]), int(truth[0][-1]))
    assert rows["frame"]["messages"] == 1 and rows["imus"]["messages"] == 1
    assert rows["frame"]["t_first_ns"] == int(truth[0][10])
    chunks = list(iter_event_chunks(path, chunk_events=7000))
    np.testing.assert_array_equal(np.concatenate([c.x for c in chunks]), truth[1])


def test_aedat4_damaged_copies(tmp_path):
    path, truth = _aedat4(tmp_path, n=12_000)
    data = path.read_bytes()
    # Cut in the middle of the packets: the packets before the cut, with a warning.
    p = tmp_path / "cut.aedat4"
    p.write_bytes(data[: len(data) * 2 // 3])
    res = read_events_with_log(p)
    assert any("truncated or corrupt" in w for w in res.warnings)
    n = len(res.events)
    assert 0 < n < truth[0].size
    np.testing.assert_array_equal(res.events.t, truth[0][:n])
    # Cut inside the header: a clear error.
    p.write_bytes(data[:40])
    with pytest.raises(RecordingError, match="AEDAT4 header cannot be read"):
        inspect_recording(p)
    p.write_bytes(b"#!AER-DAT3.1\r\n" + data[14:])
    with pytest.raises(RecordingError, match="AEDAT 2/3"):
        read_events(p)
    for q, _ in damaged_copies(tmp_path, data, seed=5, n=12, suffix=".aedat4"):
        try:
            ev = read_events(q)
        except RecordingError:
            continue
        assert np.all(np.diff(ev.t) >= 0)


def test_aedat4_without_the_package_names_the_install(tmp_path, monkeypatch):
    p = tmp_path / "x.aedat4"
    p.write_bytes(b"#!AER-DAT4.0\r\n" + b"\0" * 64)
    monkeypatch.setitem(sys.modules, "aedat", None)
    with pytest.raises(RecordingError, match=r"pip install 'plsgraph\[dv\]'"):
        inspect_recording(p)


def test_hdf5_is_refused_with_a_reason(tmp_path):
    p = tmp_path / "rec.hdf5"
    p.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    with pytest.raises(RecordingError, match="ECF"):
        read_events(p)


@pytest.mark.parametrize("enc", ["evt2", "evt3"])
def test_cli_inspect_json_lists_raw_files(tmp_path, capsys, enc):
    from plsgraph.cli.main import main

    path, (t, *_rest) = _raw(tmp_path, enc, n=3000, seconds=1.0)
    assert main(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    (row,) = info["topics"]
    assert row["events"] == t.size and row["encoding"] == enc and row["width"] == SIZE[enc][0]
    bad = tmp_path / "bad.raw"
    bad.write_bytes(b"% evt 9.0\n% end\n")
    assert main(["inspect", str(bad)]) != 0
    assert "EVT 2.0 and EVT 3.0" in capsys.readouterr().err
