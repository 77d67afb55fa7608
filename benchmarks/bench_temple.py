"""The Middlebury temple ring (real photographs, 16 views round a 10 cm object) through matcher and calibrator.

Matches the views as one frame set (SIFT on contrast-normalised images, no
stereo prior: the pair is not a parallel head), takes two ring neighbours
with their published centre distance as the known baseline (default
templeSR0007-templeSR0008, 0.2242 m, 23 degrees apart) and calibrates at
default options, twice: `scene`, nothing known, and `all-K`, every view's
published K given and held. Prints Markdown tables: what each solve gave or
why it was refused, and per view the focal length, centre and rotation
against the published cameras (in the left camera's frame), with camnet's
reported 1-sigma and the error in those sigmas.

    python benchmarks/bench_temple.py [--views templeSR0001,...] [--pair templeSR0007,templeSR0008]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from camnet.datasets.published import VsPublished, compare, in_frame_of
from camnet.datasets.temple import image_path, read_cameras
from camnet.errors import CamnetError
from camnet.matching.pipeline import observations_from_frame_sets, with_known_intrinsics
from camnet.model.camera import CameraInfo
from camnet.model.observations import Stereo
from camnet.solve import Options, calibrate

ROOT = Path(__file__).resolve().parents[1]
TEMPLE = ROOT.parent / "shared" / "data" / "middlebury_temple_sparse_ring"
DEPTH_RANGE_M = (0.3, 1.0)  # the object, 0.5-0.7 m from every view


def pct(x: float, digits: int = 2) -> str:
    return f"{100 * x:+.{digits}f}"


def in_sigmas(error: float, sigma: float) -> str:
    return f"{abs(error) / sigma:.1f}" if sigma > 0 else "-"


def camera_rows(name: str, result: VsPublished, left: str) -> list[str]:
    return [
        f"| {name} | {c.id} | {pct(c.focal_rel)} ({100 * c.focal_sigma_rel:.2f}) "
        f"| {in_sigmas(c.focal_rel, c.focal_sigma_rel)} | {c.centre_mm:.0f} ({c.centre_sigma_mm:.0f}) "
        f"| {pct(c.distance_rel, 1)} | {c.rotation_deg:.2f} ({c.rotation_sigma_deg:.2f}) |"
        for c in result.cameras
        if c.id != left
    ]


def solve_row(name: str, obs, published, left: str, right: str) -> VsPublished | None:
    """Print the scenario's summary row; its comparison with the published cameras where it solved."""
    start_s = time.perf_counter()
    try:
        result = calibrate(obs, Options())
    except CamnetError as exc:
        print(f"| {name} | refused: {exc} | - | - | - | - | - | {time.perf_counter() - start_s:.1f} |")
        return None
    solve_s = time.perf_counter() - start_s
    if not result.converged:
        print(f"| {name} | not converged: {result.reason} | - | - | - | - | - | {solve_s:.1f} |")
        return None
    vs = compare(result.calibration, obs, published, depth_range_m=DEPTH_RANGE_M)
    # The scale judged by the cameras: each centre's distance from the left one, the right one's excepted.
    centres = np.median([c.distance_rel for c in vs.cameras if c.id not in (left, right)])
    outcome = "; ".join(["solved", *vs.warnings])  # a camera left out is among the warnings, by name
    print(f"| {name} | {outcome} | {pct(vs.distance_rel)} | {vs.distance_points} | {pct(centres)} | "
          f"{100 * vs.scale_sigma_rel:.2f} | {vs.rms_reprojection_px:.2f} | {solve_s:.1f} |")
    return vs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--views", default=",".join(f"templeSR{k:04d}" for k in range(1, 17)),
                        help="comma list of view ids")
    parser.add_argument("--pair", default="templeSR0007,templeSR0008", help="the pair with the known distance")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if not TEMPLE.exists():
        print(f"the temple ring not found at {TEMPLE}", file=sys.stderr)
        return 2
    views = args.views.split(",")
    left, right = args.pair.split(",")
    published = in_frame_of(read_cameras(TEMPLE), left)
    published = {v: published[v] for v in views}
    baseline_m = float(np.linalg.norm(published[right].centre - published[left].centre))
    angle_deg = np.degrees(np.arccos(np.clip((np.trace(published[right].R) - 1) / 2, -1, 1)))
    print(f"temple ring: {len(views)} views; pair {left}-{right}, {baseline_m:.4f} m apart, {angle_deg:.1f} degrees "
          "(not a parallel head)\n")

    start_s = time.perf_counter()
    # As `camnet match` reads them: colour, made grey by the matcher.
    images = {v: cv2.imread(str(image_path(TEMPLE, v)), cv2.IMREAD_UNCHANGED) for v in views}
    cameras = [CameraInfo(v, images[v].shape[1], images[v].shape[0]) for v in views]
    obs = observations_from_frame_sets([images], cameras=cameras, stereo=Stereo(left, right, baseline_m))
    seen = np.bincount(obs.cam_index, minlength=len(views))
    print(f"matched in {time.perf_counter() - start_s:.1f} s: {len(obs.track_ids)} tracks; observations per view: "
          + ", ".join(f"{v.removeprefix('templeSR')} {n}" for v, n in zip(views, seen, strict=True)) + "\n")

    scenarios = {"scene": obs, "all-K": with_known_intrinsics(obs, published, given=("K",))}
    print("| scenario | outcome | point distances err % | points | centre distances err % | scale σ % | RMS px "
          "| solve s |")
    print("|---|---|---|---|---|---|---|---|")
    results = {name: solve_row(name, scenario_obs, published, left, right)
               for name, scenario_obs in scenarios.items()}
    results = {name: vs for name, vs in results.items() if vs is not None}
    if results:
        print("\n| scenario | view | f err % (σ) | f err / σ | centre err mm (σ) | distance from left err % "
              "| rotation err ° (σ) |")
        print("|---|---|---|---|---|---|---|")
        for name, vs in results.items():
            print("\n".join(camera_rows(name, vs, left)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
