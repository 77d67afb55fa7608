#!/usr/bin/env python3
"""The floor frame found from the scene (camnet.solve.world_frame) against the simulated truth.

Per rig, seeded solves with `Options(world=World.FLOOR)`: the angle between
the reported floor normal and the true one, and the error of the left
camera's height above the floor, each against its reported sigma. Rigs: the
families round a person standing on a floor (`floor_points` 300: ring,
ring_K with the head's K given, tape_pair), and the paper's rig over a floor
0.45 m below its left camera, the head pitched down 15 degrees and rolled 3,
every other camera rolled up to 4 degrees (`paper_tilted`).

    python benchmarks/bench_world_frame.py [--seeds 20] [--rigs ring_K,ring,paper_tilted,tape_pair]
"""

from __future__ import annotations

import argparse

import numpy as np

from camnet.sim.families import family, observe_family
from camnet.sim.simulate import make_rig, observe, rolled, with_floor
from camnet.solve import Options, calibrate
from camnet.solve.options import World

RIGS = ("ring_K", "ring", "tape_pair", "paper_tilted")


def solve(rig: str, seed: int):
    """(the solved FloorFrame, the true floor) of `rig` drawn with `seed`."""
    if rig == "paper_tilted":
        drawn, truth = with_floor(make_rig(seed=seed), pitch_deg=15.0, roll_deg=3.0, seed=seed)
        obs = observe(rolled(drawn, 4.0, seed=seed), seed=seed).observations
    else:
        drawn = family(rig, seed=seed, floor_points=300)
        truth, obs = drawn.floor, observe_family(drawn, seed=seed)
    return calibrate(obs, Options(world=World.FLOOR)).calibration.floor_frame, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--rigs", default=",".join(RIGS))
    args = parser.parse_args()
    print("| rig | found | normal error, deg (median / max) | its sigma, deg (median) | error / sigma (median / max) "
          "| within 3 sigma | height error, mm (median / max) | its sigma, mm (median) | error / sigma (median / max) "
          "| within 3 sigma |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for rig in args.rigs.split(","):
        rows = []
        for seed in range(args.seeds):
            frame, truth = solve(rig, seed)
            if frame.found:
                angle = float(np.degrees(np.arccos(np.clip(frame.R[2] @ truth.up_left, -1.0, 1.0))))
                rows.append((angle, frame.normal_sigma_deg, abs(frame.t[2] - truth.left_height_m) * 1e3,
                             frame.height_sigma_m * 1e3))
        a = np.array(rows).reshape(-1, 4)
        normal, height = a[:, 0] / a[:, 1], a[:, 2] / a[:, 3]
        print(f"| {rig} | {len(a)}/{args.seeds} | {np.median(a[:, 0]):.3f} / {a[:, 0].max():.3f} | "
              f"{np.median(a[:, 1]):.3f} | {np.median(normal):.2f} / {normal.max():.2f} | "
              f"{np.mean(normal <= 3):.0%} | {np.median(a[:, 2]):.1f} / {a[:, 2].max():.1f} | "
              f"{np.median(a[:, 3]):.1f} | {np.median(height):.2f} / {height.max():.2f} | {np.mean(height <= 3):.0%} |",
              flush=True)


if __name__ == "__main__":
    main()
