"""Raw frames written in place into a reused message (FrameBuffer), and the driver node that
publishes them so: the same bytes as encode_frame, and no frame carries another's pixels."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from camnet.drivers.base import Camera, DeviceInfo

from camnet.bus import keys
from camnet.bus.frame import ENCODINGS, Frame, FrameBuffer, decode_frame, encode_frame
from tests.conftest import matched_publisher, wait_for

CONFIG = Path(__file__).resolve().parent.parent / "config"


def pattern(seq: int, shape: tuple[int, ...], dtype) -> np.ndarray:
    """An image that differs from every other seq's in every pixel."""
    high = 65536 if np.dtype(dtype).itemsize == 2 else 256
    return ((np.arange(int(np.prod(shape))) * 7 + seq * 101) % high).astype(dtype).reshape(shape)


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8"])
def test_a_filled_and_stamped_buffer_is_the_encoded_frame_and_decodes_back(encoding):
    spec = ENCODINGS[encoding]
    shape = (5, 7) if spec.channels == 1 else (5, 7, 3)
    buffer = FrameBuffer("cam_é", encoding, shape)
    for seq in (3, 4):  # the second frame overwrites the first in the same buffer
        timestamp_ns = 1_700_000_000_000_000_000 + seq
        assert buffer.fill(seq, timestamp_ns, encoding, pattern(seq, shape, spec.dtype)) == (seq, timestamp_ns)
        message = buffer.stamp(seq, timestamp_ns)
        assert bytes(message) == encode_frame(Frame("cam_é", seq, timestamp_ns, encoding,
                                                    pattern(seq, shape, spec.dtype)))
        back = decode_frame(bytes(message))
        assert back.seq == seq and np.array_equal(back.image, pattern(seq, shape, spec.dtype))
        kept = buffer.frame(seq, timestamp_ns)  # its own pixels: the buffer moves on
        assert kept.image is not buffer.pixels and encode_frame(kept) == bytes(message)


@pytest.mark.parametrize(("encoding", "image"), [
    ("mono8", np.zeros((4, 5), np.uint8)),  # another size
    ("bgr8", np.zeros((4, 4, 3), np.uint8)),  # another encoding
    ("rgb8", np.zeros((4, 4, 3), np.uint8)),  # another encoding of the same shape and dtype
    ("mono16", np.zeros((4, 4), np.uint16)),  # another dtype
])
def test_a_frame_the_buffer_cannot_carry_comes_back_as_a_frame_of_its_own(encoding, image):
    buffer = FrameBuffer("c", "bgr8", (4, 4, 3)) if encoding == "rgb8" else FrameBuffer("c", "mono8", (4, 4))
    before = bytes(buffer.message)
    frame = buffer.fill(7, 8, encoding, image)
    assert isinstance(frame, Frame) and frame.image is image
    assert (frame.camera_id, frame.seq, frame.timestamp_ns, frame.encoding) == ("c", 7, 8, encoding)
    assert bytes(buffer.message) == before


def test_stamp_refuses_what_the_header_cannot_hold():
    buffer = FrameBuffer("c", "mono8", (4, 4))
    with pytest.raises(ValueError, match="camera c: seq -1 .*unsigned 64 bits"):
        buffer.stamp(-1, 0)
    with pytest.raises(ValueError, match="unsigned 64 bits"):
        buffer.stamp(0, 2**64)


