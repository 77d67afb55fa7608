"""A simulated rig's frames written as a recording of its cameras: image folders with their capture times.

One folder per camera, named by its id, holding one image per frame
(``000000.jpg``: the frame index is the number in the name) and a
``timestamps.txt`` in KITTI's format (one ``YYYY-MM-DD HH:MM:SS.fffffffff``
line per frame index, UTC), which camnet's v4l2 driver reads so that
cameras replayed by separate drivers keep their frames in step
(drivers/v4l2.py). config/v4l2-example.yaml runs on such a sequence, made by

    python -m camnet.io.image_sequence config/example-images/sim-rig.yaml config/example-images --frames 2

Every frame is rendered by camnet's own renderer, with each camera's sensor
noise, from a fixed seed and a fixed start time, so the same rig file gives
the same files.
"""

from __future__ import annotations

import argparse
import sys
import zlib
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from camnet.errors import InputError
from camnet.io.rig import Rig, load_rig
from camnet.sim.render import Renderer
from camnet.sim.scene import Scene

START = datetime(2024, 1, 1, tzinfo=UTC)  # the sequence's first capture time: fixed, so files are reproducible
JPEG_QUALITY = 90  # small files that keep the texture's detail, which the features are found in
TIMESTAMPS = "timestamps.txt"


def kitti_stamp(time_ns: int) -> str:
    """`time_ns` (Unix epoch, ns) as a line of a KITTI timestamps file: ``YYYY-MM-DD HH:MM:SS.fffffffff`` (UTC)."""
    seconds, ns = divmod(time_ns, 1_000_000_000)
    return f"{datetime.fromtimestamp(seconds, UTC):%Y-%m-%d %H:%M:%S}.{ns:09d}"


def write_image_sequence(rig: Rig, directory: Path, *, frames: int, fps: float) -> list[Path]:
    """Render `frames` frames of every camera of `rig` (all simulated), `1 / fps` s apart, into `directory`;
    the folders written. InputError for a camera that is not simulated."""
    others = [entry.id for entry in rig.cameras if entry.driver != "sim"]
    if others:
        raise InputError(f"{rig.source}: camera {', '.join(others)} is not simulated (driver: sim); only a "
                         "simulated camera's frames can be rendered")
    if frames < 1 or not fps > 0:
        raise InputError(f"need at least one frame at a positive rate, got {frames} frames at {fps} fps")
    scene = Scene(rig.scene)
    start_ns = int(START.timestamp()) * 1_000_000_000
    times_ns = [start_ns + round(k * 1e9 / fps) for k in range(frames)]
    folders = []
    for entry in rig.cameras:
        folder = directory / entry.id
        folder.mkdir(parents=True, exist_ok=True)
        renderer = Renderer(entry.config.camera(entry.id))
        rng = np.random.default_rng((rig.scene.seed, zlib.crc32(entry.id.encode())))  # each camera its own noise
        for k, time_ns in enumerate(times_ns):
            image = renderer.render(scene.quads((time_ns - start_ns) / 1e9),
                                    noise_sigma_dn=entry.config.noise_sigma_dn, rng=rng)
            cv2.imwrite(str(folder / f"{k:06d}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        (folder / TIMESTAMPS).write_text("".join(f"{kitti_stamp(t)}\n" for t in times_ns))
        folders.append(folder)
    return folders


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m camnet.io.image_sequence", description=__doc__.split("\n")[0])
    parser.add_argument("rig", metavar="RIG.yaml", help="a rig file of simulated cameras (driver: sim)")
    parser.add_argument("directory", metavar="DIR", help="where to write one folder per camera")
    parser.add_argument("--frames", type=int, default=2, help="frames per camera (default 2)")
    parser.add_argument("--fps", type=float, default=2.0, help="frames a second of the recording (default 2)")
    args = parser.parse_args(argv)
    try:
        folders = write_image_sequence(load_rig(args.rig), Path(args.directory), frames=args.frames, fps=args.fps)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for folder in folders:
        print(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
