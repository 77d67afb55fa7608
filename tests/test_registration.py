"""Any two cameras as the scale pair, every camera reached through the view graph, the rest left out by name."""

import re
from dataclasses import replace

import numpy as np
import pytest

from camnet.errors import SolveError
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.live.policy import LiveConfig, judge
from camnet.model.accuracy import compare
from camnet.model.observations import Stereo
from camnet.model.projection import look_at, rotation_exp, skew
from camnet.model.resection import resect
from camnet.model.two_view import bougnoux_focals, row_and_epipolar_errors
from camnet.sim.families import family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate
from camnet.solve.context import SolveContext
from camnet.solve.report.assemble import refuse_wrong_start
from camnet.solve.start.cold import check_solvable, cold_start, is_parallel


def family_observations(name: str, seed: int):
    drawn = family(name, seed=seed)
    return drawn.rig, observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations


@pytest.mark.parametrize("name", ["ring", "tape_pair"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ring_rigs_are_calibrated_whole_within_their_sigmas(name, seed):
    rig, obs = family_observations(name, seed)
    cal = calibrate(obs).calibration
    assert sorted(c.id for c in cal.cameras) == sorted(c.id for c in rig.cameras)
    assert not cal.report.cameras_left_out
    c = compare(cal, rig.cameras, rig.points)
    assert max(abs(e.focal_rel) for e in c.cameras) < 0.02
    assert abs(c.scale_rel) < 3 * c.scale_sigma_rel


def _isolated(obs, camera_id: str):
    """`obs` with every observation of `camera_id` on a track of its own: it shares nothing."""
    mine = obs.cam_index == obs.index_of(camera_id)
    track_index = obs.track_index.copy()
    track_index[mine] = len(obs.track_ids) + np.arange(mine.sum())
    return replace(obs, track_ids=np.arange(len(obs.track_ids) + mine.sum()), track_index=track_index)


def test_a_camera_that_shares_nothing_is_left_out_by_name_and_the_rest_solved():
    rig, obs = family_observations("ring", 1)
    cal = calibrate(_isolated(obs, "ring4")).calibration
    assert [c.id for c in cal.cameras] == [c.id for c in rig.cameras if c.id != "ring4"]
    assert list(cal.report.cameras_left_out) == ["ring4"]
    assert "shares only 0 tracks" in cal.report.cameras_left_out["ring4"]
    assert any(w.startswith("camera ring4 left out") for w in cal.warnings)
    c = compare(cal, rig.cameras, rig.points)
    assert max(abs(e.focal_rel) for e in c.cameras) < 0.02
    # The reason travels with the calibration document.
    assert parse_calibration(calibration_to_doc(cal)).report.cameras_left_out == cal.report.cameras_left_out


def test_a_start_that_left_cameras_out_and_fits_the_rest_badly_is_refused():
    # The rule on a sound solve's report: ring4 left out, 99% inliers. Seed 30 of tape_pair, started as the
    # paper's pair, leaves 3 cameras out and keeps 60% at 1.37 px, its scale far off (docs/benchmarks.md,
    # "Rigs unlike the paper's").
    _, obs = family_observations("ring", 1)
    cal = calibrate(_isolated(obs, "ring4")).calibration
    report = cal.report
    refuse_wrong_start(report, cal.rms_reprojection_px)  # left out, but the rest fit: a calibration
    refuse_wrong_start(replace(report, inliers=int(0.85 * report.observations)), 1.37)  # false matches
    torn = replace(report, inliers=int(0.6 * report.observations))
    with pytest.raises(SolveError, match=r"camera ring4 could not be placed, .* keeps only 60% .*1.37 px"):
        refuse_wrong_start(torn, 1.37)
    refuse_wrong_start(replace(torn, cameras_left_out={}), 1.37)  # every camera placed: its verdict says the rest


def _start(obs):
    return cold_start(SolveContext.of(obs), seed=0, max_tracks=150)


def test_the_paper_rig_starts_from_the_paper_solver_and_a_tape_pair_from_the_essential_matrix():
    paper = _start(observe(make_rig(seed=2), noise_px=0.5, seed=2).observations)
    assert paper.parallel and np.isfinite(paper.P0).all(axis=1).sum() > 40  # the paper's stereo cloud
    np.testing.assert_array_equal(paper.R[1], np.eye(3))  # the ideal pair
    _, obs = family_observations("tape_pair", 0)
    tape = _start(obs)
    assert not tape.parallel and not np.isfinite(tape.P0).any()
    assert np.degrees(np.arccos((np.trace(tape.R[1]) - 1) / 2)) > 30


def test_a_camera_with_a_few_false_stereo_tracks_leaves_the_papers_start_to_the_others():
    # As on the surround rig, where cameras 135 degrees from the head share 6-16 false tracks (or only
    # floor points) with it. Such a camera must neither enter eq. 13 (here: placed on its 7 random pixels,
    # at least 6 agreeing at 8 px) nor, where its DLT fails, drop the paper's start for the essential matrix's.
    obs = observe(make_rig(seed=2), noise_px=0.5, seed=2).observations
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), dtype=bool)
    seen[obs.track_index, obs.cam_index] = True
    pair_tracks = np.flatnonzero(seen[:, obs.index_of("left")] & seen[:, obs.index_of("right")])[:7]
    first = obs.cameras[0]
    stray = replace(obs, cameras=(*obs.cameras, replace(first, id="stray")),
                    cam_index=np.concatenate([obs.cam_index, np.full(7, len(obs.cameras))]),
                    track_index=np.concatenate([obs.track_index, pair_tracks]),
                    uv=np.concatenate([obs.uv, np.random.default_rng(0).uniform(0, first.height, (7, 2))]))
    start = _start(stray)
    assert start.parallel and np.isfinite(start.P0).all(axis=1).sum() > 40  # the paper's start
    assert list(start.left_out) == ["stray"]


