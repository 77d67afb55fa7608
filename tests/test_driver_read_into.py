"""`Camera.read_into`: each driver writes a frame's pixels into the node's reused message and hands back
only its seq and timestamp, and the message is the same bytes `encode_frame` makes of the frame `read`
gives. A frame the buffer cannot carry (another size) comes back as a Frame of its own."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from camnet.drivers.base import Camera, create_camera
from camnet.drivers.v4l2 import V4l2Camera

from camnet.bus.frame import Frame, FrameBuffer, decode_frame, encode_frame
from camnet.io.rig import V4l2Config, load_rig
from tests.test_rig import CONFIG


def fast_sim_camera(encoding: str) -> Camera:
    """config/sim.yaml's right camera in `encoding` at 5000 fps: faster than rendering (2 ms a frame with
    its cached background), so that reads come at once and slots are skipped, counted and seen as gaps."""
    rig = load_rig(CONFIG / "sim.yaml")
    entry = rig.camera("right")
    entry = replace(entry, config=replace(entry.config, encoding=encoding, fps=5000.0))
    camera = create_camera(entry, rig)
    assert isinstance(camera, Camera)
    return camera


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "bgr8"])
def test_the_sim_camera_writes_into_the_buffer_the_bytes_of_the_frame_it_renders(encoding):
    camera = fast_sim_camera(encoding)
    with camera:
        buffer = FrameBuffer.like(camera.read(timeout_s=1.0))
        stamps = [camera.read_into(buffer, timeout_s=1.0) for _ in range(2)]
    seq, timestamp_ns = stamps[-1]
    message = bytes(buffer.stamp(seq, timestamp_ns))
    assert stamps[0][0] < seq and timestamp_ns == camera.slot_timestamp_ns(seq)
    # A slot's image is deterministic (its noise is seeded by the slot): rendered again, it is the same.
    assert message == encode_frame(Frame("right", seq, timestamp_ns, encoding, camera.render(seq)))


def write_images(directory, shapes: list[tuple[int, int]]) -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, size=(*shape, 3), dtype=np.uint8) for shape in shapes]
    for i, image in enumerate(images):
        cv2.imwrite(str(directory / f"img_{i:03d}.png"), image)
    return images


@pytest.mark.parametrize("encoding", ["bgr8", "mono8"])
def test_a_v4l2_sequence_read_into_the_buffer_is_the_same_bytes_as_read_frame_by_frame(tmp_path, encoding):
    # The third image is of another size: it comes back as a Frame, and a new buffer carries the rest.
    shapes = [(48, 64), (48, 64), (32, 40), (32, 40), (32, 40)]
    write_images(tmp_path, shapes)
    config = V4l2Config(source=str(tmp_path / "img_*.png"), width=None, height=None, fps=500.0, fourcc=None,
                        encoding=encoding, loop=False)
    with V4l2Camera("seq", config) as by_frame:
        frames = [by_frame.read(timeout_s=1.0) for _ in shapes]
    with V4l2Camera("seq", config) as into:
        first = into.read(timeout_s=1.0)
        buffer = FrameBuffer.like(first)
        sent, kinds = [encode_frame(first)], []
        for _ in shapes[1:]:
            got = into.read_into(buffer, timeout_s=1.0)
            if isinstance(got, Frame):
                kinds.append("frame")
                buffer = FrameBuffer.like(got)
                sent.append(encode_frame(got))
            else:
                kinds.append("in place")
                sent.append(bytes(buffer.stamp(*got)))
    assert kinds == ["in place", "frame", "in place", "in place"]
    # A sequence is stamped from the host clock at its opening: the second camera's stamps are its own.
    stamps = [decode_frame(message).timestamp_ns for message in sent]
    assert np.all(np.diff(stamps) == 2_000_000)
    assert sent == [encode_frame(replace(frame, timestamp_ns=stamp))
                    for frame, stamp in zip(frames, stamps, strict=True)]
