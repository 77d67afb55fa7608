"""The second opinion: the scene's two halves solved apart, the sigmas widened to what they disagree on.

First the comparison itself, on calibrations made to differ by a known
amount; then whole solves: a simulated rig whose halves agree keeps its
verdict and its sigmas cover the truth, a scene too small to split says it
has no second opinion, and the check round-trips through the JSON.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.live.policy import LiveConfig
from camnet.live.tracker import Tracker
from camnet.model.accuracy import scale_error
from camnet.model.calibration import CameraSigmas
from camnet.model.projection import rotation_exp
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate, solved_from
from camnet.solve.halves import MIN_HALF_OBSERVATIONS, track_sides, unsolved_half, with_halves_check
from camnet.solve.report.halves import DISAGREE_SIGMAS, INFLATE_FROM, differences, widened
from camnet.solve.report.verdict import Level, judge
from tests.test_live import pooled


@pytest.fixture(scope="module")
def rig_and_obs():
    rig = make_rig(n_cameras=6, n_points=400, seed=4)
    return rig, observe(rig, noise_px=0.3, seed=4).observations


@pytest.fixture(scope="module")
def solved(rig_and_obs):
    _, obs = rig_and_obs
    return calibrate(obs).calibration


def turned(cal, cam_id: str, *, f_rel: float = 0.0, rotation_deg: float = 0.0):
    """`cal` with one camera's focal length scaled by 1 + f_rel and its rotation turned about the y axis."""
    cameras = []
    for c in cal.cameras:
        if c.id == cam_id:
            K = c.K.copy()
            K[0, 0] *= 1 + f_rel
            K[1, 1] *= 1 + f_rel
            R = rotation_exp(np.radians([0.0, rotation_deg, 0.0])) @ c.R
            c = replace(c, K=K, R=R, t=-R @ c.centre)
        cameras.append(c)
    return replace(cal, cameras=tuple(cameras))


def test_the_differences_of_two_calibrations_are_halved_and_weighed_by_both_sigmas(solved):
    cam = solved.cameras[3].id
    other = turned(solved, cam, f_rel=0.02, rotation_deg=0.4)

    diffs = differences(solved, other)

    assert diffs[f"f {cam}"].half == pytest.approx(0.01, rel=0.01)
    assert diffs[f"rotation {cam}"].half == pytest.approx(0.2, rel=1e-6)
    s = solved.report.uncertainty.cameras[cam]
    assert diffs[f"rotation {cam}"].sigma == pytest.approx(np.sqrt(2) * np.linalg.norm(s.rotation_deg) / 2)
    # The cameras not touched agree to rounding; the left camera's pose is the frame, so no rotation of it.
    assert diffs[f"f {solved.cameras[4].id}"].in_sigmas == 0.0
    assert f"rotation {solved.world_frame}" not in diffs
    assert diffs["scale"].half == pytest.approx(0.0, abs=1e-9)


def test_a_sigma_below_the_half_difference_is_raised_and_a_disagreement_named(solved):
    cam = solved.cameras[3].id
    s = solved.report.uncertainty.cameras[cam]
    f_px = float(next(c for c in solved.cameras if c.id == cam).K[0, 0])
    far = 10 * DISAGREE_SIGMAS * s.f_px / f_px  # far beyond the halves' sigmas
    diffs = differences(solved, turned(solved, cam, f_rel=far))

    u, named, factor = widened(solved.report.uncertainty, solved, diffs)

    assert named == (f"f {cam}",) and factor == 1.0  # one parameter's disagreement is no sigma's at large
    assert u.cameras[cam].f_px == pytest.approx(diffs[f"f {cam}"].half * f_px)
    assert u.cameras[cam].f_px > 10 * s.f_px
    # What the halves agree on keeps its sigma.
    untouched = solved.cameras[4].id
    assert u.cameras[untouched] == solved.report.uncertainty.cameras[untouched]
    assert u.scale_rel == solved.report.uncertainty.scale_rel


