#!/usr/bin/env python3
"""Real-rig families (camnet.sim.families): is each calibrated, refused for a reason, or wrong in silence?

For every family and seed, `camnet calibrate`'s engine at default options on
seeded observations (0.5 px noise; a camera sees only the side of the scene
that faces it). A solve is "silent" when it returns a calibration whose scale
or some focal length is off by more than 3 of its reported sigmas (or whose
sigma is missing): the failure the user cannot see. Prints one row per family,
with, beside it, what a user does today on the same tracks from the same
start: COLMAP's bundle adjustment (pycolmap), the scale then fixed from the
known distance (benchmarks/colmap_anchor.py); both scale errors with equal
point weights. Beside camnet's scale and shape errors, their Cramér-Rao
bounds (camnet.sim.bounds: at the ground truth, with the solve's free
parameters, known distances and lens models) and the ratios of the medians.

Then what a second head buys: the same seeded observations solved with the
second head's baseline and with it ignored, on the `two_heads` ring and on
the paper's rig with a parallel partner for mono_b; the ratio of the
reported scale sigmas, per seed where both solved.

    python benchmarks/bench_rigs.py [--seeds 20] [--families ring,wide] [--heads-only]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from dataclasses import replace

import numpy as np
from colmap_anchor import colmap_adjust

from camnet.errors import CamnetError
from camnet.model.accuracy import compare, scale_error
from camnet.sim.bounds import cramer_rao
from camnet.sim.families import FAMILIES, family, observe_family
from camnet.sim.simulate import make_rig, observe, with_head
from camnet.solve import calibrate

NOISE_PX = 0.5

HEAD_VARIANTS = ("two_heads", "paper + head")


def run_seed(name: str, seed: int) -> tuple[str, dict]:
    """("solved", errors) or ("refused", {"reason": ...}) for one seed of one family."""
    drawn = family(name, seed=seed)
    obs = observe_family(drawn, noise_px=NOISE_PX, seed=seed)
    try:
        result = calibrate(obs)
    except CamnetError as exc:
        return "refused", {"reason": str(exc).split(":")[0][:60]}
    with np.errstate(all="ignore"):
        c = compare(result.calibration, drawn.rig.cameras, drawn.rig.points)
    # A given K (a factory calibration) is held: no sigma, and its error is the given one's.
    focal_z = max(abs(e.focal_rel) / e.focal_sigma_rel if e.focal_sigma_rel > 0 else np.inf
                  for e in c.cameras if e.id not in drawn.given)
    scale_z = abs(c.scale_rel) / c.scale_sigma_rel if c.scale_sigma_rel > 0 else np.inf
    anchor = colmap_adjust(obs, seed)  # the same tracks and start; the scale from the known distance
    bound = cramer_rao(drawn.rig, result, NOISE_PX)
    return "solved", {
        "scale_equal_rel": scale_error(result.calibration.points, drawn.rig.points[result.calibration.point_ids]),
        "colmap_scale_rel": scale_error(anchor.points, drawn.rig.points[anchor.track_ids]),
        "scale_rel": c.scale_rel,
        "scale_sigma_rel": c.scale_sigma_rel,
        "scale_bound_rel": bound.scale_rel,
        "shape_mm": c.shape_rms_mm,
        "shape_bound_mm": 1e3 * bound.shape_m,
        "focal_rel": max(abs(e.focal_rel) for e in c.cameras if e.id not in drawn.given),
        # The same camera's bound: the worst error beside what the geometry allows it.
        "focal_bound_rel": bound.focal_rel[max((e for e in c.cameras if e.id not in drawn.given),
                                               key=lambda e: abs(e.focal_rel)).id],
        "rms_px": c.rms_reprojection_px,
        "within_3_sigma": bool(np.nan_to_num(max(focal_z, scale_z), nan=np.inf) <= 3.0),
    }


def head_pair(variant: str, seed: int) -> tuple[dict | None, dict | None]:
    """(one head, two heads): the solve's scale error and sigma with the second head's baseline ignored and
    used, on the same observations; None where refused."""
    if variant == "two_heads":
        drawn = family("two_heads", seed=seed)
        rig, normals = drawn.rig, drawn.normals
    else:
        rig, normals = with_head(make_rig(seed=seed, n_points=120), "mono_b"), None
    obs = observe(rig, noise_px=NOISE_PX, seed=seed, normals=normals).observations
    out = []
    for used in (replace(obs, baselines=()), obs):
        try:
            cal = calibrate(used).calibration
        except CamnetError:
            out.append(None)
            continue
        with np.errstate(all="ignore"):
            c = compare(cal, rig.cameras, rig.points)
        out.append({"scale_rel": c.scale_rel, "scale_sigma_rel": c.scale_sigma_rel})
    return out[0], out[1]


def _median_pct(solves: list[dict], key: str) -> float:
    return 100 * float(np.median([abs(s[key]) for s in solves])) if solves else float("nan")


def print_head_table(seeds: int) -> None:
    print("\n| rig | seeds solved both ways | median scale σ % one head | two heads | median ratio | "
          "ratio <= 0.75 | median scale err % one head | two heads |")
    print("|---|---|---|---|---|---|---|---|")
    for variant in HEAD_VARIANTS:
        pairs = [head_pair(variant, seed) for seed in range(seeds)]
        ones = [one for one, two in pairs if one is not None and two is not None]
        twos = [two for one, two in pairs if one is not None and two is not None]
        ratios = [two["scale_sigma_rel"] / one["scale_sigma_rel"] for one, two in zip(ones, twos, strict=True)]
        sigmas = f"{_median_pct(ones, 'scale_sigma_rel'):.2f} | {_median_pct(twos, 'scale_sigma_rel'):.2f}"
        print(f"| {variant} | {len(ones)} of {seeds} | {sigmas} | {np.median(ratios) if ratios else np.nan:.2f} "
              f"| {sum(r <= 0.75 for r in ratios)} | {_median_pct(ones, 'scale_rel'):.2f} "
              f"| {_median_pct(twos, 'scale_rel'):.2f} |", flush=True)


PERCENT = ("scale_rel", "scale_sigma_rel", "scale_bound_rel", "focal_rel", "focal_bound_rel", "scale_equal_rel",
           "colmap_scale_rel")


def family_row(name: str, seeds: int) -> dict:
    """One family's row: counts, and the medians over its solved seeds (relative errors in %)."""
    t0 = time.perf_counter()
    solved, refused = [], Counter()
    for seed in range(seeds):
        kind, out = run_seed(name, seed)
        if kind == "solved":
            solved.append(out)
        else:
            refused[out["reason"]] += 1
        print(f"  {name} seed {seed}: {kind}", file=sys.stderr, flush=True)
    row = {"name": name, "solved": len(solved), "refused": sum(refused.values()),
           "silent": sum(not s["within_3_sigma"] for s in solved),
           "refusals": "; ".join(f"{n}x {r}" for r, n in refused.most_common(2))}
    for key in (*PERCENT, "shape_mm", "shape_bound_mm", "rms_px"):
        median = float(np.median([abs(s[key]) for s in solved])) if solved else float("nan")
        row[key] = 100 * median if key in PERCENT else median
    row["time_s"] = time.perf_counter() - t0
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--families", default=",".join(FAMILIES))
    parser.add_argument("--heads-only", action="store_true", help="only the one-head / two-heads table")
    args = parser.parse_args()
    if args.heads_only:
        print_head_table(args.seeds)
        return 0
    rows = [family_row(name, args.seeds) for name in args.families.split(",")]
    print("| family | solved | refused | wrong in silence (> 3 sigma) | median scale err % | median scale sigma % "
          "| scale CRB % | scale err / CRB | median shape mm | shape CRB mm | shape / CRB "
          "| median max focal err % | its camera's focal CRB % | focal err / CRB | median RMS px "
          "| scale err %, equal weights: camnet | pycolmap BA + distance "
          "| pycolmap / camnet | most common refusals | time s |")
    print("|" + "---|" * 20)
    for r in rows:
        cells = [r["name"], r["solved"], r["refused"], r["silent"], f"{r['scale_rel']:.2f}",
                 f"{r['scale_sigma_rel']:.2f}", f"{r['scale_bound_rel']:.3f}",
                 f"{r['scale_rel'] / r['scale_bound_rel']:.2f}", f"{r['shape_mm']:.2f}", f"{r['shape_bound_mm']:.2f}",
                 f"{r['shape_mm'] / r['shape_bound_mm']:.2f}", f"{r['focal_rel']:.1f}", f"{r['focal_bound_rel']:.2f}",
                 f"{r['focal_rel'] / r['focal_bound_rel']:.2f}", f"{r['rms_px']:.2f}",
                 f"{r['scale_equal_rel']:.2f}", f"{r['colmap_scale_rel']:.2f}",
                 f"{r['colmap_scale_rel'] / r['scale_equal_rel']:.1f}", r["refusals"], f"{r['time_s']:.0f}"]
        print("| " + " | ".join(str(c) for c in cells) + " |", flush=True)
    print_head_table(args.seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
