"""The v4l2 driver on an image sequence and a video file written here (no /dev/video)."""

import cv2
import numpy as np
import pytest
from camnet.drivers.base import DeviceError, EndOfStream
from camnet.drivers.v4l2 import V4l2Camera

from camnet.io.rig import V4l2Config


def config(source: str, **overrides) -> V4l2Config:
    values = dict(source=source, width=None, height=None, fps=200.0, fourcc=None,
                  encoding="bgr8", loop=False)
    values.update(overrides)
    return V4l2Config(**values)


def images(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8) for _ in range(n)]


def test_image_sequence_in_order_then_end(tmp_path):
    originals = images(5)
    for i, image in enumerate(originals):
        cv2.imwrite(str(tmp_path / f"img_{i:03d}.png"), image)
    with V4l2Camera("seq", config(str(tmp_path / "img_*.png"))) as cam:
        assert (cam.info.width, cam.info.height, cam.info.encoding) == (64, 48, "bgr8")
        frames = [cam.read() for _ in originals]
        with pytest.raises(EndOfStream):
            cam.read()
    assert [f.seq for f in frames] == list(range(5))
    assert all(np.array_equal(f.image, o) for f, o in zip(frames, originals, strict=True))
    assert np.all(np.diff([f.timestamp_ns for f in frames]) == 5_000_000)


def test_image_sequence_loops_and_converts_to_mono(tmp_path):
    originals = images(2)
    for i, image in enumerate(originals):
        cv2.imwrite(str(tmp_path / f"img_{i}.png"), image)
    with V4l2Camera("seq", config(str(tmp_path / "*.png"), loop=True, encoding="mono8")) as cam:
        frames = [cam.read() for _ in range(5)]
    assert frames[4].image.ndim == 2
    assert np.array_equal(frames[4].image, cv2.cvtColor(originals[0], cv2.COLOR_BGR2GRAY))


def test_video_file(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48))
    assert writer.isOpened()
    levels = [20 * i for i in range(8)]
    for level in levels:
        writer.write(np.full((48, 64, 3), level, np.uint8))
    writer.release()
    with V4l2Camera("vid", config(str(path), fps=None)) as cam:
        assert cam.info.fps == 25.0
        frames = []
        with pytest.raises(EndOfStream):
            while True:
                frames.append(cam.read())
    assert len(frames) == len(levels)
    assert [round(float(f.image.mean()) / 20) * 20 for f in frames] == levels


def test_missing_source_is_named(tmp_path):
    with pytest.raises(DeviceError, match=f"'nope': no image in {tmp_path} matches '\\*.png'"):
        V4l2Camera("nope", config(str(tmp_path / "*.png"))).__enter__()
    with pytest.raises(DeviceError, match=f"'nope': no folder {tmp_path / 'absent'} for its images"):
        V4l2Camera("nope", config(str(tmp_path / "absent" / "*.png"))).__enter__()
    with pytest.raises(DeviceError, match="neither a device"):
        V4l2Camera("nope", config(str(tmp_path / "missing.avi"))).__enter__()
