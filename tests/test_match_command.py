"""`camnet match`: one real image per camera into camnet.observations/1, and its refusals."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from camnet.datasets.strecha import image_path, in_frame_of, read_cameras
from camnet.io.formats import load_json, parse_observations
from tests._groundtruth import STRECHA_ROOT, pairwise_epipolar_fractions, require

ROOT = Path(__file__).resolve().parent.parent
VIEWS = ("0004", "0005", "0006")
# Images only: no drivers, sizes from the images, the pair's published distance (a converging pair).
RIG = """rig: fountain
stereo: {left: "0004", right: "0005", baseline_m: 1.8243}
cameras:
  - id: "0004"
  - id: "0005"
  - id: "0006"
"""


def camnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)


def test_fountain_images_become_tracks_on_the_published_epipolar_lines(tmp_path, record_property):
    root = require(STRECHA_ROOT)
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    out = tmp_path / "obs.json"
    # The file stem names the camera, or ID=PATH does.
    images = [str(image_path(root, "0004")), str(image_path(root, "0006")), f"0005={image_path(root, '0005')}"]
    result = camnet("match", *images, "--rig", str(rig), "-o", str(out), "--max-image-side-px", "1024")
    assert result.returncode == 0, result.stderr
    obs = parse_observations(load_json(out))
    assert [c.id for c in obs.cameras] == list(VIEWS) and (obs.cameras[0].width, obs.cameras[0].height) == (3072, 2048)
    assert (obs.stereo.left, obs.stereo.right, obs.stereo.baseline_m) == ("0004", "0005", 1.8243)
    assert json.loads(result.stdout)["tracks"] == len(obs.track_ids)
    truth = in_frame_of(read_cameras(root), "0004")
    uv = np.full((len(obs.track_ids), len(VIEWS), 2), np.nan)
    uv[obs.track_index, obs.cam_index] = obs.uv
    # Full-size pixels from detection at a third of the size: 3 px is one detection pixel.
    fractions = pairwise_epipolar_fractions(uv, [truth[c] for c in VIEWS], 3.0)
    record_property("pair_fractions", fractions)
    for pair, (count, fraction) in fractions.items():
        assert count >= 500 and fraction >= 0.95, (pair, count, fraction)


@pytest.mark.parametrize(
    ("images", "message"),
    [
        (["a.png", "b.png"], r"no image for camera c: give one image per camera of the rig \(3\), 2 given"),
        (["a.png", "b.png", "c.png", "d.png"], r"d.png: no camera 'd' in the rig \(cameras: a, b, c\)"),
        (["a.png", "b.png", "a=c.png"], r"a=c.png: a second image for camera 'a'"),
        (["a.png", "b.png", "missing/c.png"], r"missing/c.png: no such image file"),
        (["a.png", "b.png", "c=text.png"], r"text.png: cannot be read as an image"),
        (["a.png", "b.png", "c=small.png"], r"small.png: 32x24 pixels, but the rig file says 64x48"),
    ],
    ids=["count", "unknown-id", "twice", "missing", "unreadable", "size"],
)
def test_bad_input_is_one_line_with_no_output(tmp_path, images, message):
    rng = np.random.default_rng(0)
    for name in ("a", "b", "c"):
        cv2.imwrite(str(tmp_path / f"{name}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((24, 32), np.uint8))
    (tmp_path / "text.png").write_text("not an image")
    rig = tmp_path / "rig.yaml"
    rig.write_text("rig: r\nstereo: {left: a, right: b, baseline_m: 0.1}\ncameras:\n  - id: a\n  - id: b\n"
                   "  - {id: c, driver: sim, sim: {width: 64, height: 48, f_px: 50}}\n")
    out = tmp_path / "obs.json"
    result = subprocess.run([sys.executable, "-m", "camnet", "match", *images, "--rig", str(rig), "-o", str(out)],
                            cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert result.stderr.startswith("camnet match: error: ")
    assert re.search(message, result.stderr), result.stderr
    assert not out.exists()


def test_a_rig_of_images_is_refused_by_camnet_up(tmp_path):
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    result = camnet("up", str(rig), "--duration-s", "1")
    assert result.returncode == 2
    assert "cameras[0] (0004) has no driver; camnet up runs one per camera" in result.stderr


def test_dark_images_are_matched_once_normalised_and_refused_with_the_reason_otherwise(tmp_path):
    # A real rig's short exposure: fountain views at a third of their size, scaled to median grey 20.
    root = require(STRECHA_ROOT)
    rig = tmp_path / "rig.yaml"
    rig.write_text(RIG)
    images = []
    for view in VIEWS:
        grey = cv2.resize(cv2.imread(str(image_path(root, view)), cv2.IMREAD_GRAYSCALE), (1024, 683),
                          interpolation=cv2.INTER_AREA)
        images.append(str(tmp_path / f"{view}.png"))
        cv2.imwrite(images[-1], np.clip(grey * (20.0 / np.median(grey)), 0, 255).astype(np.uint8))
    out = tmp_path / "obs.json"
    raw = camnet("match", *images, "--rig", str(rig), "-o", str(out), "--no-normalise-contrast")
    assert raw.returncode == 2 and not out.exists()
    assert raw.stderr.count("dark (median grey 20 of 255); raise the exposure or gain") == len(VIEWS)
    assert raw.stderr.strip().splitlines()[-1].startswith("camnet match: error: no tracks")
    normalised = camnet("match", *images, "--rig", str(rig), "-o", str(out))
    assert normalised.returncode == 0, normalised.stderr
    assert json.loads(normalised.stdout)["tracks"] >= 1500
