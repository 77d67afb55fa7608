"""The calibration engine on seeded simulated rigs with known ground truth."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.errors import SolveError
from camnet.model.accuracy import compare, rotation_angle_deg
from camnet.model.projection import project_with_jacobians, rotation_exp
from camnet.sim.bounds import cramer_rao, truth_state
from camnet.sim.simulate import make_rig, move_camera, observe
from camnet.solve import Options, calibrate
from camnet.solve.uncertainty import covariance, scale_sigma


def assert_exact(result, rig, rel=1e-6):
    cal = result.calibration
    truth = {c.id: c for c in rig.cameras}
    for cam in cal.cameras:
        t = truth[cam.id]
        np.testing.assert_allclose(cam.K, t.K, rtol=rel, atol=rel * t.K[0, 0])
        np.testing.assert_allclose(cam.dist, t.dist, atol=rel)
        np.testing.assert_allclose(cam.R, t.R, atol=rel)
        np.testing.assert_allclose(cam.centre, t.centre, atol=rel * 0.1)
    np.testing.assert_allclose(cal.points, rig.points[cal.point_ids], atol=rel)


def test_projection_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    n = 5
    intr = np.tile([1200.0, 1.01, 640.0, 500.0, -0.2, 0.05, 0.001, -0.002, 0.01], (n, 1))
    R = rotation_exp(rng.normal(scale=0.2, size=(n, 3)))
    C = rng.normal(scale=0.1, size=(n, 3))
    X = rng.normal(scale=0.1, size=(n, 3)) + [0, 0, 1.0]
    uv, J_intr, J_rot, J_cen, J_pt = project_with_jacobians(intr, R, C, X)
    h = 1e-6

    def uv_of(intr=intr, R=R, C=C, X=X):
        return project_with_jacobians(intr, R, C, X)[0]

    for k in range(9):
        d = np.zeros(9)
        d[k] = h * max(1.0, abs(intr[0, k]))
        np.testing.assert_allclose((uv_of(intr=intr + d) - uv) / d[k], J_intr[:, :, k], rtol=1e-4, atol=1e-3)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        np.testing.assert_allclose((uv_of(R=rotation_exp(e) @ R) - uv) / h, J_rot[:, :, k], rtol=1e-4, atol=1e-2)
        np.testing.assert_allclose((uv_of(C=C + e) - uv) / h, J_cen[:, :, k], rtol=1e-4, atol=1e-2)
        np.testing.assert_allclose((uv_of(X=X + e) - uv) / h, J_pt[:, :, k], rtol=1e-4, atol=1e-2)


@pytest.mark.parametrize("method", ["paper", "refined", "unconstrained"])
def test_zero_noise_paper_rig_is_recovered_exactly(method):
    rig = make_rig(seed=1)
    result = calibrate(observe(rig, noise_px=0.0, seed=1).observations, Options(method=method))
    assert_exact(result, rig)


@pytest.mark.parametrize(
    "rig_args, free",
    [
        (dict(n_cameras=8, n_points=200, pp_offset_px=25.0), {"f", "pp"}),
        (dict(n_cameras=6, n_points=150, k1=-0.15, k2=0.05), {"f", "k1", "k2"}),
        (dict(n_cameras=5, n_points=150, stereo_rotation_deg=0.4), {"f", "stereo_rotation", "stereo_direction"}),
        (
            dict(n_cameras=6, n_points=200, pp_offset_px=25.0, k1=-0.1, stereo_rotation_deg=0.3),
            {"f", "pp", "k1", "stereo_rotation", "stereo_direction"},
        ),
    ],
    ids=["principal-points", "distortion", "rotated-stereo-pair", "all-of-them"],
)
def test_zero_noise_general_rigs_are_recovered_exactly(rig_args, free):
    rig = make_rig(seed=2, **rig_args)
    result = calibrate(observe(rig, noise_px=0.0, seed=2).observations, Options(free=frozenset(free)))
    assert_exact(result, rig)


def test_errors_lie_within_the_reported_uncertainty():
    """Over seeded trials, |error| <= 3 sigma for focal lengths, centres and scale in >= 95% of cases."""
    within, total = 0, 0
    for seed in range(12):
        rig = make_rig(n_cameras=6, n_points=150, seed=seed)
        result = calibrate(observe(rig, noise_px=0.5, seed=seed).observations, Options(free=frozenset({"f"})))
        c = compare(result.calibration, rig.cameras, rig.points)
        unc = result.calibration.uncertainty.cameras
        truth = {cam.id: cam for cam in rig.cameras}
        for cam in result.calibration.cameras:
            u = unc[cam.id]
            checks = [(cam.K[0, 0] - truth[cam.id].K[0, 0], u.f_px)]
            checks += list(zip(cam.centre - truth[cam.id].centre, u.centre_m, strict=True))
            for err, sd in checks:
                if sd > 0:
                    total += 1
                    within += abs(err) <= 3 * sd
        total += 1
        within += abs(c.scale_rel) <= 3 * c.scale_sigma_rel
    assert total > 150
    assert within / total >= 0.95, f"{within}/{total} within 3 sigma"  # a normal error: 99.7%


def test_reported_uncertainty_matches_the_cramer_rao_bound():
    rig = make_rig(seed=4)
    # The bound is conditional on the principal points at the centre and the pair exactly parallel, as the
    # solve's held ones are (at its default tolerance the pair's held rotation puts the sigma at 10x the bound).
    options = Options(free=frozenset({"f"}), pp_prior_rel=0, pair_tolerance_deg=0)
    result = calibrate(observe(rig, noise_px=0.5, seed=4).observations, options)
    crb = scale_sigma(covariance(result.problem, truth_state(rig, result), sigma_px=0.5), rig.points)
    reported = result.calibration.uncertainty.scale_rel.value
    assert 0.5 < reported / crb < 2.0


def test_the_focal_bound_matches_the_curvatures_sigma_camera_by_camera():
    rig = make_rig(seed=4)
    options = Options(free=frozenset({"f"}), pp_prior_rel=0, pair_tolerance_deg=0, halves=False)
    result = calibrate(observe(rig, noise_px=0.5, seed=4).observations, options)

    bound = cramer_rao(rig, result, 0.5).focal_rel

    for cam in result.calibration.cameras:
        reported = result.calibration.uncertainty.cameras[cam.id].f_px / cam.K[0, 0]
        assert 0.5 < reported / bound[cam.id] < 2.0, (cam.id, reported, bound[cam.id])


def test_outliers_are_rejected_and_do_not_bias_the_solution():
    for seed in range(4):
        rig = make_rig(seed=seed)
        sim = observe(rig, noise_px=0.5, seed=seed, outlier_fraction=0.15)
        result = calibrate(sim.observations)
        c = compare(result.calibration, rig.cameras, rig.points)
        assert abs(c.scale_rel) < 4 * c.scale_sigma_rel + 1e-4
        assert c.rms_reprojection_px < 1.0
        # Every gross outlier (farther than 5 px from the truth) is gone.
        kept = {(int(ci), int(ti)) for ci, ti in zip(result.problem.cam, result.problem.pt, strict=True)}
        obs = sim.observations
        m_of = {i: m for m, i in enumerate(result.order)}
        pt_of = {int(t): j for j, t in enumerate(obs.track_ids[result.track_rows])}
        for k in np.flatnonzero(sim.outlier_obs):
            cam = rig.cameras[obs.cam_index[k]]
            true_px = cam.project(rig.points[obs.track_index[k]][None])[0]
            tid = int(obs.track_ids[obs.track_index[k]])
            if np.linalg.norm(obs.uv[k] - true_px) > 5.0 and tid in pt_of:
                assert (m_of[obs.cam_index[k]], pt_of[tid]) not in kept


def test_partial_visibility_and_larger_networks():
    for n_cameras in (8, 16):
        rig = make_rig(n_cameras=n_cameras, n_points=300, seed=5)
        result = calibrate(observe(rig, noise_px=0.5, seed=5, visibility=0.6).observations)
        c = compare(result.calibration, rig.cameras, rig.points)
        assert abs(c.scale_rel) < 4 * c.scale_sigma_rel
        for e in c.cameras:
            assert abs(e.focal_rel) <= 4 * e.focal_sigma_rel + 1e-9
            assert e.centre_mm <= 4 * e.centre_sigma_mm + 1e-6


def test_unconstrained_adjustment_drifts_in_scale_where_the_constrained_does_not():
    refined, unconstrained = [], []
    for seed in range(8):
        rig = make_rig(seed=seed)
        obs = observe(rig, noise_px=0.5, seed=seed).observations
        for method, out in (("refined", refined), ("unconstrained", unconstrained)):
            cal = calibrate(obs, Options(method=method, free=frozenset({"f"}))).calibration
            out.append(abs(compare(cal, rig.cameras, rig.points).scale_rel))
    assert np.median(unconstrained) > 5 * np.median(refined)


def test_warm_start_after_new_tracks_converges_to_the_same_solution():
    rig = make_rig(n_cameras=6, n_points=400, seed=6)
    obs = observe(rig, noise_px=0.5, seed=6).observations
    first = obs.track_index < 380
    part = replace(
        obs,
        cam_index=obs.cam_index[first],
        track_index=obs.track_index[first],
        uv=obs.uv[first],
        track_ids=obs.track_ids[:380],
    )
    previous = calibrate(part).calibration
    cold = calibrate(obs).calibration
    warm = calibrate(obs, initial=previous).calibration
    for a, b in zip(cold.cameras, warm.cameras, strict=True):
        sd = cold.uncertainty.cameras[a.id]
        # A few hundredths of a sigma apart: the inlier sets differ by an observation or so.
        assert abs(a.K[0, 0] - b.K[0, 0]) < 0.1 * sd.f_px + 1e-6
        assert np.linalg.norm(a.centre - b.centre) < 0.1 * np.linalg.norm(sd.centre_m) + 1e-9
    assert warm.report.start == "warm"


@pytest.fixture(scope="module")
def bumped():
    """A solved rig, then the same rig with mono_02 moved 5 cm and turned 3 degrees, observed again."""
    rig = make_rig(n_cameras=6, n_points=300, seed=8)
    previous = calibrate(observe(rig, noise_px=0.5, seed=8).observations).calibration
    rig_now = move_camera(rig, "mono_02", shift_m=0.05, angle_deg=3.0, seed=8)
    return previous, rig_now, observe(rig_now, noise_px=0.5, seed=9).observations


def test_reset_camera_is_placed_again_within_its_uncertainty(bumped):
    previous, rig_now, obs = bumped
    plain = calibrate(obs, initial=previous)
    reset = calibrate(obs, initial=previous, reset_cameras={"mono_02"})
    cold = calibrate(obs)
    # Without the reset the warm start does not fit the moved camera and falls back to the robust passes.
    assert plain.calibration.report.start == "warm, robust"
    assert reset.calibration.report.start == "warm"
    truth = {c.id: c for c in rig_now.cameras}
    for result in (reset, cold):
        cam = {c.id: c for c in result.calibration.cameras}["mono_02"]
        sd = result.calibration.uncertainty.cameras["mono_02"]
        assert np.linalg.norm(cam.centre - truth["mono_02"].centre) < 3 * np.linalg.norm(sd.centre_m)
        assert rotation_angle_deg(cam.R @ truth["mono_02"].R.T) < 3 * np.linalg.norm(sd.rotation_deg)
    # The reset solve is the cold solve to a fraction of its uncertainty (about a tenth of a sigma:
    # the two keep a few different observations at the outlier threshold).
    for a, b in zip(cold.calibration.cameras, reset.calibration.cameras, strict=True):
        sd = cold.calibration.uncertainty.cameras[a.id]
        assert abs(a.K[0, 0] - b.K[0, 0]) < 0.3 * sd.f_px + 1e-9
        assert np.linalg.norm(a.centre - b.centre) < 0.3 * np.linalg.norm(sd.centre_m) + 1e-12


def test_resetting_a_stereo_camera_solves_from_scratch(bumped):
    previous, _, obs = bumped
    cold = calibrate(obs).calibration
    reset = calibrate(obs, initial=previous, reset_cameras=["left"]).calibration
    assert reset.report.start == "cold"
    np.testing.assert_allclose(reset.points, cold.points)


def test_reset_of_an_unknown_camera_is_refused(bumped):
    previous, _, obs = bumped
    with pytest.raises(SolveError, match="reset_cameras: unknown camera"):
        calibrate(obs, initial=previous, reset_cameras={"nope"})


def test_a_held_stereo_column_difference_is_warned_about_unless_k_is_given():
    """Said as a note where the reported scale sigma already counts the guessed principal points."""
    rig = make_rig(seed=3)
    sim = observe(rig, noise_px=0.5, seed=3, with_intrinsics=True)
    plain = observe(rig, noise_px=0.5, seed=3).observations
    report = calibrate(plain).calibration.report
    warned = report.warnings + report.notes
    # 0.125 m baseline, f = 1500 px, 0.65 m away: a disparity of about 290 px, 0.35% per pixel.
    assert any("principal points in the same column" in w and "0.3" in w for w in warned)
    given = replace(
        sim.observations,
        cameras=tuple(replace(c, fixed=frozenset({"K", "dist"})) for c in sim.observations.cameras),
    )
    quiet = calibrate(given).calibration.report
    quiet = quiet.warnings + quiet.notes
    assert not any("principal points in the same column" in w for w in quiet)
