"""The features message: one camera's keypoints and descriptors of one frame on the wire.

Layout (all integers little-endian), documented byte by byte in
docs/features-format.md::

    magic "CNFT" | version u8 | detector u8 | flags u8 | reserved u8 |
    header_size u16 | id_len u16 | width u32 | height u32 | seq u64 |
    timestamp_ns u64 | keyframe_seq u64 | count u32 | reused u32 |
    descriptor_size u16 | reserved u16 | camera id (utf-8, id_len bytes) |
    uv (count x 2 float32) | descriptors (count x descriptor_size uint8)

SIFT's descriptors are whole numbers 0-255 (OpenCV rounds them), so both
detectors' descriptors travel as bytes: a quarter of SIFT's float32 size,
without loss. `decode_features` refuses anything malformed with a
`FeaturesError` whose `kind` says what was wrong.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from camnet.bus.frame import check_prefix

MAGIC = b"CNFT"
VERSION = 1
_FIXED = struct.Struct("<4sBBBBHHIIQQQIIHH")
FIXED_HEADER_SIZE = _FIXED.size  # 56 bytes
MAX_ID_BYTES = 255
# Detector codes are part of the wire format: never renumber. Descriptor bytes per keypoint.
DETECTORS = {"sift": (1, 128), "orb": (2, 32)}
_BY_CODE = {code: name for name, (code, _) in DETECTORS.items()}


class FeaturesError(ValueError):
    """A malformed features message; `kind` is a short stable label for counting."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


@dataclass(frozen=True, eq=False)
class FeaturesMessage:
    """Keypoints of one frame of one camera.

    `uv` (n, 2) pixels (origin at the centre of the top-left pixel) and
    `descriptors` (n, d) uint8; `seq` and `timestamp_ns` are the frame's. The
    first `reused` keypoints are unchanged from frame `keyframe_seq` of this
    camera (static background); the rest were detected in this frame.
    """

    camera_id: str
    seq: int
    timestamp_ns: int
    width: int
    height: int
    detector: str
    keyframe_seq: int
    reused: int
    uv: np.ndarray
    descriptors: np.ndarray

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise ValueError(f"unknown detector {self.detector!r} (expected {', '.join(DETECTORS)})")
        n, size = len(self.uv), DETECTORS[self.detector][1]
        if self.uv.shape != (n, 2) or self.descriptors.shape != (n, size):
            raise ValueError(f"{self.detector} needs uv (n, 2) and descriptors (n, {size}), got "
                             f"{self.uv.shape} and {self.descriptors.shape}")
        if not 0 <= self.reused <= n:
            raise ValueError(f"reused must be in [0, {n}], got {self.reused}")
        for name in ("seq", "timestamp_ns", "keyframe_seq"):
            if not 0 <= getattr(self, name) < 2**64:
                raise ValueError(f"{name} must fit in unsigned 64 bits")
        if not 0 < self.width < 2**32 or not 0 < self.height < 2**32:
            raise ValueError(f"bad image size {self.width}x{self.height}")


def encode_features(message: FeaturesMessage) -> bytes:
    """The wire bytes of `message`; descriptors must be whole numbers 0-255."""
    id_bytes = message.camera_id.encode("utf-8")
    if not id_bytes or len(id_bytes) > MAX_ID_BYTES:
        raise ValueError(f"camera id must be 1..{MAX_ID_BYTES} utf-8 bytes")
    code, size = DETECTORS[message.detector]
    descriptors = np.asarray(message.descriptors)
    as_bytes = descriptors.astype(np.uint8)
    if descriptors.dtype != np.uint8 and not np.array_equal(as_bytes, descriptors):
        raise ValueError("descriptors must be whole numbers 0-255")
    header = _FIXED.pack(MAGIC, VERSION, code, 0, 0, FIXED_HEADER_SIZE + len(id_bytes), len(id_bytes),
                         message.width, message.height, message.seq, message.timestamp_ns, message.keyframe_seq,
                         len(message.uv), message.reused, size, 0)
    return b"".join((header, id_bytes, np.ascontiguousarray(message.uv, dtype="<f4").tobytes(),
                     np.ascontiguousarray(as_bytes).tobytes()))


def decode_features(data: bytes | bytearray | memoryview) -> FeaturesMessage:
    """The FeaturesMessage in `data`; raises FeaturesError (never anything else) if malformed."""
    buf = memoryview(data).cast("B")
    check_prefix(buf, MAGIC, VERSION, FIXED_HEADER_SIZE, FeaturesError)
    (_, _, code, _flags, _, header_size, id_len, width, height, seq, timestamp_ns, keyframe_seq, count, reused,
     size, _) = _FIXED.unpack_from(buf, 0)
    if header_size != FIXED_HEADER_SIZE + id_len or id_len == 0:
        raise FeaturesError("bad-header", f"header_size {header_size} with id_len {id_len}")
    detector = _BY_CODE.get(code)
    if detector is None:
        raise FeaturesError("bad-detector", f"detector code {code}")
    if size != DETECTORS[detector][1]:
        raise FeaturesError("bad-header", f"{detector} descriptors of {size} bytes, expected {DETECTORS[detector][1]}")
    expected = header_size + count * (8 + size)
    if len(buf) != expected:
        kind = "truncated" if len(buf) < expected else "trailing-bytes"
        raise FeaturesError(kind, f"{len(buf)} bytes, {count} keypoints need {expected}")
    if reused > count or width == 0 or height == 0:
        raise FeaturesError("bad-header", f"{reused} reused of {count} keypoints, size {width}x{height}")
    try:
        camera_id = bytes(buf[FIXED_HEADER_SIZE:header_size]).decode("utf-8")
    except UnicodeDecodeError:
        raise FeaturesError("bad-camera-id", "camera id is not utf-8") from None
    uv = np.frombuffer(buf, dtype="<f4", count=2 * count, offset=header_size).reshape(count, 2).astype(float)
    if not np.all(np.isfinite(uv)):
        raise FeaturesError("bad-keypoints", "a keypoint is not a finite pixel")
    descriptors = np.frombuffer(buf, dtype=np.uint8, count=count * size,
                                offset=header_size + 8 * count).reshape(count, size).copy()
    return FeaturesMessage(camera_id, seq, timestamp_ns, width, height, detector, keyframe_seq, reused, uv,
                           descriptors)