def test_row_model_tells_a_parallel_pair_from_a_turned_one():
    def errors(obs):
        ctx = SolveContext.of(obs)
        left, right = ctx.camera_rows(0), ctx.camera_rows(1)
        both = (left >= 0) & (right >= 0)
        return row_and_epipolar_errors(ctx.xy[left[both]], ctx.xy[right[both]], threshold_px=16.0)

    assert is_parallel(*errors(observe(make_rig(seed=0, pp_offset_px=25.0), seed=0).observations))
    assert is_parallel(*errors(family_observations("ring", 0)[1]))
    assert not is_parallel(*errors(family_observations("tape_pair", 0)[1]))


def test_bougnoux_recovers_two_focal_lengths_from_an_exact_fundamental_matrix():
    R, t = rotation_exp(np.array([0.1, 0.5, 0.05])), np.array([1.0, 0.1, 0.3])
    K1, K2 = np.diag([1000.0, 1000.0, 1.0]), np.diag([1400.0, 1400.0, 1.0])
    F = np.linalg.inv(K2).T @ skew(t) @ R @ np.linalg.inv(K1)
    np.testing.assert_allclose(bougnoux_focals(F), (1000.0, 1400.0), rtol=1e-9)


def test_resection_with_unknown_focal_length_works_on_a_nearly_flat_cloud():
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), rng.normal(scale=0.005, size=200)])  # a wall
    R, t = look_at(np.array([0.8, -0.3, -2.0]), np.zeros(3))
    xc = X @ R.T + t
    xy = 1100.0 * xc[:, :2] / xc[:, 2:] + rng.normal(scale=0.5, size=(200, 2))
    xy[:20] = rng.uniform(-600, 600, (20, 2))  # mismatches
    got = resect(X, xy, f_px=None, width_px=1280, threshold_px=8.0)
    assert abs(got.f_px / 1100.0 - 1) < 0.01
    np.testing.assert_allclose(got.C, -R.T @ t, atol=0.02)
    assert not got.inliers[:20].any() and got.inliers[20:].mean() > 0.95


def test_a_pair_that_shares_too_few_tracks_is_refused_in_one_line():
    obs = observe(make_rig(seed=0), seed=0).observations
    right = obs.cam_index == obs.index_of("right")
    keep = ~right | (obs.track_index < 5)
    thin = replace(obs, cam_index=obs.cam_index[keep], track_index=obs.track_index[keep], uv=obs.uv[keep])
    with pytest.raises(SolveError, match=r"stereo pair \(left, right\) shares only 5 tracks; need at least 8"):
        check_solvable(thin)


def test_the_papers_method_refuses_a_pair_that_is_not_parallel():
    _, obs = family_observations("tape_pair", 0)
    with pytest.raises(SolveError, match="method paper: .* not parallel"):
        calibrate(obs, Options(method="paper"))


def test_a_warm_start_places_a_camera_new_to_it_through_the_graph():
    rig, obs = family_observations("ring", 1)
    without = calibrate(_isolated(obs, "ring4")).calibration
    assert "ring4" not in [c.id for c in without.cameras]
    result = calibrate(obs, initial=without)
    assert not result.calibration.report.cameras_left_out
    c = compare(result.calibration, rig.cameras, rig.points)
    assert {e.id for e in c.cameras} == {cam.id for cam in rig.cameras}
    assert max(abs(e.focal_rel) for e in c.cameras) < 0.02


def test_the_live_calibrator_keeps_the_others_and_says_why_a_camera_is_missing():
    _, obs = family_observations("ring", 1)
    cal = calibrate(_isolated(obs, "ring4")).calibration
    assert judge(cal, obs, LiveConfig(max_scale_rel=1.0)) == ""
    assert cal.report.cameras_left_out["ring4"].startswith("it shares only 0 tracks")
    unexplained = replace(cal, report=replace(cal.report, cameras_left_out={}))
    assert judge(unexplained, obs, LiveConfig(max_scale_rel=1.0)) == (
        "camera ring4 not calibrated, and the solve does not say why")


@pytest.mark.parametrize("seed", [0, 1, 11])
def test_a_scale_pair_far_apart_is_solved_within_its_sigmas_or_refused_with_a_better_pair_named(seed):
    # ring0 and ring3, 135 degrees apart, share 30-55 tracks: a weak pair to start from (the start from the pair
    # that shares the most tracks places seed 1, see tests/test_start_choice.py). Started from the scale pair,
    # seed 11 leaves ring6 out and keeps 71% of the rest's observations, its scale far off at a small sigma
    # (docs/benchmarks.md, "Rigs unlike the paper's").
    drawn = family("tape_pair", seed=seed)
    cams = {c.id: c for c in drawn.rig.cameras}
    distance_m = float(np.linalg.norm(cams["ring0"].centre - cams["ring3"].centre))
    obs = observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations
    obs = replace(obs, stereo=Stereo("ring0", "ring3", distance_m))
    try:
        cal = calibrate(obs).calibration
    except SolveError as exc:
        better = r"the stereo pair \(ring0, ring3\) shares only \d+ tracks, ring\d and ring\d share \d+: name as"
        assert re.search(better, str(exc)), str(exc)
        return
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    assert max(abs(e.focal_rel) for e in c.cameras) < 0.02
    assert abs(c.scale_rel) < 3 * c.scale_sigma_rel
