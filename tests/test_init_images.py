"""`camnet init --images DIR`: the rig file of a folder of images, loaded and run by the command it names next."""

from __future__ import annotations

import glob
import shlex
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from camnet.drivers.v4l2 import V4l2Camera, source_problem

from camnet.io.formats import load_json, parse_calibration, parse_observations
from camnet.io.rig import V4l2Config, load_rig
from tests._groundtruth import KITTI_ROOT
from tests.test_own_cameras import camnet, own_bus

EXAMPLE_IMAGES = Path(__file__).resolve().parents[1] / "config" / "example-images"
CAMERAS = ("left", "mono_a", "mono_b", "right")  # in name order, as init lists them


def sequences(tmp_path: Path) -> Path:
    """A folder of one subfolder of frames (with timestamps.txt) per camera: the example's rendered images."""
    images = tmp_path / "shots"
    for camera_id in CAMERAS:
        shutil.copytree(EXAMPLE_IMAGES / camera_id, images / camera_id)
    return images


def next_command(stdout: str) -> list[str]:
    """The command `camnet init` says to run next (the first, when it names two)."""
    line = next(line for line in stdout.splitlines() if line.startswith("next: "))
    commands = [part for part in line.removeprefix("next: ").split(", then ") if part.startswith("camnet ")]
    return shlex.split(commands[0])


