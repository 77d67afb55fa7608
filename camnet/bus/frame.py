"""The frame message: one camera image on the wire.

Layout (all integers little-endian), documented byte by byte in
docs/frame-format.md::

    magic "CNFR" | version u8 | encoding u8 | compression u8 | flags u8 |
    header_size u16 | id_len u16 | width u32 | height u32 | seq u64 |
    timestamp_ns u64 | payload_size u32 | camera id (utf-8, id_len bytes) |
    payload (payload_size bytes)

Raw payloads are the pixels row by row with no padding; 16-bit pixels are
little-endian. `decode_frame` refuses anything malformed with a `FrameError`
whose `kind` says what was wrong, so receivers can count and go on.
"""

from __future__ import annotations

import enum
import functools
import struct
from dataclasses import dataclass

import numpy as np

MAGIC = b"CNFR"
VERSION = 1
_FIXED = struct.Struct("<4sBBBBHHIIQQI")
FIXED_HEADER_SIZE = _FIXED.size  # 40 bytes
# Where seq and timestamp_ns lie in the fixed header: all that changes from one frame to the next.
_SEQ_OFFSET = struct.calcsize("<4sBBBBHHII")
_SEQ_AND_TIMESTAMP = struct.Struct("<QQ")
MAX_ID_BYTES = 255
MAX_SIDE_PX = 65535


class FrameError(ValueError):
    """A malformed frame; `kind` is a short stable label for counting."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


def check_prefix(buf: memoryview, magic: bytes, version: int, fixed_size: int, error: type[ValueError]) -> None:
    """Raise `error(kind, message)` unless `buf` starts with `magic` and `version` and holds a fixed
    header of `fixed_size` bytes: the checks every camnet wire message starts with."""
    if len(buf) < 5:
        raise error("truncated", f"{len(buf)} bytes, shorter than any header")
    if bytes(buf[:4]) != magic:
        raise error("bad-magic", f"starts with {bytes(buf[:4])!r}, expected {magic!r}")
    if buf[4] != version:
        raise error("unknown-version", f"version {buf[4]}, this camnet reads {version}")
    if len(buf) < fixed_size:
        raise error("truncated", f"{len(buf)} bytes, header needs {fixed_size}")


class Compression(enum.IntEnum):
    """How a frame's pixels travel; the values are wire codes: never renumber."""

    NONE = 0
    PNG = 1
    JPEG = 2


@dataclass(frozen=True)
class EncodingSpec:
    code: int
    channels: int
    dtype: np.dtype


# ROS sensor_msgs names; codes are part of the wire format: never renumber.
ENCODINGS: dict[str, EncodingSpec] = {
    "mono8": EncodingSpec(1, 1, np.dtype(np.uint8)),
    "mono16": EncodingSpec(2, 1, np.dtype("<u2")),
    "bgr8": EncodingSpec(3, 3, np.dtype(np.uint8)),
    "rgb8": EncodingSpec(4, 3, np.dtype(np.uint8)),
    "bayer_rggb8": EncodingSpec(5, 1, np.dtype(np.uint8)),
    "bayer_bggr8": EncodingSpec(6, 1, np.dtype(np.uint8)),
    "bayer_gbrg8": EncodingSpec(7, 1, np.dtype(np.uint8)),
    "bayer_grbg8": EncodingSpec(8, 1, np.dtype(np.uint8)),
}
_BY_CODE = {spec.code: name for name, spec in ENCODINGS.items()}


