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
def test_a_sealed_buffer_is_the_encoded_frame_and_decodes_back(encoding):
    spec = ENCODINGS[encoding]
    shape = (5, 7) if spec.channels == 1 else (5, 7, 3)
    buffer = FrameBuffer("cam_é", encoding, shape)
    for seq in (3, 4):  # the second frame overwrites the first in the same buffer
        np.copyto(buffer.pixels, pattern(seq, shape, spec.dtype))
        frame = Frame("cam_é", seq, 1_700_000_000_000_000_000 + seq, encoding, buffer.pixels)
        message = buffer.seal(frame)
        assert bytes(message) == encode_frame(Frame("cam_é", seq, frame.timestamp_ns, encoding,
                                                    pattern(seq, shape, spec.dtype)))
        back = decode_frame(bytes(message))
        assert back.seq == seq and np.array_equal(back.image, pattern(seq, shape, spec.dtype))


def test_seal_refuses_pixels_that_are_not_in_the_buffer():
    buffer = FrameBuffer("c", "mono8", (4, 4))
    elsewhere = Frame("c", 0, 0, "mono8", np.zeros((4, 4), np.uint8))
    assert not buffer.holds(elsewhere)
    with pytest.raises(ValueError, match="not in this buffer"):
        buffer.seal(elsewhere)
    assert not buffer.holds(Frame("other", 0, 0, "mono8", buffer.pixels))


class PatternCamera:
    """A Camera whose frame `seq` is `pattern(seq)`, written into `out` when given; logs what it got."""

    def __init__(self, n_frames: int, shape=(240, 320)) -> None:
        self.camera_id, self.groundtruth, self.dropped = "left", None, 0
        self.shape, self.n_frames, self.seq = shape, n_frames, 0
        self.outs: list[np.ndarray | None] = []
        self.info = DeviceInfo("left", "test", shape[1], shape[0], "mono8", 0.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        return None

    def read(self, *, timeout_s: float = 1.0, out: np.ndarray | None = None) -> Frame:
        time.sleep(0.01)  # a camera's pace: the subscriber keeps up
        self.outs.append(out)
        image = pattern(self.seq, self.shape, np.uint8)
        if out is not None:
            np.copyto(out, image)
            image = out
        frame = Frame(self.camera_id, self.seq, time.time_ns(), "mono8", image)
        self.seq += 1
        return frame


def test_the_driver_node_publishes_each_frame_with_its_own_pixels_through_one_buffer(zenoh_pair):
    from camnet.drivers.node import DriverNode

    from camnet.io.rig import load_rig

    listener, connector = zenoh_pair
    rig = load_rig(CONFIG / "sim.yaml")
    camera = PatternCamera(n_frames=12)
    assert isinstance(camera, Camera)
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
    node.run(max_frames=12)
    assert wait_for(lambda: len(received) >= 10, 60.0, progress=lambda: len(received)), \
        f"{len(received)} frames arrived"
    sub.undeclare()
    # One buffer, reused: the camera got the node's pixels array from the second frame on.
    outs = camera.outs
    assert outs[0] is None and all(o is outs[1] for o in outs[1:])
    # Every frame that arrived carries its own pixels, none another's (Zenoh copied each before
    # put returned); the frames handed to on_frame kept theirs after the buffer moved on.
    for frame in received + offered:
        assert np.array_equal(frame.image, pattern(frame.seq, camera.shape, np.uint8)), frame.seq
    assert [f.seq for f in offered] == list(range(12))
    # Large enough for Zenoh shared memory, which the node leaves off by default: all went as bytes.
    assert (node.frames_out.shared, node.frames_out.copied) == (0, 12)
    assert len({f.seq for f in received}) == len(received)
