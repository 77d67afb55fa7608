"""A simulated rig's frames as image folders with their capture times: what the v4l2 example replays."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from camnet.drivers.v4l2 import frame_index, parse_timestamps

from camnet.errors import InputError
from camnet.io.image_sequence import TIMESTAMPS, kitti_stamp, main, write_image_sequence
from camnet.io.rig import load_rig, parse_rig

EXAMPLE_IMAGES = Path(__file__).resolve().parents[1] / "config" / "example-images"


def test_stamps_are_read_back_as_written():
    times_ns = [1_704_067_200_000_000_000, 1_704_067_200_500_000_001, 1_999_999_999_123_456_789]
    text = "".join(f"{kitti_stamp(t)}\n" for t in times_ns)
    assert text.splitlines()[1] == "2024-01-01 00:00:00.500000001"
    assert parse_timestamps(text, source="t").tolist() == times_ns


def test_the_shipped_example_images_are_what_their_rig_renders(tmp_path):
    """config/example-images is made by the command its rig file names: rendered again, the same images
    (give or take JPEG's rounding), stamps and frame indices."""
    assert main([str(EXAMPLE_IMAGES / "sim-rig.yaml"), str(tmp_path), "--frames", "2"]) == 0
    rig = load_rig(EXAMPLE_IMAGES / "sim-rig.yaml")
    for entry in rig.cameras:
        shipped = sorted((EXAMPLE_IMAGES / entry.id).glob("*.jpg"))
        again = sorted((tmp_path / entry.id).glob("*.jpg"))
        assert [p.name for p in shipped] == [p.name for p in again] == ["000000.jpg", "000001.jpg"]
        assert [frame_index(str(p)) for p in shipped] == [0, 1]
        for a, b in zip(shipped, again, strict=True):
            image_a, image_b = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
            assert image_a.shape == (entry.config.height, entry.config.width) == image_b.shape
            assert np.mean(np.abs(image_a.astype(int) - image_b)) < 1.0, (entry.id, a.name)
        assert (EXAMPLE_IMAGES / entry.id / TIMESTAMPS).read_text() == (tmp_path / entry.id / TIMESTAMPS).read_text()
    shipped_bytes = sum(p.stat().st_size for p in EXAMPLE_IMAGES.rglob("*") if p.is_file())
    assert shipped_bytes < 1_000_000, f"the example takes {shipped_bytes} bytes of every clone"


def test_only_simulated_cameras_are_rendered(tmp_path):
    rig = parse_rig({"rig": "r", "stereo": {"left": "a", "right": "b", "baseline_m": 0.1},
                     "cameras": [{"id": "a", "driver": "sim", "sim": {"width": 64, "height": 48, "f_px": 50}},
                                 {"id": "b", "driver": "v4l2", "v4l2": {"source": "/dev/video0"}}]},
                    source="rig.yaml")
    with pytest.raises(InputError, match=r"rig.yaml: camera b is not simulated"):
        write_image_sequence(rig, tmp_path, frames=2, fps=2.0)
    assert not any(tmp_path.iterdir())
