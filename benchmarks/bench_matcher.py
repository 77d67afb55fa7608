"""Matcher time per 4-camera 1280x1024 frame set, SIFT vs ORB; and per ring frame set, all pairs vs the view graph.

Times detect + match (all pairs, RANSAC) + tracks, over repeats; prints
median and p90. Uses four neighbouring Strecha fountain views resized and
cropped to 1280x1024 when ../shared/data is present (no stereo prior: these
views converge), else seeded synthetic textures seen by a simulated
parallel rig (with the stereo prior).

With `--ring 4,8,16` it renders rings of M simulated cameras instead
(config/surround.yaml's geometry, M - 1 positions evenly round the person,
one of them the parallel head) and matches their frame sets twice, every
pair and the view graph's pairs given the ground truth as the calibration,
and prints pairs matched and CPU seconds of matching per frame set.

    python benchmarks/bench_matcher.py [--repeats N] [--ring 4,8,16 [--frame-sets 5]]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from camnet.io.formats import Stereo
from camnet.matching.engine import match_frame_set
from camnet.matching.features import Detector, MatcherConfig, detect
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


# ---------------------------------------------------------------- rings: all pairs vs the view graph

RING_SIZE = {"width": 640, "height": 512, "fps": 2, "f_px": 475}  # config/surround.yaml's cameras


def ring_document(m: int) -> dict:
    """A surround rig of `m` cameras: the head (two cameras, 0.12 m) and m - 2 singles, evenly on a 2 m ring."""
    positions = m - 1
    cameras = []
    for k in range(positions):
        a = 2 * np.pi * k / positions
        centre, target = [2 * np.sin(a), -0.25, -2 * np.cos(a)], [0.0, 0.0, 0.0]
        if k == 0:
            cameras.append({"id": "head_left", "driver": "sim", "sim": {**RING_SIZE, "centre_m": centre,
                                                                         "look_at_m": target}})
            centre, target = [0.12, -0.25, -2.0], [0.12, 0.0, 0.0]
            cameras.append({"id": "head_right", "driver": "sim", "sim": {**RING_SIZE, "centre_m": centre,
                                                                          "look_at_m": target}})
        else:
            cameras.append({"id": f"ring{k}", "driver": "sim", "sim": {**RING_SIZE, "centre_m": centre,
                                                                        "look_at_m": target}})
    return {"rig": f"ring{m}", "stereo": {"left": "head_left", "right": "head_right", "baseline_m": 0.12,
                                          "parallel": True},
            "scene": {"seed": 11, "object": "person", "box_centre_m": [0.0, 0.0, 0.0],
                      "box_size_m": [0.5, 1.7, 0.34], "box_rotation_deg_per_s": 10.0, "floor_y_m": 0.85,
                      "wall_x_range_m": [-2.0, 2.0], "floor_z_range_m": [-2.0, 2.0]},
            "cameras": cameras}


def ground_truth_calibration(rig, time_s: float = 0.0):
    """The rig's true cameras and points on its scene's quads, in the left camera's frame: a perfect calibration."""
    from camnet.model.calibration import Calibration
    from camnet.sim.scene import Scene

    rng = np.random.default_rng(0)
    points = np.concatenate([q.p0 + rng.random((40, 1)) * q.u + rng.random((40, 1)) * q.v
                             for q in Scene(rig.scene).quads(time_s)])
    left = rig.camera(rig.stereo.left).config.camera(rig.stereo.left)
    points_left = points @ left.R.T + left.t  # x_left = R_l X + t_l
    return Calibration(tuple(rig.simulated_truth()), np.arange(len(points)), points_left, float("nan"),
                       rig.stereo.left)


def ring_features(rig, frame_sets: int):
    """Each frame set's features (camnet.matching.edge: whole, then where changed), and CPU seconds of detection
    per frame set."""
    from camnet.drivers.base import create_camera

    from camnet.matching.edge import FeatureExtractor

    cameras = [create_camera(entry, rig) for entry in rig.cameras]
    extractors = [FeatureExtractor(entry.id) for entry in rig.cameras]
    sets, detect_s = [], 0.0
    for slot in range(frame_sets):
        images = [camera.render(slot) for camera in cameras]
        t0 = time.process_time()
        sets.append([x.extract(image, seq=slot, timestamp_ns=slot)
                     for x, image in zip(extractors, images, strict=True)])
        detect_s += time.process_time() - t0
    return sets, detect_s / frame_sets


def match_ring(sets, rig, calibration) -> dict:
    """Pairs, CPU seconds per frame set and the tracks of the last, matching every pair and the view graph's.

    The two matchers take turns frame set by frame set, so that a change of load on a shared machine
    falls on both; CPU time (every thread of this process) measures what matching costs.
    """
    from camnet.services.matcher import rig_stereo

    from camnet.matching.reuse import IncrementalMatcher
    from camnet.matching.viewgraph import ViewGraph

    stereo = rig_stereo(rig)
    runs = {}
    for name in ("before", "after"):
        graph = ViewGraph(always={frozenset((stereo.left, stereo.right))})
        if name == "after":
            graph.update(calibration)
        runs[name] = (IncrementalMatcher(stereo=stereo), graph, {"pairs": [], "seconds": [], "tracks": 0})
    for cameras in sets:
        ids = [c.camera_id for c in cameras]
        for matcher, graph, out in runs.values():
            t0 = time.process_time()
            pairs = graph.pairs(ids, matched_well=matcher.matched_well(graph.config.good_matches))
            matches = matcher.match(cameras, pairs=pairs)
            out["tracks"] = len(build_tracks(matches))
            out["seconds"].append(time.process_time() - t0)
            out["pairs"].append(len(matches.pairs))
    return {name: run[2] for name, run in runs.items()}


def ring_table(sizes: list[int], *, frame_sets: int) -> None:
    from camnet.io.rig import parse_rig

    print(f"rings of M simulated cameras at 640x512 (SIFT), {frame_sets} frame sets each; the first is matched "
          "whole, the later ones on what changed; 'after': the view graph given the true calibration; CPU seconds")
    print(f"{'M':>3} {'pairs':>5} {'detect s':>8} | {'before: pairs':>13} {'whole s':>7} {'later s':>7} {'tracks':>6}"
          f" | {'after: pairs':>12} {'whole s':>7} {'later s':>7} {'tracks':>6}")
    for m in sizes:
        rig = parse_rig(ring_document(m))
        sets, detect_s = ring_features(rig, frame_sets)
        runs = match_ring(sets, rig, ground_truth_calibration(rig))
        cells = []
        for r in (runs["before"], runs["after"]):
            cells.append(f"{np.median(r['pairs']):>13.0f} {r['seconds'][0]:7.2f} {np.median(r['seconds'][1:]):7.2f} "
                         f"{r['tracks']:6d}")
        print(f"{m:3d} {m * (m - 1) // 2:5d} {detect_s:8.2f} | {cells[0]} | {cells[1][1:]}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--ring", metavar="M,M,...", help="rings of these many cameras: all pairs vs the view graph")
    parser.add_argument("--frame-sets", type=int, default=5, help="with --ring: frame sets per ring (default 5)")
    args = parser.parse_args()
    if args.ring:
        ring_table([int(m) for m in args.ring.split(",")], frame_sets=args.frame_sets)
        return
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