class PatternCamera:
    """A Camera whose frame `seq` is `pattern(seq)`; logs which way each frame was read."""

    def __init__(self, n_frames: int, shape=(240, 320), *, resized_at: int | None = None) -> None:
        self.camera_id, self.groundtruth, self.dropped = "left", None, 0
        self.shape, self.n_frames, self.seq = shape, n_frames, 0
        self.resized_at = resized_at  # from this frame on, half the size (a camera reconfigured)
        self.calls: list[str] = []  # "read", or "read_into" (then `buffers` has its buffer)
        self.buffers: list[FrameBuffer] = []
        self.info = DeviceInfo("left", "test", shape[1], shape[0], "mono8", 0.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        return None

    def shape_of(self, seq: int) -> tuple[int, int]:
        resized = self.resized_at is not None and seq >= self.resized_at
        return (self.shape[0] // 2, self.shape[1] // 2) if resized else self.shape

    def _next(self) -> tuple[int, int, str, np.ndarray]:
        time.sleep(0.01)  # a camera's pace: the subscriber keeps up
        self.seq += 1
        return self.seq - 1, time.time_ns(), "mono8", pattern(self.seq - 1, self.shape_of(self.seq - 1), np.uint8)

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        self.calls.append("read")
        return Frame(self.camera_id, *self._next())

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0) -> tuple[int, int] | Frame:
        self.calls.append("read_into")
        self.buffers.append(buffer)
        return buffer.fill(*self._next())


def _run_node(zenoh_pair, camera, frames: int, at_least: int):
    """(node, frames received on the bus, frames handed to on_frame) of a driver node that ran `frames`
    frames of `camera` as the sim rig's "left"; at least `at_least` received."""
    from camnet.drivers.node import DriverNode

    from camnet.io.rig import load_rig

    listener, connector = zenoh_pair
    rig = load_rig(CONFIG / "sim.yaml")
    received: list[Frame] = []
    offered: list[Frame] = []
    lock = threading.Lock()

    def on_sample(sample):
        frame = decode_frame(sample.payload.to_bytes())
        with lock:
            received.append(frame)

    sub = listener.declare_subscriber(keys.frame(rig.name, "left"), on_sample)
    # The publishing peer knows of the subscription before the first frame goes (not after a fixed delay).
    matched_publisher(connector, keys.frame(rig.name, "left")).undeclare()
    node = DriverNode(connector, rig, camera, on_frame=offered.append)
    node.run(max_frames=frames)
    assert wait_for(lambda: len(received) >= at_least, 60.0, progress=lambda: len(received)), \
        f"{len(received)} frames arrived"
    sub.undeclare()
    return node, received, offered


def test_the_driver_node_publishes_each_frame_with_its_own_pixels_through_one_buffer(zenoh_pair):
    camera = PatternCamera(n_frames=12)
    assert isinstance(camera, Camera)
    node, received, offered = _run_node(zenoh_pair, camera, 12, 10)
    # One buffer, reused: the first frame read as a Frame, every later one into the node's buffer,
    # the camera handing back only its seq and timestamp.
    assert camera.calls == ["read"] + ["read_into"] * 11
    assert all(b is camera.buffers[0] for b in camera.buffers)
    # Every frame that arrived carries its own pixels, none another's (Zenoh copied each before
    # put returned); the frames handed to on_frame kept theirs after the buffer moved on.
    for frame in received + offered:
        assert np.array_equal(frame.image, pattern(frame.seq, camera.shape_of(frame.seq), np.uint8)), frame.seq
    assert [f.seq for f in offered] == list(range(12))
    # Large enough for Zenoh shared memory, which the node leaves off by default: all went as bytes.
    assert (node.frames_out.shared, node.frames_out.copied) == (0, 12)
    assert len({f.seq for f in received}) == len(received)


def test_a_camera_that_changes_size_gets_a_new_buffer_and_every_frame_arrives_whole(zenoh_pair):
    camera = PatternCamera(n_frames=10, resized_at=5)
    _, received, offered = _run_node(zenoh_pair, camera, 10, 8)
    # Frame 5 did not fit the buffer: it came back as a Frame, and a buffer of its size took the rest.
    assert camera.calls == ["read"] + ["read_into"] * 9
    assert camera.buffers[3] is camera.buffers[0] and camera.buffers[4] is camera.buffers[3]
    assert camera.buffers[5] is not camera.buffers[4] and all(b is camera.buffers[5] for b in camera.buffers[5:])
    assert camera.buffers[5].pixels.shape == camera.shape_of(5)
    for frame in received + offered:
        assert np.array_equal(frame.image, pattern(frame.seq, camera.shape_of(frame.seq), np.uint8)), frame.seq
    assert [f.seq for f in offered] == list(range(10))
