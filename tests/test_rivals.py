"""Competing solutions of a cold solve: run from several starts, named where the data cannot tell them from the
kept one, their sigmas widened to cover them (camnet.solve.start.choice, camnet.solve.report.rivals)."""

import json
from dataclasses import replace
from functools import cache

import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.model.accuracy import compare
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.report.rivals import NEAR_COST_SIGMAS, RIVAL_SIGMAS
from camnet.solve.report.verdict import Level, judge
from camnet.solve.start.choice import solve_from_any_start, start_order
from camnet.solve.start.state import PairStart

HELD_OFF_SIGMAS = 6.0  # the rival's focal length, held this many of the kept solution's sigmas away


def weak_pair_rig(n_cameras: int, n_points: int):
    """The paper's rig on an arc, the right stereo camera seeing three quarters of the tracks: the pair's start,
    then the strongest pair's (two cameras that see every track)."""
    rig = make_rig(n_cameras=n_cameras, n_points=n_points, seed=1)
    obs = observe(rig, noise_px=0.5, seed=1).observations
    drop = (obs.cam_index == obs.index_of("right")) & (np.random.default_rng(0).random(len(obs.uv)) < 0.25)
    return rig, replace(obs, cam_index=obs.cam_index[~drop], track_index=obs.track_index[~drop], uv=obs.uv[~drop])


@cache
def well_posed():
    rig, obs = weak_pair_rig(12, 1000)
    return rig, obs, calibrate(obs)


@cache
def with_a_rival():
    """A cold solve, and a solution that fits the same observations nearly as well with mono_03's focal length
    held HELD_OFF_SIGMAS of its sigmas away: two converged, sound solutions of nearly equal cost that differ."""
    rig, obs = weak_pair_rig(6, 300)
    options = Options()
    cold = calibrate(obs, options)
    cam = next(c for c in cold.calibration.cameras if c.id == "mono_03")
    sigma_f = cold.calibration.uncertainty.cameras["mono_03"].f_px
    K = cam.K.copy()
    K[0, 0] += HELD_OFF_SIGMAS * sigma_f
    K[1, 1] += HELD_OFF_SIGMAS * sigma_f
    held = replace(obs, cameras=tuple(replace(c, K=K, dist=np.zeros(5), fixed=frozenset({"K"})) if c.id == "mono_03"
                                      else c for c in obs.cameras))
    off = calibrate(held, options)
    order = start_order(obs)
    assert len(order) == 2 and order[-1] == PairStart.STRONGEST

    def solve(pair: PairStart):
        return cold if pair == order[0] else off

    found = solve_from_any_start(obs, solve, outlier_sigmas=options.outlier_sigmas,
                                 min_outlier_px=options.min_outlier_px)
    return rig, cold, off, found


def test_a_rival_of_nearly_equal_cost_is_named_with_each_solution_and_its_cost():
    # Holding one focal length off moves the others and the scale with it, at nearly no cost: the valley the
    # kept solution's curvature cannot see.
    rig, cold, off, found = with_a_rival()
    rivals = found.calibration.report.rivals
    assert len(rivals) == 1
    r = rivals[0]
    assert abs(r.cost_px2 - r.kept_cost_px2) <= NEAR_COST_SIGMAS * r.cost_noise_px2
    kept, other = (off, cold) if found.calibration.points is off.calibration.points else (cold, off)
    assert r.start == (start_order(weak_pair_rig(6, 300)[1])[0] if other is cold else PairStart.STRONGEST).value
    focal_kept, focal_other = ({c.id: c.K[0, 0] for c in res.calibration.cameras} for res in (kept, other))
    named = {(d.parameter, d.camera) for d in r.differences}
    assert ("scale", None) in named and sum(p == "f_px" for p, _ in named) >= 2
    for d in r.differences:
        assert abs(d.rival - d.kept) > RIVAL_SIGMAS * d.kept_sigma
        if d.parameter == "f_px":
            assert (d.kept, d.rival) == pytest.approx((focal_kept[d.camera], focal_other[d.camera]))
    scale = next(d for d in r.differences if d.parameter == "scale")
    against_truth = [1 + compare(res.calibration, rig.cameras, rig.points).scale_rel for res in (kept, other)]
    assert scale.rival == pytest.approx(against_truth[1] / against_truth[0], abs=0.01)


def test_the_sigmas_of_what_differs_cover_both_solutions_and_the_verdict_says_so():
    _, _, _, found = with_a_rival()
    cal = found.calibration
    r = cal.report.rivals[0]
    for d in r.differences:
        if d.parameter == "scale":
            widened = cal.uncertainty.scale_rel.value
        elif d.parameter == "f_px":
            widened = cal.uncertainty.cameras[d.camera].f_px
        else:
            widened = float(np.linalg.norm(cal.uncertainty.cameras[d.camera].rotation_deg))
        assert abs(d.rival - d.kept) <= 2.0 * widened + 1e-12, d  # both within two reported sigmas
        assert widened > d.kept_sigma
    assert any("competing solution" in w and "the scale by" in w and "known distance" in w for w in cal.warnings)
    verdict = judge(cal)
    assert verdict.level != Level.GOOD
    assert any("competing solution" in f.what for f in verdict.findings)


def test_a_well_posed_rig_solved_from_several_starts_names_no_rival():
    rig, obs, result = well_posed()
    assert start_order(obs) == [PairStart.PAPER, PairStart.STRONGEST]
    cal = result.calibration
    assert cal.report.rivals == ()
    assert judge(cal).level == Level.GOOD
    c = compare(cal, rig.cameras, rig.points)
    assert abs(c.scale_rel) < 3 * c.scale_sigma_rel


def test_rivals_read_back_from_the_document_as_written():
    _, _, _, found = with_a_rival()
    doc = calibration_to_doc(found.calibration)
    assert doc["diagnostics"]["rivals"][0]["differences"]
    again = parse_calibration(json.loads(json.dumps(doc)))
    assert again.report.rivals == found.calibration.report.rivals
    assert calibration_to_doc(again) == doc


def test_a_document_without_rivals_reads_as_none_and_a_bad_one_is_refused_by_path():
    _, _, result = well_posed()
    doc = calibration_to_doc(result.calibration)
    assert "rivals" not in doc["diagnostics"]
    assert parse_calibration(doc).report.rivals == ()
    doc["diagnostics"]["rivals"] = [{"start": "essential", "cost_px2": 1.0, "kept_cost_px2": 1.0,
                                     "cost_noise_px2": 1.0, "differences": [{"parameter": "shear"}]}]
    with pytest.raises(InputError, match=r"^diagnostics\.rivals\[0\]\.differences\[0\]\.parameter: unknown value"):
        parse_calibration(doc)