@functools.lru_cache(maxsize=64)
def _check_image(encoding: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
    """Raise ValueError unless an image of `shape` and `dtype` can be `encoding`.

    Remembered (a failure is not): a camera makes every frame alike, and a
    receiver decodes one Frame per frame.
    """
    spec = ENCODINGS.get(encoding)
    if spec is None:
        known = ", ".join(ENCODINGS)
        raise ValueError(f"unknown encoding {encoding!r} (expected {known})")
    expected_ndim = 2 if spec.channels == 1 else 3
    if len(shape) != expected_ndim or (spec.channels > 1 and shape[2] != spec.channels):
        wanted = "(h, w)" if spec.channels == 1 else f"(h, w, {spec.channels})"
        raise ValueError(f"{encoding} needs shape {wanted}, got {shape}")
    if dtype.itemsize != spec.dtype.itemsize or dtype.kind != "u":
        raise ValueError(f"{encoding} needs dtype {spec.dtype.name}, got {dtype}")


@dataclass(frozen=True, eq=False, slots=True)
class Frame:
    """One image of one camera.

    `image` is (height, width) for one-channel encodings and (height, width, 3)
    for bgr8/rgb8; dtype uint8, or uint16 for mono16. `timestamp_ns` is the
    capture time in integer nanoseconds (the camera's clock when it has one,
    else the host's CLOCK_REALTIME); `seq` numbers the frames of this camera
    (a gap: lost frames; simulated cameras number the slots of their common clock).
    """

    camera_id: str
    seq: int
    timestamp_ns: int
    encoding: str
    image: np.ndarray

    def __post_init__(self) -> None:
        _check_image(self.encoding, self.image.shape, self.image.dtype)
        if not 0 <= self.seq < 2**64 or not 0 <= self.timestamp_ns < 2**64:
            raise ValueError("seq and timestamp_ns must fit in unsigned 64 bits")

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])


def encode_frame(frame: Frame, *, compression: Compression = Compression.NONE,
                 jpeg_quality: int = 90) -> bytes:
    """The wire bytes of `frame`; PNG is lossless, JPEG is lossy and 8-bit only."""
    spec = ENCODINGS[frame.encoding]
    id_bytes = _id_bytes(frame)
    image = np.ascontiguousarray(frame.image)
    if compression is Compression.NONE:
        # A view, not tobytes(): join copies the pixels once, straight into the message.
        # A second megabyte-sized temporary costs more in page faults than in copying.
        payload = memoryview(image.astype(spec.dtype, copy=False).reshape(-1).view(np.uint8))
    else:
        payload = _compress(image, compression, frame.encoding, jpeg_quality)
    return b"".join((_header(frame, id_bytes, compression, len(payload)), id_bytes, payload))


def _id_bytes(frame: Frame) -> bytes:
    id_bytes = frame.camera_id.encode("utf-8")
    if not id_bytes or len(id_bytes) > MAX_ID_BYTES:
        raise ValueError(f"camera id must be 1..{MAX_ID_BYTES} utf-8 bytes")
    if frame.width > MAX_SIDE_PX or frame.height > MAX_SIDE_PX:
        raise ValueError("image too large for the frame format")
    return id_bytes


def _header(frame: Frame, id_bytes: bytes, compression: Compression, payload_size: int) -> bytes:
    """The fixed header of `frame` (the camera id follows it)."""
    return _FIXED.pack(MAGIC, VERSION, ENCODINGS[frame.encoding].code, int(compression), 0,
                       FIXED_HEADER_SIZE + len(id_bytes), len(id_bytes), frame.width, frame.height,
                       frame.seq, frame.timestamp_ns, payload_size)