def test_halves_that_differ_by_more_than_their_sigmas_all_over_multiply_every_sigma(solved):
    """Differences of twice their sigmas on every camera: no one parameter disagrees, the sigmas as a whole do."""
    u = solved.report.uncertainty
    other = solved
    for cam in solved.cameras[2:]:
        s = u.cameras[cam.id]
        other = turned(other, cam.id, f_rel=2 * 2 * np.hypot(s.f_px, s.f_px) / 2 / cam.K[0, 0],
                       rotation_deg=2 * 2 * np.hypot(*(2 * [np.linalg.norm(s.rotation_deg)])) / 2)
    diffs = differences(solved, other)

    wide, named, factor = widened(u, solved, diffs)

    assert named == () and factor > INFLATE_FROM
    for cam in solved.cameras:
        assert wide.cameras[cam.id].f_px == pytest.approx(factor * u.cameras[cam.id].f_px)
    assert wide.scale_rel.value == pytest.approx(factor * u.scale_rel.value)


def test_a_rotation_sigma_is_raised_on_every_axis_alike():
    s = CameraSigmas(1.0, 0.0, 0.0, 0.0, 0.0, (0.01, 0.02, 0.02), (0.001, 0.001, 0.001))
    from camnet.solve.report.halves import _axes_at_least

    axes = _axes_at_least(s.rotation_deg, 0.3)

    assert np.linalg.norm(axes) == pytest.approx(0.3)
    assert axes[1] / axes[0] == pytest.approx(2.0)
    assert _axes_at_least(s.rotation_deg, 0.001) == s.rotation_deg


def test_a_rig_whose_halves_agree_keeps_its_verdict_and_its_sigmas_cover_the_truth(rig_and_obs, solved):
    rig, obs = rig_and_obs
    plain = calibrate(obs, Options(halves=False)).calibration
    halves = solved.report.halves

    assert halves is not None and halves.splits == 1, halves
    assert not halves.widened, halves
    assert judge(solved).level == judge(plain).level == Level.GOOD
    # The halves agree within their sigmas: the curvature's sigmas stand.
    assert solved.report.uncertainty.cameras == plain.report.uncertainty.cameras
    assert max(halves.in_sigmas.values()) <= DISAGREE_SIGMAS
    truth = {c.id: c for c in rig.cameras}
    error = scale_error(np.array([c.centre for c in solved.cameras]), np.array([truth[c.id].centre
                                                                                 for c in solved.cameras]))
    assert abs(error) <= 3 * solved.report.uncertainty.scale_rel.value


def test_the_halves_are_split_across_the_cloud_and_keep_every_camera(rig_and_obs, solved):
    _, obs = rig_and_obs
    name, side = next(iter(track_sides(obs, solved)))

    assert name == "across the widest axis"
    kept = np.isin(obs.track_ids, solved.point_ids)
    assert np.all(side[~kept] == -1) and abs(np.sum(side == 0) - np.sum(side == 1)) <= 1
    for h in (0, 1):
        counts = np.bincount(obs.cam_index[side[obs.track_index] == h], minlength=len(obs.cameras))
        assert counts.min() >= MIN_HALF_OBSERVATIONS


def test_a_scene_too_small_to_split_says_it_has_no_second_opinion():
    obs = observe(make_rig(n_cameras=4, n_points=50, seed=2), noise_px=0.3, seed=2).observations

    cal = calibrate(obs).calibration

    assert cal.report.halves.splits == 0
    assert "no split keeps every camera's view in both halves" in cal.report.halves.reason
    verdict = judge(cal)
    assert verdict.level == Level.POOR
    assert [f.level for f in verdict.findings if f.what.startswith("no second opinion")] == [Level.POOR]


