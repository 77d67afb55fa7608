"""Each camera's pose against its own two views with its neighbours: a camera placed wrong is named, not its
neighbour, and a sound solve names none."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.model.calibration import PairPoseCheck
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.pair_check import with_pair_check
from camnet.solve.report.pair_poses import judge_pairs
from camnet.solve.report.verdict import Level, judge
from camnet.testing.turned import turned


@pytest.fixture(scope="module")
def solved():
    """(observations, calibration) of the paper's four cameras on 300 points at 0.5 px, its pair check made."""
    obs = observe(make_rig(n_points=300, seed=3), noise_px=0.5, seed=3).observations
    return obs, calibrate(obs, Options(halves=False)).calibration


def test_a_sound_solve_names_no_camera_and_its_checks_read_back(solved):
    obs, cal = solved

    checked = with_pair_check(obs, cal)

    checks = checked.report.pair_checks
    # Every pair of four cameras shares its points; the stereo pair, held parallel, is an assumption, not checked.
    assert len(checks) == 5 and {frozenset((c.first, c.second)) for c in checks}.isdisjoint(
        {frozenset((obs.stereo.left, obs.stereo.right))}), checks
    verdict = judge_pairs(checks)
    assert not verdict.named and not verdict.unexplained, [(c.first, c.second, c.in_sigmas) for c in checks]
    # A sound pair sits within its two views' noise: about sqrt(5) over five degrees of freedom.
    assert float(np.median([c.in_sigmas for c in checks])) < 4.0
    assert parse_calibration(calibration_to_doc(checked)).report.pair_checks == checks


def test_a_camera_turned_two_degrees_is_named_and_rated_poor_and_its_neighbours_are_not(solved):
    obs, cal = solved
    wrong = cal.cameras[2].id

    checked = with_pair_check(obs, turned(cal, wrong, 2.0))

    verdict = judge_pairs(checked.report.pair_checks)
    assert list(verdict.named) == [wrong] and not verdict.unexplained, verdict
    # The two views trade some of the turn with the baseline direction: each pair says most of it.
    assert all(1.0 < c.rotation_deg < 3.0 for c in verdict.named[wrong]), verdict.named[wrong]
    levels = {c.camera: c.level for c in judge(checked).cameras}
    assert levels.pop(wrong) == Level.POOR
    assert Level.POOR not in levels.values(), levels
    assert any(w.startswith(f"camera {wrong}: its pose disagrees with its own two views") for w in
               checked.report.warnings), checked.report.warnings


def _check(a: str, b: str, d: float) -> PairPoseCheck:
    return PairPoseCheck(a, b, rotation_deg=d / 100, direction_deg=d / 50, in_sigmas=d, shared=100, inliers=100)


def test_the_camera_that_disagrees_with_most_of_its_neighbours_is_blamed_and_a_lone_pair_is_said_as_a_pair():
    ring = [_check("a", "b", 2.0), _check("b", "c", 2.5), _check("c", "d", 1.5), _check("d", "e", 2.2),
            _check("e", "a", 1.8), _check("a", "c", 2.1)]

    blamed = judge_pairs((*ring, _check("x", "a", 80.0), _check("x", "b", 60.0), _check("x", "c", 2.4)))
    lone = judge_pairs((*ring[:-1], replace(ring[-1], in_sigmas=50.0)))

    assert list(blamed.named) == ["x"] and not blamed.unexplained, blamed
    # a and c each disagree with one of three neighbours: neither is blamed, the pair is named.
    assert not lone.named and [(c.first, c.second) for c in lone.unexplained] == [("a", "c")], lone
