#!/usr/bin/env python3
"""What the second opinion (camnet.solve.halves, camnet.solve.pair_check) costs and what it changes, on simulated
rigs whose truth is known.

First the cost: a cold solve of 12 cameras and 1000 tracks, with and
without the halves and pair checks, the ratio of the median times in one run. Then,
per family of camnet.sim.families (and the hard ones), the same seeded
observations solved both ways: how many solves have their scale and every
focal length within 3 reported sigmas of the truth, how much the check
widened the sigmas (the median ratio of the scale's), how often it named
a disagreement, and the verdicts it changed. Last, the pair check: on each
family's sound solves, how often it names a camera or a pair (false
alarms), and how often it names a camera turned by 0.1-2 degrees. Then the lens check: each family solved as
a live rig solves (distortion held), straight and with its last camera's lens bent, and the focal lengths it
names against those off by more than 3 sigmas. Where the model is exact the
check should widen little and change no verdict; on the real scenes it is
the part that speaks (benchmarks/bench_real.py).

    python benchmarks/bench_second_opinion.py [--seeds 10] [--families ring,wide] [--cost-seeds 5]
        [--tables cost,families,pairs,lens]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from camnet.errors import CamnetError
from camnet.live.policy import LIVE_FREE
from camnet.model.accuracy import compare
from camnet.sim.families import FAMILIES, HARD_FAMILIES, family, observe_family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate, solved_from
from camnet.solve.lens_check import with_lens_check
from camnet.solve.pair_check import with_pair_check
from camnet.solve.report.lens_shifts import biased
from camnet.solve.report.pair_poses import judge_pairs
from camnet.solve.report.verdict import judge
from camnet.testing.turned import turned

NOISE_PX = 0.5
TABLES = ("cost", "families", "pairs", "lens")
LENS_K1 = (0.0, 0.2)  # the last camera's lens in the lens check's rows: straight, and a webcam's bend


def cost_row(seeds: int) -> str:
    """Median cold-solve seconds of 12 cameras and 1000 tracks without and with the check, and their ratio."""
    times: dict[bool, list[float]] = {False: [], True: []}
    pair_check = []
    for seed in range(seeds):
        obs = observe(make_rig(n_cameras=12, n_points=1000, seed=seed), noise_px=NOISE_PX, seed=seed).observations
        for halves in (False, True):  # side by side, so that a busy spell slows both
            t0 = time.perf_counter()
            cal = calibrate(obs, Options(halves=halves)).calibration
            times[halves].append(time.perf_counter() - t0)
        pair_check.append(cal.report.timings_s.get("pair_check", 0.0))
        print(f"  cost seed {seed}: {times[False][-1]:.1f} s, {times[True][-1]:.1f} s", file=sys.stderr, flush=True)
    plain, checked = np.median(times[False]), np.median(times[True])
    return (f"| 12 cameras, 1000 tracks, {seeds} seeds | {plain:.2f} | {checked:.2f} | {np.median(pair_check):.2f} "
            f"| {checked / plain:.2f} |")


def within(cal, drawn) -> bool:
    """Scale and every focal length not given within 3 reported sigmas of the truth."""
    with np.errstate(all="ignore"):
        c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    z = [abs(c.scale_rel) / c.scale_sigma_rel if c.scale_sigma_rel > 0 else np.inf]
    z += [abs(e.focal_rel) / e.focal_sigma_rel if e.focal_sigma_rel > 0 else np.inf
          for e in c.cameras if e.id not in drawn.given]
    return bool(np.nan_to_num(max(z), nan=np.inf) <= 3.0)


def family_row(name: str, seeds: int) -> str:
    solved, inside, changed, named, ratios = {False: 0, True: 0}, {False: 0, True: 0}, 0, 0, []
    for seed in range(seeds):
        drawn = family(name, seed=seed)
        obs = observe_family(drawn, noise_px=NOISE_PX, seed=seed)
        cals = {}
        for halves in (False, True):
            try:
                cals[halves] = calibrate(obs, Options(halves=halves)).calibration
            except CamnetError:
                continue
            solved[halves] += 1
            inside[halves] += within(cals[halves], drawn)
        if len(cals) == 2:
            plain, checked = (cals[h].report.uncertainty.scale_rel.value for h in (False, True))
            if plain and checked:
                ratios.append(checked / plain)
            changed += judge(cals[False]).level != judge(cals[True]).level
            named += bool(cals[True].report.halves and cals[True].report.halves.widened)
        print(f"  {name} seed {seed}: {len(cals)} solved", file=sys.stderr, flush=True)
    ratio = f"{np.median(ratios):.2f}" if ratios else "-"
    return (f"| {name} | {solved[False]} / {solved[True]} | {inside[False]} / {inside[True]} | {ratio} | "
            f"{named} | {changed} |")


TURNS_DEG = (0.1, 0.25, 0.5, 1.0, 2.0)


def pair_row(name: str, seeds: int) -> str:
    """The pair check on a family's sound solves (any camera or pair named: a false alarm), then with one camera
    (not the stereo pair's) turned by each of TURNS_DEG: in how many seeds it, and it alone, is named."""
    alarms, named, solved = 0, dict.fromkeys(TURNS_DEG, 0), 0
    for seed in range(seeds):
        drawn = family(name, seed=seed)
        obs = observe_family(drawn, noise_px=NOISE_PX, seed=seed)
        try:
            cal = calibrate(obs, Options(halves=False)).calibration
        except CamnetError:
            continue
        solved += 1
        sound = judge_pairs(with_pair_check(obs, cal).report.pair_checks)
        alarms += bool(sound.named or sound.unexplained)
        cam_id = cal.cameras[min(4, len(cal.cameras) - 1)].id
        for turn in TURNS_DEG:
            found = judge_pairs(with_pair_check(obs, turned(cal, cam_id, turn)).report.pair_checks)
            named[turn] += list(found.named) == [cam_id]
        print(f"  {name} seed {seed}: pair check", file=sys.stderr, flush=True)
    return f"| {name} | {solved} | {alarms} | " + " | ".join(str(named[t]) for t in TURNS_DEG) + " |"


def bent(drawn, k1: float):
    """`drawn` with the last camera's lens given `k1` (nobody tells the solve)."""
    cameras = list(drawn.rig.cameras)
    dist = np.zeros_like(cameras[-1].dist)
    dist[0] = k1
    cameras[-1] = replace(cameras[-1], dist=dist)
    return replace(drawn, rig=replace(drawn.rig, cameras=tuple(cameras)))


def lens_row(name: str, seeds: int, k1: float) -> str:
    """The lens check (camnet.solve.lens_check) on a family solved as live (distortion held), its last camera's lens
    bent by `k1`: the undescribed cameras whose focal length is off by more than 3 of its sigmas, how many of those
    it named, and how many it named that were not (false alarms)."""
    wrong = caught = alarms = solved = 0
    for seed in range(seeds):
        drawn = bent(family(name, seed=seed), k1) if k1 else family(name, seed=seed)
        obs = observe_family(drawn, noise_px=NOISE_PX, seed=seed)
        try:
            cal = calibrate(obs, Options(free=LIVE_FREE, halves=False)).calibration
        except CamnetError:
            continue
        solved += 1
        shifts = with_lens_check(obs, cal, Options(free=LIVE_FREE), solved_from).report.lens_shifts or {}
        truth = {c.id: c for c in drawn.rig.cameras}
        for camera in cal.cameras:
            if camera.id not in shifts:
                continue
            sigma = cal.report.uncertainty.cameras[camera.id].f_px
            off = abs(camera.K[0, 0] - truth[camera.id].K[0, 0]) > 3 * sigma
            named = camera.id in biased(shifts)
            wrong, caught, alarms = wrong + off, caught + (off and named), alarms + (named and not off)
        print(f"  {name} seed {seed}: lens check, k1 {k1:g}", file=sys.stderr, flush=True)
    return f"| {name} | {k1:g} | {solved} | {wrong} | {caught} | {alarms} |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--cost-seeds", type=int, default=5)
    parser.add_argument("--families", default=",".join((*FAMILIES, *HARD_FAMILIES)))
    parser.add_argument("--tables", default=",".join(TABLES), help=f"comma list of {', '.join(TABLES)}")
    args = parser.parse_args()
    tables = args.tables.split(",")
    families = list(filter(None, args.families.split(",")))
    if "cost" in tables:
        print("| cold solve | without the checks, s | with them, s | of which the pair check, s | ratio |\n"
              "|---|---|---|---|---|")
        print(cost_row(args.cost_seeds), flush=True)
    if "families" in tables:
        print("\n| family | solved without / with | scale and focal lengths within 3 sigma, without / with | "
              "median scale sigma ratio, with / without | disagreements named | verdicts changed |")
        print("|---|---|---|---|---|---|")
        for name in families:
            print(family_row(name, args.seeds), flush=True)
    if "pairs" in tables:
        print("\n| family | solved | false alarms | " + " | ".join(f"{t:g} deg turn named" for t in TURNS_DEG) + " |")
        print("|---|---|---|" + "---|" * len(TURNS_DEG))
        for name in families:
            print(pair_row(name, args.seeds), flush=True)
    if "lens" in tables:
        print("\n| family | last camera's k1 | solved | focal lengths beyond 3 sigma | of those named | "
              "named within 3 sigma |")
        print("|---|---|---|---|---|---|")
        for name in families:
            if name != "fisheye":  # its lens model frees its coefficients
                for k1 in LENS_K1:
                    print(lens_row(name, args.seeds, k1), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
