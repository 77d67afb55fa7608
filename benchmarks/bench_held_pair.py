#!/usr/bin/env python3
"""A stereo head held parallel: does the reported scale sigma cover a head toed in by a little?

Solves seeded ring families (camnet.sim.families) with every head's right
camera toed in by `--yaws` degrees, at default options, and prints per
family and toe-in: how many seeds the rule freed the yaw on, how many carry
the held yaw's warning, the share of scale errors within 3 reported sigmas
(the pair's held rotation at `pair_tolerance_deg`), the same share for the
sigma conditional on the pair being exactly parallel (taken from the same
covariance, conditioned on the held axes), the median sigmas and error, and
the largest error in reported sigmas.

    python benchmarks/bench_held_pair.py [--families ring_K] [--yaws 0,0.05,0.1,0.2] [--seeds 0-19]
        [--tolerance-deg 0.08]
"""

from __future__ import annotations

import argparse

import numpy as np

from camnet.errors import SolveError
from camnet.model.accuracy import compare
from camnet.sim.families import family, observe_family
from camnet.solve import Options, calibrate
from camnet.solve.bundle import ROT
from camnet.solve.free_rule import PAIR_TOLERANCE_DEG
from camnet.solve.uncertainty import scale_sigma, scale_weights


def solve(name: str, seed: int, yaw_deg: float, options: Options):
    """(scale error, reported sigma, sigma were the pair exactly parallel, yaw freed, warned), or None: refused."""
    drawn = family(name, seed=seed, head_yaw_deg=yaw_deg)
    try:
        result = calibrate(observe_family(drawn, noise_px=0.5, seed=seed), options)
    except SolveError:
        return None
    cal, cov, problem = result.calibration, result.covariance, result.problem
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    cols = cov.columns[1, ROT]
    held = cols[(cols >= 0) & ~problem.rot_free[1]]
    w = scale_weights(cov, result.state.X)
    ratio = scale_sigma(cov, result.state.X, w, given=held) / scale_sigma(cov, result.state.X, w)
    warned = any("stereo_yaw held" in text for text in cal.warnings)
    return c.scale_rel, c.scale_sigma_rel, c.scale_sigma_rel * ratio, bool(problem.rot_free[1, 1]), warned


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", default="ring_K")
    parser.add_argument("--yaws", default="0,0.05,0.1,0.2")
    parser.add_argument("--seeds", default="0-19")
    parser.add_argument("--tolerance-deg", type=float, default=PAIR_TOLERANCE_DEG)
    args = parser.parse_args()
    first, last = (int(s) for s in args.seeds.split("-"))
    options = Options(pair_tolerance_deg=args.tolerance_deg)
    print(f"tolerance {args.tolerance_deg} deg, seeds {first}-{last}")
    print("| family | toe-in deg | solved | yaw freed | warned | within 3σ | within 3σ exactly parallel "
          "| median σ % | median σ % exactly parallel | median abs err % | max err/σ |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.families.split(","):
        for yaw in (float(y) for y in args.yaws.split(",")):
            rows = [r for r in (solve(name, s, yaw, options) for s in range(first, last + 1)) if r is not None]
            err, sigma, parallel, freed, warned = (np.array(x) for x in zip(*rows, strict=True))
            z, z0 = np.abs(err) / sigma, np.abs(err) / parallel
            print(f"| {name} | {yaw:g} | {len(rows)} | {freed.sum()} | {warned.sum()} | "
                  f"{100 * np.mean(z <= 3):.0f}% | {100 * np.mean(z0 <= 3):.0f}% | {100 * np.median(sigma):.3g} | "
                  f"{100 * np.median(parallel):.3g} | {100 * np.median(np.abs(err)):.3g} | {z.max():.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
