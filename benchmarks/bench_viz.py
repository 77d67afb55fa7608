"""Cost of streaming a live calibration to Rerun (camnet.viz), per solve and per frame.

Logs real solves of simulated rigs (60% visibility for non-stereo cameras,
0.5 px noise) to an .rrd file in a temporary folder; prints the median time
of `log_calibration` (with observations and ground truth) and of `log_frame`
for a 1280x1024 image, and the bytes each adds to the file.

    python benchmarks/bench_viz.py [--repeats N]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from camnet import viz, viz_sinks
from camnet.io.formats import Calibration
from camnet.sim.scene import procedural_texture
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate

T0_NS = 1_700_000_000_000_000_000


def median_ms(fn, repeats: int) -> float:
    times = []
    for k in range(repeats):
        t0 = time.perf_counter()
        fn(k)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def bench_solve(n_cameras: int, n_points: int, repeats: int, folder: Path) -> tuple[float, float]:
    rig = make_rig(n_cameras=n_cameras, n_points=n_points, seed=1)
    obs = observe(rig, noise_px=0.5, seed=1, visibility=0.6).observations
    cal = calibrate(obs).calibration
    truth = Calibration(rig.cameras, np.arange(n_points), rig.points, 0.0, rig.cameras[0].id)
    # Solves that differ (as live ones do), so that Rerun's compression does not flatter the file size.
    rng = np.random.default_rng(2)
    cals = [replace(cal, points=cal.points + rng.normal(scale=1e-4, size=cal.points.shape)) for _ in range(repeats)]
    path = folder / f"solve_{n_cameras}_{n_points}.rrd"
    rec = viz.open_recording(rig="bench", sinks=[viz_sinks.parse_sink(f"save={path}")])
    ms = median_ms(lambda k: viz.log_calibration(rec, cals[k], time_ns=T0_NS + k, observations=obs, truth=truth),
                   repeats)
    viz.close_recording(rec)
    return ms, path.stat().st_size / repeats


def bench_frame(encoding: str, repeats: int, folder: Path) -> tuple[float, float]:
    greys = [procedural_texture(1280, 1024, np.random.default_rng(seed)) for seed in range(repeats)]
    images = greys if encoding == "mono8" else [cv2.applyColorMap(g, cv2.COLORMAP_BONE) for g in greys]
    path = folder / f"frame_{encoding}.rrd"
    rec = viz.open_recording(rig="bench", sinks=[viz_sinks.parse_sink(f"save={path}")])
    ms = median_ms(lambda k: viz.log_frame(rec, "left", images[k], time_ns=T0_NS + k, encoding=encoding), repeats)
    viz.close_recording(rec)
    return ms, path.stat().st_size / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        print("| what | ms (median) | KiB per call |")
        print("|---|---|---|")
        for n_cameras, n_points in ((4, 250), (4, 1000), (8, 1000), (16, 1000)):
            ms, size = bench_solve(n_cameras, n_points, args.repeats, folder)
            print(f"| log_calibration M={n_cameras} N={n_points} | {ms:.1f} | {size / 1024:.0f} |", flush=True)
        for encoding in ("mono8", "bgr8"):
            ms, size = bench_frame(encoding, args.repeats, folder)
            print(f"| log_frame 1280x1024 {encoding} | {ms:.1f} | {size / 1024:.0f} |", flush=True)


if __name__ == "__main__":
    main()
