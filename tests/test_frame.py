import struct

import numpy as np
import pytest

from camnet.bus.frame import (
    ENCODINGS,
    FIXED_HEADER_SIZE,
    Compression,
    Frame,
    FrameError,
    decode_frame,
    encode_frame,
)
from camnet.bus.receiver import FrameReceiver


def make_frame(encoding: str, *, seq: int = 7, camera_id: str = "cam_é", h: int = 37,
               w: int = 53) -> Frame:
    spec = ENCODINGS[encoding]
    rng = np.random.default_rng(spec.code)
    shape = (h, w) if spec.channels == 1 else (h, w, spec.channels)
    high = 65536 if spec.dtype.itemsize == 2 else 256
    image = rng.integers(0, high, size=shape).astype(spec.dtype)
    return Frame(camera_id=camera_id, seq=seq, timestamp_ns=1_700_000_000_123_456_789,
                 encoding=encoding, image=image)


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("compression", [Compression.NONE, Compression.PNG])
def test_round_trip_bit_exact(encoding, compression):
    frame = make_frame(encoding)
    back = decode_frame(encode_frame(frame, compression=compression))
    assert (back.camera_id, back.seq, back.timestamp_ns, back.encoding) == \
        (frame.camera_id, frame.seq, frame.timestamp_ns, frame.encoding)
    assert back.image.dtype.itemsize == frame.image.dtype.itemsize
    assert np.array_equal(back.image, frame.image)


def test_jpeg_is_close_and_refuses_16_bit():
    image = np.tile(np.arange(64, dtype=np.uint8) * 3, (48, 1))
    frame = Frame("c", 0, 0, "mono8", image)
    back = decode_frame(encode_frame(frame, compression=Compression.JPEG, jpeg_quality=95))
    assert np.abs(back.image.astype(int) - image).mean() < 2
    with pytest.raises(ValueError, match="JPEG"):
        encode_frame(make_frame("mono16"), compression=Compression.JPEG)


def test_header_layout_is_documented_size():
    data = encode_frame(make_frame("mono8", camera_id="left", h=2, w=3))
    assert data[:4] == b"CNFR" and data[4] == 1
    assert FIXED_HEADER_SIZE == 40
    header_size, id_len = struct.unpack_from("<HH", data, 8)
    assert (header_size, id_len) == (44, 4)
    assert len(data) == 44 + 6


def _malformed() -> dict[str, bytes]:
    good = encode_frame(make_frame("mono8"))
    bad_encoding = bytearray(good)
    bad_encoding[5] = 200
    bad_compression = bytearray(good)
    bad_compression[6] = 9
    wrong_version = bytearray(good)
    wrong_version[4] = 99
    return {
        "truncated": good[: len(good) - 10],
        "bad-magic": b"XXXX" + good[4:],
        "unknown-version": bytes(wrong_version),
        "bad-encoding": bytes(bad_encoding),
        "bad-compression": bytes(bad_compression),
        "trailing-bytes": good + b"\0",
    }


@pytest.mark.parametrize("kind", sorted(_malformed()))
def test_malformed_frames_raise_frame_error(kind):
    with pytest.raises(FrameError) as info:
        decode_frame(_malformed()[kind])
    assert info.value.kind == kind


@pytest.mark.parametrize("size", [0, 1, 4, 5, 39, 40])
def test_short_inputs_are_truncated(size):
    with pytest.raises(FrameError) as info:
        decode_frame(encode_frame(make_frame("mono8"))[:size])
    assert info.value.kind == "truncated"


def test_random_bytes_never_raise_anything_but_frame_error():
    rng = np.random.default_rng(1)
    good = encode_frame(make_frame("bgr8"))
    for _ in range(300):
        data = bytearray(good)
        for i in rng.integers(0, FIXED_HEADER_SIZE + 8, size=3):
            data[i] = int(rng.integers(256))
        data[:4] = b"CNFR"
        data[4] = 1
        try:
            decode_frame(bytes(data))
        except FrameError as exc:
            assert exc.kind


def test_frame_refuses_wrong_shape():
    with pytest.raises(ValueError, match="bgr8"):
        Frame("c", 0, 0, "bgr8", np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="unknown encoding"):
        Frame("c", 0, 0, "yuv", np.zeros((4, 4), np.uint8))


def test_receiver_counts_gaps_and_malformed(caplog):
    receiver = FrameReceiver()
    for seq in [0, 1, 2, 5, 6, 10]:
        assert receiver.accept(encode_frame(make_frame("mono8", seq=seq, camera_id="a")))
    for seq in [0, 1]:
        receiver.accept(encode_frame(make_frame("mono8", seq=seq, camera_id="b")))
    bad = _malformed()
    for _ in range(3):
        assert receiver.accept(bad["truncated"]) is None
    assert receiver.accept(bad["unknown-version"]) is None
    counts = receiver.counts()
    assert (counts["a"].received, counts["a"].dropped, counts["a"].last_seq) == (6, 5, 10)
    assert (counts["b"].received, counts["b"].dropped) == (2, 0)
    assert receiver.malformed.counts == {"truncated": 3, "unknown-version": 1}
    # Logged once per kind, not once per frame.
    assert sum("truncated" in r.getMessage() for r in caplog.records) == 1
    receiver.accept(encode_frame(make_frame("mono8", seq=0, camera_id="a")))
    assert receiver.counts()["a"].restarts == 1


def test_pixels_beyond_the_header_are_refused_before_decoding():
    """A small PNG can decode to hundreds of MB of pixels (docs/benchmarks.md, "Evidence behind the nodes'
    choices"): the header's size is checked before the payload is decoded."""
    import cv2

    small = encode_frame(make_frame("mono8", camera_id="a", h=48, w=64), compression=Compression.PNG)
    header_size = struct.unpack_from("<H", small, 8)[0]
    bomb = cv2.imencode(".png", np.zeros((16000, 16000), np.uint8))[1].tobytes()
    forged = bytearray(small[:header_size]) + bomb
    struct.pack_into("<I", forged, 36, len(bomb))  # the payload size, last field of the fixed header
    with pytest.raises(FrameError, match="declares") as info:
        decode_frame(bytes(forged))
    assert info.value.kind == "bad-size"


def test_a_receiver_with_the_rig_sizes_refuses_other_cameras_and_sizes_from_the_header():
    receiver = FrameReceiver({"a": (64, 48), "b": None})
    assert receiver.accept(encode_frame(make_frame("mono8", camera_id="a", h=48, w=64)))
    assert receiver.accept(encode_frame(make_frame("mono8", camera_id="b", h=10, w=10)))
    assert receiver.accept(encode_frame(make_frame("mono8", camera_id="a", h=480, w=640))) is None
    assert receiver.accept(encode_frame(make_frame("mono8", camera_id="c", h=48, w=64))) is None
    assert receiver.malformed.counts == {"wrong-size": 1, "unknown-camera": 1}