def test_a_folder_per_camera_becomes_image_sequences_that_camnet_up_calibrates(tmp_path):
    images = sequences(tmp_path)
    rigs = tmp_path / "rigs"
    rigs.mkdir()
    proc = camnet("init", "--images", str(images), "--pair", "left", "right", "--baseline", "125 mm", "-o",
                  str(rigs / "shots.yaml"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rig = load_rig(rigs / "shots.yaml")
    assert [c.id for c in rig.cameras] == list(CAMERAS)
    assert (rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m) == ("left", "right", 0.125)
    for entry in rig.cameras:
        config = entry.config
        assert isinstance(config, V4l2Config) and (config.width, config.height) == (640, 512)
        assert config.encoding == "mono8" and config.loop
        assert Path(config.timestamps).resolve() == images / entry.id / "timestamps.txt"  # relative to the rig
        assert sorted(Path(p).name for p in glob.glob(config.source)) == ["000000.jpg", "000001.jpg"]
    command = next_command(proc.stdout)
    assert command == ["camnet", "up", str(rigs / "shots.yaml")]
    run_dir = tmp_path / "run"
    up = camnet(*command[1:], "--until-frame-sets", "2", "--duration-s", "120", "--run-dir", str(run_dir),
                *own_bus(), cwd=tmp_path, timeout_s=300.0)
    assert up.returncode == 0, up.stdout + up.stderr
    cal = parse_calibration(load_json(run_dir / "calibration.json"))
    truth = {c.id: c for c in load_rig(EXAMPLE_IMAGES / "sim-rig.yaml").simulated_truth()}
    for cam in cal.cameras:
        assert abs(cam.K[0, 0] / truth[cam.id].K[0, 0] - 1) < 0.05, cam.id


def test_what_is_not_given_is_a_marked_line_to_fill_in_and_nothing_runs_before(tmp_path):
    images = sequences(tmp_path)
    proc = camnet("init", "--images", str(images), "-o", "rig.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "rig.yaml").read_text()
    assert "# stereo: {left: left, right: mono_a, baseline_m: FILL_IN, parallel: false}\n" in text
    assert "FILL_IN before calibrating" in text and "guesses the first two" in text
    assert load_rig(tmp_path / "rig.yaml").stereo is None  # it loads as written
    assert "next: fill in the stereo pair and its baseline in rig.yaml, then camnet up rig.yaml" in proc.stdout
    refused = camnet("up", "rig.yaml", "--run-dir", str(tmp_path / "run"), cwd=tmp_path)
    assert refused.returncode == 2 and "the rig has no stereo pair" in refused.stderr
    # Filled in as it says: the pair, the measured distance, the '# ' taken off.
    (tmp_path / "rig.yaml").write_text(text.replace("# stereo: {left: left, right: mono_a, baseline_m: FILL_IN",
                                                    "stereo: {left: left, right: right, baseline_m: 0.125"))
    rig = load_rig(tmp_path / "rig.yaml")
    assert (rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m) == ("left", "right", 0.125)
    # Uncommented but not measured: refused, never a silent scale.
    (tmp_path / "rig.yaml").write_text(text.replace("# stereo:", "stereo:"))
    refused = camnet("up", "rig.yaml", cwd=tmp_path)
    assert refused.returncode == 2 and "stereo.baseline_m: expected a finite number, got 'FILL_IN'" in refused.stderr


def test_one_image_per_camera_is_a_rig_for_camnet_match(tmp_path):
    images = tmp_path / "stills"
    images.mkdir()
    for camera_id in ("0006", "0007", "0010"):  # ids of digits: written quoted, read back as written
        view = {"0006": "left", "0007": "right", "0010": "mono_a"}[camera_id]
        shutil.copy(EXAMPLE_IMAGES / view / "000000.jpg", images / f"{camera_id}.jpg")
    proc = camnet("init", "--images", "stills", "--pair", "0006", "0007", "--baseline", "0.125m", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    rig = load_rig(tmp_path / "rig.yaml")
    assert [c.id for c in rig.cameras] == ["0006", "0007", "0010"] and all(c.driver is None for c in rig.cameras)
    assert "- id: '0006'  # 0006.jpg, 640x512 grey" in (tmp_path / "rig.yaml").read_text()
    command = next_command(proc.stdout)
    assert command[:2] == ["camnet", "match"]
    match = camnet(*command[1:], cwd=tmp_path)
    assert match.returncode == 0, match.stderr
    obs = parse_observations(load_json(tmp_path / "observations.json"))
    assert [(c.id, c.width, c.height) for c in obs.cameras] == [(c, 640, 512) for c in ("0006", "0007", "0010")]
    assert len(obs.track_ids) > 100


def test_kitti_folders_are_read_with_their_timestamps(tmp_path):
    """Real images in KITTI raw's layout (image_0N/data/*.png beside image_0N/timestamps.txt)."""
    from tests._groundtruth import require

    root = require(KITTI_ROOT)
    whole = camnet("init", "--images", str(root), "-o", str(tmp_path / "all.yaml"), cwd=tmp_path)
    # The extract has no image_02/timestamps.txt: its frames could not pair with the others' by capture time.
    assert whole.returncode == 2 and whole.stderr.count("\n") == 1, whole.stderr
    assert f"{root / 'image_02' / 'data'}: no timestamps.txt, while image_00, image_01, image_03" in whole.stderr
    assert not (tmp_path / "all.yaml").exists()
    images = tmp_path / "kitti"
    for camera_id in ("image_00", "image_01", "image_03"):
        shutil.copytree(root / camera_id, images / camera_id)
    proc = camnet("init", "--images", str(images), "--pair", "image_00", "image_01", "--baseline", "0.54m",
                  "-o", str(tmp_path / "kitti.yaml"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    rig = load_rig(tmp_path / "kitti.yaml")
    sizes = {c.id: (c.config.width, c.config.height, c.config.encoding) for c in rig.cameras}
    for camera_id, (width, height, encoding) in sizes.items():
        first = cv2.imread(sorted((images / camera_id / "data").glob("*.png"))[0].as_posix(), cv2.IMREAD_UNCHANGED)
        assert (width, height) == (first.shape[1], first.shape[0])
        assert encoding == ("bgr8" if first.ndim == 3 else "mono8")
    for entry in rig.cameras:  # what the driver of each camera opens: its frames, stamped by the recording
        assert source_problem(entry.id, entry.config) is None
        with V4l2Camera(entry.id, entry.config) as camera:
            frames = [camera.read(timeout_s=30.0) for _ in range(2)]
        assert frames[0].timestamp_ns < frames[1].timestamp_ns and frames[0].image.shape[1] == sizes[entry.id][0]


def write_images(folder: Path, sizes: list[tuple[int, int]]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for k, (width, height) in enumerate(sizes):
        cv2.imwrite(str(folder / f"{k:04d}.png"), rng.integers(0, 255, (height, width), dtype=np.uint8))


@pytest.mark.parametrize(("make", "message"), [
    (lambda d: (d / "notes.txt").write_text("no images here"),
     "{d}: no images (png, jpg, jpeg, tif, ...); give a folder with one subfolder of images per camera, or one "
     "image per camera"),
    (lambda d: (write_images(d / "a", [(64, 48)]), (d / "b").mkdir(), (d / "b" / "0000.png").write_text("text")),
     "{d}/b/0000.png: cannot be read as an image"),
    (lambda d: (write_images(d / "a", [(64, 48)]), write_images(d / "b", [(64, 48), (32, 24)])),
     "{d}/b: images of two sizes, 0000.png 64x48 and 0001.png 32x24; one camera's images share one size"),
    (lambda d: write_images(d / "a", [(64, 48)]),
     "{d}: the images of one camera (a); a rig needs two for its stereo pair"),
    (lambda d: (write_images(d, [(64, 48)]), write_images(d / "a", [(64, 48)])),
     "{d}: holds both images (0000.png, ...) and folders of images (a, ...)"),
], ids=["no-images", "unreadable", "mixed-sizes", "one-camera", "both-layouts"])
def test_bad_folders_are_one_line_and_nothing_is_written(tmp_path, make, message):
    folder = tmp_path / "imgs"
    folder.mkdir()
    make(folder)
    proc = camnet("init", "--images", str(folder), "-o", str(tmp_path / "rig.yaml"), cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"camnet init: error: {message.format(d=folder)}"), proc.stderr
    assert not (tmp_path / "rig.yaml").exists()
