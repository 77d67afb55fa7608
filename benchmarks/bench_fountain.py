"""fountain-P11 (real photographs, no parallel pair) through matcher and calibrator, against its published cameras.

Matches the views as one frame set (SIFT on copies downscaled to at most
--max-image-side-px, keypoints mapped back to the full 3072 x 2048 pixels, so
the published K applies unchanged), takes a converging pair with its published
centre distance as the known baseline (default 0004-0005, 1.8243 m, 11 degrees
apart) and calibrates at default options, twice: `scene`, nothing known, and
`all-K`, every camera's published K given and held. Prints Markdown tables:
what each solve gave or why it was refused, and per camera the focal length,
centre, distance from the left camera and rotation against the published
cameras (in the left camera's frame), with camnet's reported 1-sigma.

    python benchmarks/bench_fountain.py [--views 0000,...] [--pair 0004,0005] [--max-image-side-px 1024]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from camnet.datasets.published import VsPublished, compare
from camnet.datasets.strecha import image_path, in_frame_of, read_cameras
from camnet.errors import CamnetError
from camnet.matching.engine import EngineConfig
from camnet.matching.features import MatcherConfig
from camnet.matching.pipeline import observations_from_frame_sets, with_known_intrinsics
from camnet.model.camera import CameraInfo
from camnet.model.observations import Stereo
from camnet.solve import Options, calibrate

ROOT = Path(__file__).resolve().parents[1]
FOUNTAIN = ROOT.parent / "shared" / "data" / "strecha_fountain_p11"


def pct(x: float, digits: int = 2) -> str:
    return f"{100 * x:+.{digits}f}"


def camera_rows(name: str, result: VsPublished, left: str) -> list[str]:
    return [
        f"| {name} | {c.id} | {pct(c.focal_rel)} ({100 * c.focal_sigma_rel:.2f}) | "
        f"{c.centre_mm:.0f} ({c.centre_sigma_mm:.0f}) | {pct(c.distance_rel, 1)} | "
        f"{c.rotation_deg:.2f} ({c.rotation_sigma_deg:.2f}) |"
        for c in result.cameras
        if c.id != left
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", default=",".join(f"{k:04d}" for k in range(11)), help="comma list of view ids")
    parser.add_argument("--pair", default="0004,0005", help="the pair with the known distance: LEFT,RIGHT")
    parser.add_argument("--max-image-side-px", type=int, default=1024, help="detect on copies at most this large")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if not FOUNTAIN.exists():
        print(f"fountain-P11 not found at {FOUNTAIN}", file=sys.stderr)
        return 2
    views = args.views.split(",")
    left, right = args.pair.split(",")
    published = in_frame_of(read_cameras(FOUNTAIN), left)
    published = {v: published[v] for v in views}
    baseline_m = float(np.linalg.norm(published[right].centre - published[left].centre))
    angle_deg = np.degrees(np.arccos(np.clip((np.trace(published[right].R) - 1) / 2, -1, 1)))
    print(f"fountain-P11: {len(views)} views; pair {left}-{right}, {baseline_m:.4f} m apart, {angle_deg:.1f} degrees "
          f"(not a parallel head); detection at most {args.max_image_side_px} px, pixels full size\n")

    start_s = time.perf_counter()
    images = {v: cv2.imread(str(image_path(FOUNTAIN, v)), cv2.IMREAD_GRAYSCALE) for v in views}
    cameras = [CameraInfo(v, images[v].shape[1], images[v].shape[0]) for v in views]
    obs = observations_from_frame_sets([images], cameras=cameras, stereo=Stereo(left, right, baseline_m),
                                       config=EngineConfig(matcher=MatcherConfig(max_image_side_px=args.max_image_side_px)))
    seen = np.bincount(obs.cam_index, minlength=len(views))
    print(f"matched in {time.perf_counter() - start_s:.1f} s: {len(obs.track_ids)} tracks; observations per view: "
          + ", ".join(f"{v} {n}" for v, n in zip(views, seen, strict=True)) + "\n")

    scenarios = {"scene": obs, "all-K": with_known_intrinsics(obs, published, given=("K",))}
    print("| scenario | outcome | point distances err % | points | centre distances err % | scale σ % | RMS px "
          "| solve s |")
    print("|---|---|---|---|---|---|---|---|")
    results = {}
    for name, scenario_obs in scenarios.items():
        start_s = time.perf_counter()
        try:
            result = calibrate(scenario_obs, Options())
        except CamnetError as exc:
            print(f"| {name} | refused: {exc} | - | - | - | - | - | {time.perf_counter() - start_s:.1f} |")
            continue
        solve_s = time.perf_counter() - start_s
        if not result.converged:
            print(f"| {name} | not converged: {result.reason} | - | - | - | - | - | {solve_s:.1f} |")
            continue
        vs = results[name] = compare(result.calibration, scenario_obs, published)
        # The scale judged by the cameras: each centre's distance from the left one, the right one's excepted.
        centres = np.median([c.distance_rel for c in vs.cameras if c.id not in (left, right)])
        outcome = "; ".join(["solved", *vs.warnings])
        print(f"| {name} | {outcome} | {pct(vs.distance_rel)} | {vs.distance_points} | {pct(centres)} | "
              f"{100 * vs.scale_sigma_rel:.2f} | {vs.rms_reprojection_px:.2f} | {solve_s:.1f} |")
    if results:
        print("\n| scenario | view | f err % (σ) | centre err mm (σ) | distance from left err % | rotation err ° (σ) |")
        print("|---|---|---|---|---|---|")
        for name, vs in results.items():
            print("\n".join(camera_rows(name, vs, left)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
