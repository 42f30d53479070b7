"""The hand-written CDR parsers of the hot message types against the general ones.

``parse_event_packet`` reads a little-endian message in a few ``unpack_from`` calls and leaves anything else (and any
message that does not fit its own lengths) to the bounds-checked reader; ``parse_camera_info_cdr`` replaces the rosbags
type store for the camera info. Both must give the general readers' fields exactly, and refuse what they refuse.
"""

from __future__ import annotations

import numpy as np
import pytest

from plsgraph.core.camera import CameraModel
from plsgraph.errors import RecordingError
from plsgraph.io import messages
from plsgraph.io.cdr import CdrWriter
from plsgraph.io.messages import CAMERA_INFO_TYPE, parse_camera_info_cdr, parse_event_packet
from plsgraph.io.writer import _camera_bytes


def _packet(frame: str, enc: str, blob: bytes, stamp: int = 1_700_000_000_123_456_789, big: int = 0) -> bytes:
    w = CdrWriter()
    w.header(stamp, frame)
    w.prim("uint32", 260)
    w.prim("uint32", 346)
    w.prim("uint64", 77)
    w.prim("uint64", 1_700_000_000_000_000_000)
    w.string(enc)
    w.prim("uint8", big)
    w.raw_bytes(blob)
    return w.getvalue()


def _general(data):
    """parse_event_packet with the quick path turned off: the bounds-checked reader alone."""
    quick = messages._event_packet_le_cdr
    messages._event_packet_le_cdr = lambda _d: None
    try:
        return messages.parse_event_packet(data)
    finally:
        messages._event_packet_le_cdr = quick


def _outcome(fn, data):
    try:
        hdr, blob = fn(data)
        return hdr, bytes(blob)
    except RecordingError as exc:
        return type(exc).__name__, str(exc)


def test_event_packet_quick_path_equals_the_general_reader_on_every_alignment_and_damage():
    rng = np.random.default_rng(3)
    n = 0
    # Frame ids and encodings of every length mod 8 move the 8-byte fields across all alignments.
    for frame in ("", "c", "cam", "camera", "event_cam0", "davis346_left"):
        for enc in ("evt3", "libcaer_cmp", "mono"):
            blob = rng.integers(0, 256, int(rng.integers(0, 40)), dtype=np.uint8).tobytes()
            data = _packet(frame, enc, blob)
            hdr, got = parse_event_packet(data)
            assert messages._event_packet_le_cdr(data) is not None  # the quick path did read it
            assert (hdr.frame_id, hdr.encoding, hdr.width, hdr.height, hdr.seq) == (frame, enc, 346, 260, 77)
            assert hdr.stamp_ns == 1_700_000_000_123_456_789 and bytes(got) == blob
            variants = [data, memoryview(data), bytearray(data)]
            variants += [data[:k] for k in range(0, len(data))]  # every truncation
            for _ in range(20):  # bytes changed in the header's lengths and fields
                b = bytearray(data)
                b[int(rng.integers(0, min(len(b), 64)))] = int(rng.integers(0, 256))
                variants.append(bytes(b))
            for v in variants:
                assert _outcome(parse_event_packet, v) == _outcome(_general, v)
                n += 1
    assert n > 1000


def test_event_packet_big_endian_cdr_and_big_endian_events_take_the_general_path():
    data = bytearray(_packet("cam", "evt3", b"\x01\x02"))
    assert messages._event_packet_le_cdr(bytes(_packet("cam", "evt3", b"", big=1))) is None
    with pytest.raises(RecordingError, match="big-endian"):
        parse_event_packet(_packet("cam", "evt3", b"", big=1))
    data[1] = 0  # big-endian CDR encapsulation: not the quick path's
    assert messages._event_packet_le_cdr(bytes(data)) is None


def test_camera_info_parser_equals_rosbags_and_refuses_a_truncated_message():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    cam = CameraModel(346, 260, np.array([[251.3, 0, 171.2], [0, 250.9, 129.8], [0, 0, 1]]),
                      np.array([-0.31, 0.12, 1e-3, -2e-4, 0.01]))
    for frame in ("", "cam", "davis346"):
        data = _camera_bytes(1_700_000_000_500_000_000, frame, cam)
        stamp, got = parse_camera_info_cdr(data, 5)
        ref = ts.deserialize_cdr(data, CAMERA_INFO_TYPE)
        assert stamp == ref.header.stamp.sec * 1_000_000_000 + ref.header.stamp.nanosec
        assert (got.width, got.height, got.distortion_model) == (ref.width, ref.height, ref.distortion_model)
        assert np.array_equal(got.k, ref.k) and np.array_equal(got.d, ref.d)
        for k in range(len(data)):
            with pytest.raises(RecordingError):
                parse_camera_info_cdr(data[:k], 5)
    # A zero stamp falls back to the log time (marked negative, as the other parsers do).
    assert parse_camera_info_cdr(_camera_bytes(0, "", cam), 5)[0] == -6


