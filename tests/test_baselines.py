"""Known distances beyond the stereo baseline: a second head, a taped distance, a soft stereo baseline.

The paper's rig with a second parallel head (mono_b and a new camera 0.125 m to
its right), seeded; each test holds the solve against what the distances say.
"""

from dataclasses import replace

import numpy as np
import pytest

from camnet.model.accuracy import compare
from camnet.model.methods import Method
from camnet.model.observations import Baseline, Observations
from camnet.sim.simulate import PAPER_BASELINE_M, make_rig, observe, with_head
from camnet.solve import Options, calibrate

HEAD = ("mono_b", "mono_b_right")


@pytest.fixture(scope="module")
def rig():
    return with_head(make_rig(seed=2, n_points=80), "mono_b")


def given_K(obs: Observations) -> Observations:
    """Every camera's true K given and held: no guessed principal point widens the scale's sigma."""
    return replace(obs, cameras=tuple(replace(c, fixed=frozenset({"K", "dist"})) for c in obs.cameras))


def centres(result) -> dict[str, np.ndarray]:
    return {c.id: c.centre for c in result.calibration.cameras}


def distance_m(result, a: str, b: str) -> float:
    C = centres(result)
    return float(np.linalg.norm(C[a] - C[b]))


def scale(result, rig) -> float:
    return 1.0 + compare(result.calibration, rig.cameras, rig.points).scale_rel


def test_an_exact_second_baseline_is_held(rig):
    obs = observe(rig, noise_px=0.5, seed=2).observations
    wrong = replace(obs, baselines=(Baseline(*HEAD, 1.01 * PAPER_BASELINE_M),))
    for o, expected in ((obs, PAPER_BASELINE_M), (wrong, 1.01 * PAPER_BASELINE_M)):
        result = calibrate(o)
        assert distance_m(result, *HEAD) == pytest.approx(expected, abs=1e-6)
        assert np.linalg.norm(centres(result)["right"]) == pytest.approx(PAPER_BASELINE_M, abs=1e-12)


def test_the_second_head_alone_sets_the_scale_when_the_stereo_baseline_is_loose(rig):
    obs = given_K(observe(rig, noise_px=0.1, seed=2, with_intrinsics=True).observations)
    loose = replace(obs, stereo=replace(obs.stereo, sigma_m=1.0))  # a metre: known not at all
    for factor in (1.0, 1.03):
        result = calibrate(replace(loose, baselines=(Baseline(*HEAD, factor * PAPER_BASELINE_M),)))
        assert scale(result, rig) == pytest.approx(factor, abs=2e-3)
        assert np.linalg.norm(centres(result)["right"]) == pytest.approx(factor * PAPER_BASELINE_M, rel=2e-3)


def test_a_wrong_baseline_pulls_the_scale_and_a_loose_one_is_ignored(rig):
    obs = given_K(observe(rig, noise_px=0.5, seed=2, with_intrinsics=True).observations)
    taped = replace(obs, stereo=replace(obs.stereo, sigma_m=0.002), baselines=())
    alone = scale(calibrate(taped), rig)
    # An exact second head 3% long against a stereo baseline known to 1.6%: the scale moves part of the way.
    pulled = scale(calibrate(replace(taped, baselines=(Baseline(*HEAD, 1.03 * PAPER_BASELINE_M),))), rig)
    assert 0.003 < pulled - alone < 0.03
    loose = calibrate(replace(taped, baselines=(Baseline(*HEAD, 1.03 * PAPER_BASELINE_M, 10.0),)))
    assert scale(loose, rig) == pytest.approx(alone, abs=1e-5)


def test_a_taped_stereo_baseline_limits_the_reported_scale_sigma(rig):
    obs = given_K(observe(rig, noise_px=0.5, seed=2, with_intrinsics=True).observations)
    exact = calibrate(replace(obs, baselines=()))
    tape_m = 0.002
    taped = calibrate(replace(obs, baselines=(), stereo=replace(obs.stereo, sigma_m=tape_m)))
    sigma_exact = exact.calibration.uncertainty.scale_rel.value
    sigma_taped = taped.calibration.uncertainty.scale_rel.value
    # The tape's 1.6% dominates the scene's share; they add in quadrature.
    expected = np.hypot(tape_m / PAPER_BASELINE_M, sigma_exact)
    assert sigma_taped == pytest.approx(expected, rel=0.1)
    assert taped.calibration.report.free.stereo_direction is False  # the right centre moves in 3-D instead
    assert any("baseline is soft" in d for d in taped.calibration.report.free_rule)


def test_a_second_head_lowers_the_reported_scale_sigma(rig):
    obs = observe(rig, noise_px=0.5, seed=2).observations
    one = calibrate(replace(obs, baselines=())).calibration.uncertainty.scale_rel.value
    two = calibrate(obs).calibration.uncertainty.scale_rel.value
    assert two < 0.97 * one


def test_the_unconstrained_method_knows_no_distance(rig):
    obs = observe(rig, noise_px=0.5, seed=2).observations
    options = Options(method=Method.UNCONSTRAINED)
    plain = calibrate(replace(obs, baselines=()), options)
    wrong = calibrate(replace(obs, baselines=(Baseline(*HEAD, 2 * PAPER_BASELINE_M),)), options)
    np.testing.assert_allclose(wrong.calibration.points, plain.calibration.points, atol=1e-9)


def test_camnet_simulate_draws_a_second_head():
    import argparse

    from camnet.commands.simulate import add_arguments, simulate_from_args
    from camnet.errors import InputError

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    rig, sim = simulate_from_args(parser.parse_args(["-o", "x.json", "--second-head"]))
    assert sim.observations.baselines == (Baseline(*HEAD, PAPER_BASELINE_M),)
    C = {c.id: c.centre for c in rig.cameras}
    assert np.linalg.norm(C["mono_b_right"] - C["mono_b"]) == pytest.approx(PAPER_BASELINE_M)
    with pytest.raises(InputError, match="--second-head"):
        simulate_from_args(parser.parse_args(["-o", "x.json", "--second-head", "--cameras", "3"]))


def test_a_distance_the_scene_contradicts_is_reported(rig):
    obs = observe(rig, noise_px=0.5, seed=2).observations
    assert not [w for w in calibrate(obs).calibration.warnings if "the scene puts them" in w]
    wrong = calibrate(replace(obs, baselines=(Baseline(*HEAD, 1.5 * PAPER_BASELINE_M),)))
    said = [w for w in wrong.calibration.warnings if "the scene puts them" in w]
    assert len(said) == 1 and said[0].startswith("cameras mono_b and mono_b_right: the scene puts them 0.1")
    assert "not the given 0.1875 m" in said[0]


def test_the_reported_scale_sigma_holds_a_taped_baseline_to_its_reading():
    """Twenty seeded rigs whose stereo baseline is a tape's reading (truth plus a 2 mm draw): the scale
    errors, in reported sigmas, are standard normal."""
    z = []
    for seed in range(20):
        rig = make_rig(seed=seed, n_points=60)
        reading_m = rig.baseline_m + np.random.default_rng(seed).normal(scale=0.002)
        obs = given_K(observe(rig, noise_px=0.5, seed=seed, with_intrinsics=True).observations)
        obs = replace(obs, stereo=replace(obs.stereo, baseline_m=reading_m, sigma_m=0.002))
        c = compare(calibrate(obs).calibration, rig.cameras, rig.points)
        z.append(c.scale_rel / c.scale_sigma_rel)
    assert np.max(np.abs(z)) < 3.0
    assert 0.5 < np.mean(np.square(z)) < 1.8