def test_a_camera_seen_in_few_tracks_of_a_long_pool_keeps_its_second_opinion():
    # A live check thins each half of a long pool; the camera the others outnumber keeps its views first.
    obs = observe(make_rig(n_cameras=5, n_points=4000, seed=3), noise_px=0.3, seed=3).observations
    rare = obs.index_of(obs.camera_ids[4])
    drop = (obs.cam_index == rare) & (obs.track_index % 16 != 0)
    obs = replace(obs, cam_index=obs.cam_index[~drop], track_index=obs.track_index[~drop], uv=obs.uv[~drop])
    seen = int(np.sum(obs.cam_index == rare))
    assert 4 * MIN_HALF_OBSERVATIONS < seen < 10 * MIN_HALF_OBSERVATIONS, seen  # every 7th track would thin it short
    cal = calibrate(obs, Options(halves=False)).calibration

    checked = with_halves_check(obs, cal, lambda half: calibrate(half, Options(halves=False)).calibration,
                                truncation_px=Options().truncation_px(cal.rms_reprojection_px), max_half_tracks=300)

    assert checked.report.halves.splits == 1, checked.report.halves.reason
    assert f"f {obs.camera_ids[4]}" in checked.report.halves.in_sigmas


def test_the_check_is_written_and_read_back(solved):
    wide = replace(solved.report.halves, widened=("scale",), in_sigmas={**solved.report.halves.in_sigmas,
                                                                         "scale": np.inf})
    cal = replace(solved, report=replace(solved.report, halves=wide))

    back = parse_calibration(calibration_to_doc(cal))

    assert back.report.halves == wide
    old = calibration_to_doc(cal)
    del old["diagnostics"]["halves"]
    assert parse_calibration(old).report.halves is None


@pytest.mark.parametrize("interval_s", [0.0, 1e9])
def test_the_live_calibrator_asks_again_once_half_its_pool_is_new_and_carries_the_last_answer_between(interval_s):
    # Asked again once half the pool is new and the interval is up (live, a minute apart at least), or where the
    # pool has doubled however recent the last check (1e9: never for the time alone).
    rig = make_rig(n_points=300, seed=1)
    first = observe(rig, seed=1).observations
    tracker = Tracker(LiveConfig(halves_interval_s=interval_s))

    asked = tracker.update(first).calibration.report.halves
    # A third of the pool new: the last answer is carried, not asked again.
    third = pooled(first, observe(replace(rig, points=rig.points[:150] + 0.002), seed=2).observations)
    carried = tracker.update(third).calibration.report.halves
    # As many new tracks again as the pool held: half of it new, the pool doubled: asked afresh.
    twice = pooled(first, observe(replace(rig, points=rig.points + 0.003), seed=3).observations)
    again = tracker.update(twice).calibration.report.halves

    assert asked.splits == 1
    assert carried.half_differences == asked.half_differences and carried.in_sigmas == asked.in_sigmas
    assert again.splits == 1 and again.half_differences != asked.half_differences


def _split_solved(obs, whole):
    """The first split's halves, each with its solution alone."""
    _, side = next(iter(track_sides(obs, whole)))
    halves = []
    for h in (0, 1):
        keep = side == h
        rows = keep[obs.track_index]
        part = replace(obs, cam_index=obs.cam_index[rows], track_index=obs.track_index[rows], uv=obs.uv[rows])
        halves.append((part, calibrate(part, Options(halves=False)).calibration))
    return halves