class FrameBuffer:
    """One camera's wire message, reused frame after frame: the header's room, then the pixels.

    A camera writes a frame's pixels straight into `pixels` (a view of the
    message; `fill`, from `Camera.read_into`), and `stamp` writes the
    frame's seq and timestamp into the header in front: a raw frame goes out
    without a `Frame` or a new message. The message is copied before `put`
    returns (by Zenoh, or into shared memory by the driver node), so the
    next frame may overwrite the buffer; anything that keeps a frame must
    copy its image.
    """

    __slots__ = ("camera_id", "encoding", "message", "pixels")

    def __init__(self, camera_id: str, encoding: str, shape: tuple[int, ...]) -> None:
        spec = ENCODINGS[encoding]
        self.camera_id, self.encoding = camera_id, encoding
        probe = Frame(camera_id, 0, 0, encoding, np.empty(shape, spec.dtype))  # the checks encode_frame makes
        id_bytes = _id_bytes(probe)
        header_size = FIXED_HEADER_SIZE + len(id_bytes)
        self.message = bytearray(header_size + probe.image.nbytes)
        # Everything but seq and timestamp is the same for every frame of the buffer: written once.
        self.message[:header_size] = _header(probe, id_bytes, Compression.NONE, probe.image.nbytes) + id_bytes
        self.pixels = np.frombuffer(self.message, dtype=spec.dtype, offset=header_size).reshape(shape)

    @classmethod
    def like(cls, frame: Frame) -> FrameBuffer:
        """A buffer for frames of `frame`'s camera, encoding and size."""
        return cls(frame.camera_id, frame.encoding, frame.image.shape)

    def fill(self, seq: int, timestamp_ns: int, encoding: str, image: np.ndarray) -> tuple[int, int] | Frame:
        """What `Camera.read_into` returns for a frame: ``(seq, timestamp_ns)`` with `image` copied into
        `pixels` when this buffer carries such frames (its encoding, shape and dtype), else the Frame, its
        image its own.

        On a camera's every frame: the checks are ordered cheapest first, and
        dtypes compared by identity before equality (numpy's are mostly singletons).
        """
        pixels = self.pixels
        if image.shape == pixels.shape and encoding == self.encoding and (
                image.dtype is pixels.dtype or image.dtype == pixels.dtype):
            pixels[...] = image
            return seq, timestamp_ns
        return Frame(self.camera_id, seq, timestamp_ns, encoding, image)

    def stamp(self, seq: int, timestamp_ns: int) -> bytearray:
        """The message of the frame in `pixels`, numbered `seq` and taken at `timestamp_ns`: ready to put.

        Only seq and timestamp change from frame to frame; the rest of the
        header was written with the buffer.
        """
        try:
            _SEQ_AND_TIMESTAMP.pack_into(self.message, _SEQ_OFFSET, seq, timestamp_ns)
        except struct.error:
            raise ValueError(f"camera {self.camera_id}: seq {seq} and timestamp_ns {timestamp_ns} "
                             "must fit in unsigned 64 bits") from None
        return self.message

    def frame(self, seq: int, timestamp_ns: int) -> Frame:
        """The frame in `pixels` as a `Frame` of its own (its pixels copied: the buffer moves on)."""
        return Frame(self.camera_id, seq, timestamp_ns, self.encoding, self.pixels.copy())


def _compress(image: np.ndarray, compression: Compression, encoding: str, quality: int) -> bytes:
    import cv2  # imported here: raw frames need no codec

    if compression is Compression.JPEG:
        if image.dtype != np.uint8:
            raise ValueError(f"JPEG cannot carry {encoding}; use PNG or no compression")
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    else:
        ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"could not compress a {encoding} image as {compression.name}")
    return buf.tobytes()


@dataclass(frozen=True)
class FrameHeader:
    """What the header of a wire frame says; `payload_size` bytes follow `header_size` ones."""

    camera_id: str
    seq: int
    timestamp_ns: int
    encoding: str
    compression: Compression
    width: int
    height: int
    header_size: int
    payload_size: int


def decode_header(data: bytes | bytearray | memoryview) -> FrameHeader:
    """The header of the frame in `data`, without touching its pixels.

    Checks the magic, version, header, sizes, encoding and compression, so a
    frame that passes is complete; raises FrameError (never anything else)
    otherwise.
    """
    buf = memoryview(data).cast("B")
    check_prefix(buf, MAGIC, VERSION, FIXED_HEADER_SIZE, FrameError)
    (_, _, code, comp, _flags, header_size, id_len, width, height, seq, timestamp_ns,
     payload_size) = _FIXED.unpack_from(buf, 0)
    if header_size != FIXED_HEADER_SIZE + id_len or id_len == 0:
        raise FrameError("bad-header", f"header_size {header_size} with id_len {id_len}")
    if len(buf) < header_size + payload_size:
        raise FrameError("truncated", f"{len(buf)} bytes, frame needs {header_size + payload_size}")
    if len(buf) > header_size + payload_size:
        raise FrameError("trailing-bytes", f"{len(buf) - header_size - payload_size} extra bytes")
    encoding = _BY_CODE.get(code)
    if encoding is None:
        raise FrameError("bad-encoding", f"encoding code {code}")
    try:
        compression = Compression(comp)
    except ValueError:
        raise FrameError("bad-compression", f"compression code {comp}") from None
    try:
        camera_id = bytes(buf[FIXED_HEADER_SIZE:header_size]).decode("utf-8")
    except UnicodeDecodeError:
        raise FrameError("bad-camera-id", "camera id is not utf-8") from None
    if width == 0 or height == 0:
        raise FrameError("bad-size", f"{width}x{height}")
    return FrameHeader(camera_id, seq, timestamp_ns, encoding, compression, width, height, header_size,
                       payload_size)


