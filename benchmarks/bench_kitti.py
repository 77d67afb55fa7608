"""KITTI raw (real images) through the matcher chain and the calibrator, against the published calibration.

Pools the tracks of the 4 frame sets (cams 0, 1 and one colour camera each),
then calibrates in each scenario of `camnet.datasets.kitti.SCENARIOS`, from
nothing known to every intrinsic known, and prints Markdown tables: per
camera the focal length, centre, direction and rotation against the
published calibration with camnet's reported 1-sigma; per scenario the
scale judged by 3-D point distances (points 2-15 m deep, triangulated with
the published stereo pair) and the colour cameras' distance from cam 0.
With --live it also runs config/kitti.yaml through the live nodes (v4l2
drivers replaying the recorded frames and stamps, matcher, calibrator from
the published stereo head: the all-K scenario live) and adds its rows.

    python benchmarks/bench_kitti.py [--max-tracks N] [--live]
"""

from __future__ import annotations

import argparse
import logging
import socket
import sys
import tempfile
import time
from pathlib import Path

from camnet.datasets.kitti import SCENARIOS, KittiExtract, pooled_observations, prepare_scenario
from camnet.datasets.published import VsPublished, compare
from camnet.errors import CamnetError
from camnet.solve import Options, calibrate
from camnet.testing.live_rig import calibrate_live

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT.parent / "shared" / "data" / "kitti_raw_2011_09_26_extract_3cam"


def pct(x: float, digits: int = 2) -> str:
    return f"{100 * x:+.{digits}f}"


def camera_rows(name: str, result: VsPublished, left: str) -> list[str]:
    return [
        f"| {name} | {c.id} | {pct(c.focal_rel)} ({100 * c.focal_sigma_rel:.2f}) | "
        f"{c.centre_mm:.0f} ({c.centre_sigma_mm:.0f}) | {c.direction_deg:.1f} | {pct(c.distance_rel, 1)} | "
        f"{c.rotation_deg:.2f} ({c.rotation_sigma_deg:.2f}) |"
        for c in result.cameras
        if c.id != left
    ]


def scenario_row(name: str, result: VsPublished, solve_s: float) -> str:
    return (
        f"| {name} | {pct(result.distance_rel)} | {result.distance_points} | "
        f"{100 * result.scale_sigma_rel:.2f} | {result.rms_reprojection_px:.2f} | {solve_s:.1f} | "
        f"{len(result.warnings)} |"
    )


def live_rows(kitti: KittiExtract, max_tracks: int) -> tuple[list[str], str]:
    """The live network on config/kitti.yaml: its camera rows and scenario row (time: until the calibration)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    run_dir = Path(tempfile.mkdtemp(prefix="camnet-kitti-live-"))
    print(f"live: config/kitti.yaml, nodes' logs in {run_dir}", file=sys.stderr)
    cal, obs, elapsed_s = calibrate_live(ROOT / "config" / "kitti.yaml", run_dir=run_dir,
                                         endpoint=endpoint, max_tracks=max_tracks)
    result = compare(cal, obs, kitti.cameras)
    return camera_rows("live all-K", result, kitti.stereo.left), scenario_row("live all-K", result, elapsed_s)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-tracks", type=int, default=3000, help="pool size (default 3000)")
    parser.add_argument("--live", action="store_true", help="also run config/kitti.yaml through the live nodes")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    if not KITTI.exists():
        print(f"KITTI extract not found at {KITTI}; nothing to do", file=sys.stderr)
        return 1
    kitti = KittiExtract.open(KITTI)
    t0 = time.perf_counter()
    obs = pooled_observations(kitti, max_tracks=args.max_tracks)
    match_s = time.perf_counter() - t0
    print(f"matching: {len(obs.track_ids)} tracks, {len(obs.uv)} observations in {match_s:.1f} s", file=sys.stderr)

    cameras, scenarios = [], []
    for name, description in SCENARIOS.items():
        print(f"calibrating: {name} ({description})", file=sys.stderr)
        prepared, initial = prepare_scenario(obs, kitti.cameras, name)
        t1 = time.perf_counter()
        try:
            cal = calibrate(prepared, Options(), initial=initial).calibration
        except CamnetError as exc:
            scenarios.append(f"| {name} | failed: {exc} | | | | | |")
            continue
        solve_s = time.perf_counter() - t1
        result = compare(cal, obs, kitti.cameras)
        cameras.extend(camera_rows(name, result, kitti.stereo.left))
        scenarios.append(scenario_row(name, result, solve_s))
        for warning in result.warnings:
            print(f"  warning: {warning}", file=sys.stderr)
    if args.live:
        rows, row = live_rows(kitti, args.max_tracks)
        cameras.extend(rows)
        scenarios.append(row)

    print("\nScenarios:\n")
    for name, description in SCENARIOS.items():
        print(f"- `{name}`: {description}")
    print("\nPer camera against the published calibration (camnet's reported 1-sigma in brackets):\n")
    print("| scenario | cam | f err % (σ) | centre err mm (σ) | direction err ° | distance from cam 0 err % "
          "| rotation err ° (σ) |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(cameras))
    print("\nScale (median over pairs of 3-D point distances, points 2-15 m deep) and fit:\n")
    print("| scenario | point distances err % | points | reported scale σ % | RMS px | solve s | warnings |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(scenarios))
    print(f"\nMatching 4 frame sets (12 images, 1392x512, SIFT): {match_s:.1f} s")
    if args.live:
        print("live all-K: config/kitti.yaml through the v4l2 drivers, matcher and calibrator (from the published "
              "stereo head, only focal lengths free); its 'solve s' is from the nodes' start to that calibration")
    return 0


if __name__ == "__main__":
    sys.exit(main())
