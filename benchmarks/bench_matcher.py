"""Matcher time per 4-camera 1280x1024 frame set, SIFT vs ORB.

Times detect + match (all pairs, RANSAC) + tracks, over repeats; prints
median and p90. Uses four neighbouring Strecha fountain views resized and
cropped to 1280x1024 when ../shared/data is present (no stereo prior: these
views converge), else seeded synthetic textures seen by a simulated
parallel rig (with the stereo prior).

    python benchmarks/bench_matcher.py [--repeats N]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from camnet.io.formats import Stereo
from camnet.matching.features import Detector, MatcherConfig, detect, match_frame_set
from camnet.matching.tracks import build_tracks

WIDTH, HEIGHT = 1280, 1024
STRECHA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "strecha_fountain_p11"
STRECHA_VIEWS = ("0004", "0005", "0006", "0007")


def strecha_frame_set() -> dict[str, np.ndarray] | None:
    images = {}
    for view in STRECHA_VIEWS:
        image = cv2.imread(str(STRECHA / "images" / f"{view}.jpg"), cv2.IMREAD_COLOR)
        if image is None:
            return None
        scale = HEIGHT / image.shape[0]
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        x0 = (image.shape[1] - WIDTH) // 2
        images[view] = image[:, x0 : x0 + WIDTH]
    return images


def synthetic_frame_set(seed: int = 0) -> dict[str, np.ndarray]:
    """Four crops of one seeded texture: a 40 px disparity pair plus two shifted views."""
    rng = np.random.default_rng(seed)
    h, w = HEIGHT + 64, WIDTH + 128
    texture = np.zeros((h, w))
    for cell in (2, 5, 13, 31):
        small = rng.random((h // cell + 2, w // cell + 2))
        texture += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)[:h, :w]
    texture = (255 * (texture - texture.min()) / np.ptp(texture)).astype(np.uint8)
    offsets = {"left": (0, 20), "right": (40, 20), "mono_a": (90, 5), "mono_b": (15, 60)}
    return {k: texture[dy : dy + HEIGHT, dx : dx + WIDTH] for k, (dx, dy) in offsets.items()}


def time_once(images, config, stereo) -> tuple[float, float, int, int]:
    t0 = time.perf_counter()
    for image in images.values():
        detect(image, config)
    t_detect = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracks = build_tracks(match_frame_set(images, config, stereo=stereo))
    t_total = time.perf_counter() - t0
    return t_total, t_detect, len(tracks), int(np.sum(tracks.views == 4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    images = strecha_frame_set()
    stereo = None
    source = "Strecha fountain 0004-0007, 1280x1024, no stereo prior"
    if images is None:
        images = synthetic_frame_set()
        stereo = Stereo("left", "right", 0.1, parallel=True)
        source = "synthetic seeded texture, 1280x1024, stereo prior on left/right"
    print(f"frame set: 4 cameras, {source}; {args.repeats} repeats; {cv2.getNumThreads()} threads")
    header = ("detector", "median s", "p90 s", "detect s", "tracks", "4-view")
    print("{:8} {:>9} {:>7} {:>9} {:>7} {:>7}".format(*header))
    for detector in (Detector.SIFT, Detector.ORB):
        config = MatcherConfig(detector=detector)
        runs = np.array([time_once(images, config, stereo) for _ in range(args.repeats)])
        total, detect_s = runs[:, 0], runs[:, 1]
        print(
            f"{detector.value:8} {np.median(total):9.3f} {np.percentile(total, 90):7.3f} "
            f"{np.median(detect_s):9.3f} {int(runs[-1, 2]):7d} {int(runs[-1, 3]):7d}"
        )


if __name__ == "__main__":
    main()