def decode_frame(data: bytes | bytearray | memoryview) -> Frame:
    """The Frame in `data`; raises FrameError (never anything else) if malformed.

    From immutable `bytes`, raw pixels are not copied: the image is a read-only
    view that keeps `data` alive (copy it to modify). From a mutable buffer
    the pixels are copied.
    """
    header = decode_header(data)
    # Slicing a memoryview copies nothing; slicing bytes would copy the pixels.
    payload = memoryview(data).cast("B")[header.header_size:header.header_size + header.payload_size]
    image = _pixels(payload, header.compression, header.encoding, header.width, header.height,
                    owned=isinstance(data, bytes))
    return Frame(camera_id=header.camera_id, seq=header.seq, timestamp_ns=header.timestamp_ns,
                 encoding=header.encoding, image=image)


def _pixels(payload, compression: Compression, encoding: str, width: int,
            height: int, *, owned: bool) -> np.ndarray:
    spec = ENCODINGS[encoding]
    shape = (height, width) if spec.channels == 1 else (height, width, spec.channels)
    if compression is Compression.NONE:
        expected = width * height * spec.channels * spec.dtype.itemsize
        if len(payload) != expected:
            raise FrameError("bad-size", f"{len(payload)} pixel bytes, {width}x{height} "
                             f"{encoding} needs {expected}")
        image = np.frombuffer(payload, dtype=spec.dtype).reshape(shape)
        if not owned:
            # The caller's buffer may be reused: the image must not alias it.
            image = image.copy()
        return image.astype(spec.dtype.newbyteorder("="), copy=False)
    import cv2

    # Decoding allocates what the compressed stream declares, which may be far more than the
    # header says (a 250 KB PNG can hold 16000 x 16000 pixels): compare before decoding.
    declared = compressed_size(payload, compression)
    if declared != (width, height):
        raise FrameError("bad-size", f"{compression.name} payload declares {declared}, header says {width}x{height}")
    image = cv2.imdecode(np.frombuffer(payload, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FrameError("bad-payload", f"{compression.name} payload does not decode")
    if image.shape != shape or image.dtype.itemsize != spec.dtype.itemsize:
        raise FrameError("bad-size", f"decoded {image.shape} {image.dtype}, header says "
                         f"{shape} {encoding}")
    return image


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}  # frame headers


def compressed_size(payload, compression: Compression) -> tuple[int, int] | None:
    """(width, height) a PNG or JPEG stream declares, read from its header alone; None if unreadable.

    PNG: the IHDR chunk that must come first. JPEG: the first start-of-frame
    marker (SOFn), after the segments before it.
    """
    data = bytes(payload[:65536]) if compression is Compression.JPEG else bytes(payload[:24])
    if compression is Compression.PNG:
        if len(data) < 24 or data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR":
            return None
        return struct.unpack(">II", data[16:24])
    at = 2 if data[:2] == b"\xff\xd8" else len(data)
    while at + 9 <= len(data) and data[at] == 0xFF:
        marker, length = data[at + 1], struct.unpack(">H", data[at + 2:at + 4])[0]
        if marker in _JPEG_SOF:
            height, width = struct.unpack(">HH", data[at + 5:at + 9])
            return width, height
        at += 2 + length
    return None