def test_camera_info_with_a_damaged_string_is_refused_as_rosbags_refuses_it():
    """A distortion model or frame id that is not UTF-8, or lost its terminating NUL, makes the message unreadable
    (it is skipped and the next camera info is used), as the message deserializer it replaces did."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    cam = CameraModel(346, 260, np.array([[251.3, 0, 171.2], [0, 250.9, 129.8], [0, 0, 1]]), np.zeros(5))
    good = _camera_bytes(1_700_000_000_500_000_000, "cam", cam)
    at_model = good.index(b"plumb_bob")
    at_frame = good.index(b"cam")
    damaged = []
    for i, byte in ((at_model + 2, 0xFF), (at_frame + 1, 0xC3), (at_model + len("plumb_bob"), ord("x"))):
        b = bytearray(good)
        b[i] = byte  # invalid UTF-8, a truncated two-byte sequence, the NUL overwritten
        damaged.append(bytes(b))
    for data in damaged:
        with pytest.raises(Exception):  # noqa: B017 - rosbags raises its own error types
            ts.deserialize_cdr(data, CAMERA_INFO_TYPE)
        with pytest.raises(RecordingError, match="UTF-8|NUL"):
            parse_camera_info_cdr(data, 5)


def test_a_damaged_camera_info_is_skipped_and_the_next_one_used(tmp_path):
    from plsgraph.io.recording import _Collector

    cam = CameraModel(346, 260, np.array([[251.3, 0, 171.2], [0, 250.9, 129.8], [0, 0, 1]]), np.zeros(5))
    good = _camera_bytes(1_700_000_000_500_000_000, "cam", cam)
    bad = bytearray(good)
    bad[good.index(b"plumb_bob") + 2] = 0xFF
    c = _Collector("camera_info", "/camera_info")
    for data, t in ((bytes(bad), 1), (good, 2)):
        try:
            c.add_cdr(data, t)
        except RecordingError:
            c.bad += 1
    warnings: list[str] = []
    got = c.build(warnings.append)
    assert c.bad == 1 and not warnings
    assert got is not None and np.array_equal(got.K, cam.K)



def test_the_intrinsics_most_camera_info_messages_carry_are_used():
    """Before: the first message's intrinsics were used, whatever the others said (a first message with fx 4 % off,
    14 correct ones after it: exit 0 with the lever arm 5 cm off), and a first message with fx = 0 or NaN made the
    recording look as if it had no camera info at all."""
    from plsgraph.io.messages import CameraInfoFields
    from plsgraph.io.recording import _Collector

    K = np.array([[251.3, 0, 171.2], [0, 250.9, 129.8], [0, 0, 1]])

    def fields(scale=1.0, fx=None):
        k = K.copy()
        k[:2] *= scale
        if fx is not None:
            k[0, 0] = fx
        return CameraInfoFields(346, 260, "plumb_bob", np.zeros(5), k.ravel())

    def collector(messages):
        c = _Collector("camera_info", "/camera_info")
        for i, f in enumerate(messages):  # as add_cdr keeps them: the stamp, the fields
            c.t.append(i + 1)
            c.rows.append(f)
        return c

    for first, unusable in ((fields(1.04), False), (fields(fx=0.0), True), (fields(fx=float("nan")), True)):
        c = collector([first] + [fields()] * 14)
        warnings: list[str] = []
        got = c.build(warnings.append)
        assert got is not None and np.array_equal(got.K, K)
        assert len(warnings) == 1 and "14 of 15 carry the ones used (fx 251.3" in warnings[0]
        assert ("unusable" in warnings[0]) is unusable
    c = collector([fields(fx=0.0), fields(fx=float("nan"))])
    warnings = []
    assert c.build(warnings.append) is None and "none of its 2 camera info messages is usable" in warnings[0]
    c = collector([fields(1.04)] * 2 + [fields()] * 2)  # no majority: the first of the most frequent
    warnings = []
    assert np.allclose(c.build(warnings.append).K[0, 0], 251.3 * 1.04) and "fewer than half agree" in warnings[0]
