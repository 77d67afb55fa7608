#!/usr/bin/env python3
"""Real-rig families (camnet.sim.families): is each calibrated, refused for a reason, or wrong in silence?

For every family and seed, `camnet calibrate`'s engine at default options on
seeded observations (0.5 px noise; a camera sees only the side of the scene
that faces it). A solve is "silent" when it returns a calibration whose scale
or some focal length is off by more than 3 of its reported sigmas (or whose
sigma is missing): the failure the user cannot see. Prints one row per family.

    python benchmarks/bench_rigs.py [--seeds 20] [--families ring,wide]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

import numpy as np

from camnet.errors import CamnetError
from camnet.geometry.calibrate import calibrate
from camnet.geometry.evaluate import compare
from camnet.sim.families import FAMILIES, family
from camnet.sim.simulate import observe


def run_seed(name: str, seed: int) -> tuple[str, dict]:
    """("solved", errors) or ("refused", {"reason": ...}) for one seed of one family."""
    drawn = family(name, seed=seed)
    obs = observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations
    try:
        result = calibrate(obs)
    except CamnetError as exc:
        return "refused", {"reason": str(exc).split(":")[0][:60]}
    with np.errstate(all="ignore"):
        c = compare(result.calibration, drawn.rig.cameras, drawn.rig.points)
    focal_z = max(abs(e.focal_rel) / e.focal_sigma_rel if e.focal_sigma_rel > 0 else np.inf for e in c.cameras)
    scale_z = abs(c.scale_rel) / c.scale_sigma_rel if c.scale_sigma_rel > 0 else np.inf
    return "solved", {
        "scale_rel": c.scale_rel,
        "scale_sigma_rel": c.scale_sigma_rel,
        "focal_rel": max(abs(e.focal_rel) for e in c.cameras),
        "rms_px": c.rms_reprojection_px,
        "within_3_sigma": bool(np.nan_to_num(max(focal_z, scale_z), nan=np.inf) <= 3.0),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--families", default=",".join(FAMILIES))
    args = parser.parse_args()
    rows = []
    for name in args.families.split(","):
        t0 = time.perf_counter()
        solved, refused = [], Counter()
        for seed in range(args.seeds):
            kind, out = run_seed(name, seed)
            if kind == "solved":
                solved.append(out)
            else:
                refused[out["reason"]] += 1
            print(f"  {name} seed {seed}: {kind}", file=sys.stderr, flush=True)
        silent = sum(not s["within_3_sigma"] for s in solved)
        med = {key: float(np.median([abs(s[key]) for s in solved])) if solved else float("nan")
               for key in ("scale_rel", "scale_sigma_rel", "focal_rel", "rms_px")}
        rows.append((name, len(solved), sum(refused.values()), silent, 100 * med["scale_rel"],
                     100 * med["scale_sigma_rel"], 100 * med["focal_rel"], med["rms_px"],
                     "; ".join(f"{n}x {r}" for r, n in refused.most_common(2)), time.perf_counter() - t0))
    print("| family | solved | refused | wrong in silence (> 3 sigma) | median scale err % | median scale sigma % "
          "| median max focal err % | median RMS px | main refusals | time s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.2f} | {r[5]:.2f} | {r[6]:.1f} | {r[7]:.2f} | {r[8]} "
              f"| {r[9]:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
