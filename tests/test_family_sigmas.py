"""The reported sigmas hold on the real-rig families: scale and focal errors within 3 sigma.

Over 20 seeds of each family (camnet.sim.families) that the benchmark (0-19)
does not use, at default options but for the second opinion (the curvature's
own sigmas must hold here; on these families the halves change none of
them, benchmarks/bench_second_opinion.py): the scale and every estimated focal
length lie within 3 reported sigmas in at least 95% of the checks, per
family and quantity (one miss in 20). A camera whose K the observations
give is held and has no focal check; a camera the solve leaves out is named
in its report and has none either; a refused solve (a wrong start) has no check, and at most one per
family is allowed. The ring with its head's K given must
also keep its scale error below 0.5%. The paper's rig is checked the same way in tests/test_engine.py;
here the rigs it is unlike.
"""

from dataclasses import replace

import numpy as np
import pytest

from camnet.errors import SolveError
from camnet.model.accuracy import compare
from camnet.sim.families import FAMILIES, family, observe_family
from camnet.solve import Options, calibrate

FIRST_SEED = 20
SEEDS = 20  # per family: 95% then allows one miss per family and quantity
WITHIN = 0.95
RING_K_MAX_SCALE_REL = 0.005  # the factory-calibrated head's must-reach
CURVATURE_ONLY = Options(halves=False)


def z_scores(name: str, seed: int) -> tuple[float, list[float], float, float]:
    """(|scale error| / sigma, [|focal error| / sigma per estimated focal length], scale error, its sigma)."""
    drawn = family(name, seed=seed)
    cal = calibrate(observe_family(drawn, noise_px=0.5, seed=seed), CURVATURE_ONLY).calibration
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)  # the cameras placed (a camera left out is named)

    def z(error: float, sigma: float) -> float:
        return abs(error) / sigma if sigma > 0 else np.inf  # a missing sigma never passes

    focal = [z(e.focal_rel, e.focal_sigma_rel) for e in c.cameras if e.id not in drawn.given]
    return z(c.scale_rel, c.scale_sigma_rel), focal, c.scale_rel, c.scale_sigma_rel


@pytest.mark.parametrize("name", FAMILIES)
def test_scale_and_focal_errors_lie_within_three_reported_sigmas(name):
    scale_z, focal_z, scale_rel = [], [], []
    refused = []
    for seed in range(FIRST_SEED, FIRST_SEED + SEEDS):
        try:
            s, f, rel, _ = z_scores(name, seed)
        except SolveError:
            refused.append(seed)  # said, not silent; but a rule that refused everything would pass the rest
            continue
        scale_z.append(s)
        focal_z += f
        scale_rel.append(abs(rel))
    assert len(refused) <= round(SEEDS * (1 - WITHIN)), f"{name}: refused seeds {refused}"
    scale_z, focal_z = np.array(scale_z), np.array(focal_z)
    assert np.mean(scale_z <= 3) >= WITHIN, f"{name}: scale errors / sigma {np.round(scale_z, 2).tolist()}"
    assert np.mean(focal_z <= 3) >= WITHIN, f"{name}: focal errors / sigma, worst {np.sort(focal_z)[-3:].tolist()}"
    if name == "ring_K":
        # On every seed: the free rule keeps the head's yaw held, which freed would put the scale's sigma up
        # to 1.6-1.8% (seeds 25, 28 and 30 test the yaw's rule: docs/benchmarks.md, "Rigs unlike the paper's").
        assert (np.array(scale_rel) < RING_K_MAX_SCALE_REL).all(), (
            f"ring_K: scale errors % {np.round(100 * np.array(scale_rel), 3).tolist()}")


def test_a_tape_pair_that_passes_for_parallel_is_calibrated_from_the_other_start():
    # Seed 30 of tape_pair: its two cameras 45 degrees apart pass for the paper's parallel pair (RANSAC's
    # fundamental matrix fits their matches no better than matching rows); the paper's start leaves ring3-5
    # out and keeps 60% of the observations, which is refused. The essential matrix's start places them all.
    s, f, _, _ = z_scores("tape_pair", 30)
    assert s <= 3 and max(f) <= 3, f"scale error / sigma {s:.2f}, focal {np.round(f, 2).tolist()}"


def test_a_start_that_keeps_few_observations_gives_way_to_the_other():
    # Seed 2 of wide, its pair's K given (its distortion not): the paper's start lands in a wrong basin, where
    # the adjustment keeps 72% of the observations at RMS 2.3 px with the scale 21% off at a reported 1.0%. The
    # essential matrix's start keeps 99% at 0.52 px, and has the lower truncated cost of every observation.
    drawn = family("wide", seed=2)
    truth = {c.id: c for c in drawn.rig.cameras}
    obs = observe_family(drawn, noise_px=0.5, seed=2)
    pair = (obs.stereo.left, obs.stereo.right)
    obs = replace(obs, cameras=tuple(replace(c, K=truth[c.id].K.copy(), fixed=frozenset({"K"})) if c.id in pair
                                     else c for c in obs.cameras))
    cal = calibrate(obs).calibration
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    assert abs(c.scale_rel) <= 3 * c.scale_sigma_rel, (c.scale_rel, c.scale_sigma_rel)
    assert cal.report.inliers >= 0.9 * cal.report.observations