def test_a_half_whose_cold_solve_fell_short_of_its_own_minimum_is_ruled_out_and_the_next_split_compared(
        rig_and_obs):
    _, obs = rig_and_obs
    whole = calibrate(obs, Options(halves=False)).calibration
    truncation = Options().truncation_px(whole.rms_reprojection_px)
    (part_a, a), (part_b, b) = _split_solved(obs, whole)
    cam = whole.cameras[3].id
    lost = turned(b, cam, f_rel=0.15, rotation_deg=3.0)  # where a half's cold solve may stop

    assert unsolved_half(whole, ((part_a, a), (part_b, b)), truncation) == ""  # both solved
    said = unsolved_half(whole, ((part_a, a), (part_b, lost)), truncation)
    assert said.startswith("the whole's solution fits half 2 better than that half's own, by"), said
    # The same through the check: the first split's second half is lost, the next split is compared instead.
    solves = iter([a, lost])
    checked = with_halves_check(obs, whole, lambda half: next(solves, None) or calibrate(
        half, Options(halves=False)).calibration, truncation_px=truncation)
    halves = checked.report.halves
    assert halves.ruled_out == ("across the widest axis",) and halves.splits == 1, halves
    assert not halves.widened and halves.sigma_factor == 1.0, halves
    assert f"f {cam}" in halves.in_sigmas and halves.in_sigmas[f"f {cam}"] < DISAGREE_SIGMAS
    assert parse_calibration(calibration_to_doc(checked)).report.halves == halves
    # Every split's halves lost: no second opinion, and why.
    calls = iter(range(6))

    def second_lost(half):
        solved = calibrate(half, Options(halves=False)).calibration
        return turned(solved, cam, f_rel=0.15) if next(calls) % 2 else solved

    lost_every = with_halves_check(obs, whole, second_lost, truncation_px=truncation)
    assert lost_every.report.halves.splits == 0 and len(lost_every.report.halves.ruled_out) == 3
    assert "its cold solve fell short of its own minimum" in lost_every.report.halves.reason
    assert judge(lost_every).level == Level.POOR


def test_a_half_stopped_along_a_valley_is_compared_at_its_better_solution_from_the_whole(rig_and_obs):
    # A weak half's cold solve can stop where its cost has barely risen, several of its sigmas from a solution as
    # good: its focal length held 8% off and the rest solved to it, as such a stop would be.
    _, obs = rig_and_obs
    whole = calibrate(obs, Options(halves=False)).calibration
    truncation = Options().truncation_px(whole.rms_reprojection_px)
    (part_a, a), (part_b, b) = _split_solved(obs, whole)
    cam = whole.cameras[3].id
    held_f = Options(halves=False, free=frozenset({"stereo_rotation", "stereo_direction"}))
    stopped = calibrate(part_b, held_f, initial=turned(b, cam, f_rel=0.08)).calibration
    assert unsolved_half(whole, ((part_a, a), (part_b, stopped)), truncation) == ""  # within a cost's noise

    def checked(polish):
        solves = iter([a, stopped])
        return with_halves_check(obs, whole, lambda half: next(solves, None) or calibrate(
            half, Options(halves=False)).calibration, truncation_px=truncation, polish=polish).report.halves

    alone = checked(None)
    assert alone.splits == 1 and f"f {cam}" in alone.widened, alone
    from_whole = checked(lambda half, start: solved_from(half, Options(halves=False), start))
    assert from_whole.from_whole == ("half 2 across the widest axis",), from_whole
    assert not from_whole.widened and from_whole.sigma_factor == 1.0, from_whole
    assert from_whole.in_sigmas[f"f {cam}"] < DISAGREE_SIGMAS
    assert parse_calibration(calibration_to_doc(replace(whole, report=replace(
        whole.report, halves=from_whole)))).report.halves == from_whole
    # A solution from the whole's start that fits a half worse than its cold one leaves the disagreement.
    worse = checked(lambda half, start: turned(start, cam, f_rel=0.15))
    assert worse.from_whole == () and f"f {cam}" in worse.widened, worse


def test_halves_that_fit_themselves_better_than_the_whole_are_never_ruled_out(rig_and_obs):
    # However far the whole lies from them: then the model does not fit the scene alike, or the whole is wrong.
    _, obs = rig_and_obs
    whole = calibrate(obs, Options(halves=False)).calibration
    truncation = Options().truncation_px(whole.rms_reprojection_px)
    halves = tuple(_split_solved(obs, whole))
    cam = whole.cameras[3].id

    assert unsolved_half(turned(whole, cam, f_rel=0.15, rotation_deg=3.0), halves, truncation) == ""
