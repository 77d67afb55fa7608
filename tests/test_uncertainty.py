"""The reported uncertainty: weak directions kept, undetermined points left out, the scale's weights."""

from dataclasses import replace

import numpy as np
import scipy.linalg

from camnet.model.accuracy import compare
from camnet.model.calibration import PointsLeftOut
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, calibrate, schur
from camnet.solve.bundle import CEN, CentreMode
from camnet.solve.report.assemble import reported_points
from camnet.solve.schur import POINT_RCOND, point_inverses, points_determined
from camnet.solve.uncertainty import covariance, inverse_spd, residual_dof, scale_sigma, scale_weights


def test_inverse_keeps_the_weak_directions_of_a_badly_scaled_matrix():
    rng = np.random.default_rng(0)
    Q, _ = np.linalg.qr(rng.normal(size=(12, 12)))
    A = Q @ np.diag(np.logspace(-8, 0, 12)) @ Q.T  # a flat valley, 1e8 conditioned
    D = np.diag(np.logspace(-5, 5, 12))  # pixels, radians and metres side by side
    S = D @ A @ D
    # inv(S) = inv(D) inv(A) inv(D): compare in A's units, where the valley is 1e8 deep.
    inverse, null, _ = inverse_spd(S)
    np.testing.assert_allclose(D @ inverse @ D, np.linalg.inv(A), rtol=1e-6, atol=1e-6)
    assert null.shape == (12, 0)
    # A pseudo-inverse cut off relative to the largest eigenvalue loses the valley.
    assert not np.allclose(D @ scipy.linalg.pinvh(S) @ D, np.linalg.inv(A), rtol=1e-2)


def test_a_direction_nothing_fixes_is_named_and_the_rest_keeps_its_inverse():
    rng = np.random.default_rng(1)
    B = rng.normal(size=(6, 6))
    A = np.zeros((8, 8))
    A[:6, :6] = B @ B.T + np.eye(6)  # determined
    A[6:, 6:] = [[1.0, 1.0], [1.0, 1.0]]  # the last two trade off exactly: only their sum is fixed
    inverse, null, unit = inverse_spd(A)
    np.testing.assert_allclose(inverse[:6, :6], np.linalg.inv(A[:6, :6]), rtol=1e-9)
    assert null.shape == (8, 1)
    direction = null[:, 0] / unit
    assert np.allclose(direction[:6], 0.0) and np.isclose(direction[6], -direction[7])


def test_freeing_the_principal_points_widens_the_focal_sigma():
    """On a shallow scene the focal length slides against the principal points: the sigma must say so."""
    rig = make_rig(seed=2, depth_range_m=(0.6, 0.65), n_points=200)
    obs = observe(rig, noise_px=0.5, seed=2).observations
    sigmas, errors = {}, {}
    for name, free in (("f", {"f"}), ("f,pp", {"f", "pp"})):
        cal = calibrate(obs, Options(free=frozenset(free), pp_prior_rel=0)).calibration
        unc = cal.uncertainty.cameras
        truth = {c.id: c.K[0, 0] for c in rig.cameras}
        sigmas[name] = np.array([unc[c.id].f_px for c in cal.cameras])
        errors[name] = np.array([c.K[0, 0] - truth[c.id] for c in cal.cameras])
    assert np.all(sigmas["f,pp"] > 2 * sigmas["f"]), sigmas
    assert np.all(np.abs(errors["f,pp"]) < 4 * sigmas["f,pp"]), (errors, sigmas)


def test_guessed_principal_points_count_in_the_reported_scale_sigma():
    """Principal points 10 px off centre that the data cannot tell: the sigma must cover what holding them costs."""
    covered = {0.01: 0, 0.0: 0}
    for seed in range(6):
        rig = make_rig(n_cameras=6, n_points=150, seed=seed, pp_offset_px=10.0)
        obs = observe(rig, noise_px=0.5, seed=seed).observations
        for prior in covered:
            # The pair held exactly parallel: its tolerance (tests/test_held_pair.py) would cover some of what a
            # column offset costs, and this is about the principal points' prior; so is the curvature's sigma, not
            # the halves' (which see some of the offset too).
            cal = calibrate(obs, Options(pp_prior_rel=prior, pair_tolerance_deg=0, halves=False)).calibration
            c = compare(cal, rig.cameras, rig.points)
            covered[prior] += abs(c.scale_rel) <= 3 * c.scale_sigma_rel
    # With the 1% prior most seeds are covered, with sigmas conditional on the centre almost none
    # (docs/benchmarks.md, "The engine").
    assert covered[0.01] >= 5 and covered[0.0] <= 1, covered


def test_points_behind_a_camera_or_without_parallax_are_left_out():
    rig = make_rig(seed=1, n_points=80)
    result = calibrate(observe(rig, noise_px=0.5, seed=1).observations, Options(free=frozenset({"f"})))
    problem, state = result.problem, result.state
    kept, dropped = reported_points(problem, state, covariance(problem, state))
    assert kept.all() and dropped == PointsLeftOut()
    X = state.X.copy()
    X[0] = -X[0]  # behind the left camera
    X[1] = state.C[0] + 1e7 * (X[1] - state.C[0])  # far along its ray: no parallax left
    moved = replace(state, X=X)
    kept, dropped = reported_points(problem, moved, covariance(problem, moved, sigma_px=0.5))
    assert not kept[0] and not kept[1] and kept[2:].all()
    assert dropped == PointsLeftOut(fewer_than_two_views=0, behind_a_camera=1, undetermined=1)


def test_far_points_do_not_swamp_the_scale():
    rig = make_rig(seed=3, n_points=80)
    result = calibrate(observe(rig, noise_px=0.5, seed=3).observations, Options(free=frozenset({"f"})))
    problem, state = result.problem, result.state
    body = scale_sigma(covariance(problem, state, sigma_px=0.5), state.X)
    X = state.X.copy()
    X[:3] = state.C[0] + 30.0 * (X[:3] - state.C[0])  # three points 20 m away, with little parallax
    far = replace(state, X=X)
    cov = covariance(problem, far, sigma_px=0.5)
    w = scale_weights(cov, X)
    assert np.all(w[:3] < 1e-3) and np.all(w[3:] > 0.1)
    assert scale_sigma(cov, X) < 1.5 * body
    # With equal weights the three far points' lever arm takes the scale over.
    assert scale_sigma(cov, X, np.ones(len(X))) > 3 * body


def test_a_point_seen_once_uses_two_degrees_of_freedom():
    rig = make_rig(seed=4)
    result = calibrate(observe(rig, noise_px=0.5, seed=4).observations, Options(free=frozenset({"f"})))
    problem = result.problem
    before = residual_dof(problem)
    first = np.flatnonzero(problem.pt == 0)
    keep = np.ones(len(problem.cam), dtype=bool)
    keep[first[1:]] = False  # point 0 keeps one view
    # Its lost views took 2 coordinates each; it now fixes 2 unknowns instead of 3.
    assert residual_dof(problem.subset(keep)) == before - 2 * (len(first) - 1) + 1


def test_the_scale_given_exact_principal_points_is_the_conditional_sigma():
    obs = observe(make_rig(seed=6, n_points=120), noise_px=0.5, seed=6).observations
    # Principal points guessed: a prior on them in the covariance; the pair held exactly (no tolerance), so
    # that with them exact the sigma is the conditional one.
    result = calibrate(obs, Options(pair_tolerance_deg=0))
    wide, problem, X = result.covariance, result.problem, result.state.X
    prior_columns = wide.columns[:, 2:4][~problem.intr_free[:, 2:4]]
    assert len(prior_columns) == 8
    held = covariance(problem, result.state, sigma_px=wide.sigma_px)
    w = scale_weights(wide, X)
    given = scale_sigma(wide, X, w, given=prior_columns)
    assert scale_sigma(wide, X, w) > 3 * given
    assert np.isclose(given, scale_sigma(held, X, w), rtol=1e-6)
    unc = result.calibration.uncertainty
    assert unc.scale_rel_if_pp_exact.value < unc.scale_rel.value / 3


def test_a_solve_reports_the_normal_equations_of_a_wider_problem():
    """The covariance over held principal points comes with the solve's last step: it must be exact."""
    from camnet.solve import bundle

    rig = make_rig(n_cameras=5, n_points=80, seed=4)
    obs = observe(rig, noise_px=0.5, seed=4).observations
    result = calibrate(obs, Options(free=frozenset({"f"}), pp_prior_rel=0))
    problem, state = result.problem, result.state
    intr_free = problem.intr_free.copy()
    intr_free[:, 2:4] = True  # the principal points, held in the solve
    wider = replace(problem, intr_free=intr_free)
    nudged = state.intr.copy()
    nudged[2:, 0] *= 1.01
    for start in (state, replace(state, intr=nudged)):  # converged already, then steps to take
        solved, info = bundle.solve(problem, start, report=wider)
        direct = bundle.normal_equations(wider, solved)
        assert info.normal.U.shape == direct.U.shape != bundle.normal_equations(problem, solved).U.shape
        for name in ("U", "W", "V", "gc", "gp"):
            np.testing.assert_allclose(getattr(info.normal, name), getattr(direct, name), rtol=1e-12, atol=1e-9)
        own = schur.restrict(info.normal, bundle.columns_within(problem, wider))
        np.testing.assert_allclose(own.U, bundle.normal_equations(problem, solved).U, rtol=1e-12)


def test_a_track_seen_twice_by_one_camera_adds_to_the_normal_equations():
    """Observations are terms of a sum: a repeated one counts twice, not once."""
    from camnet.solve import bundle

    rig = make_rig(n_cameras=4, n_points=40, seed=5)
    obs = observe(rig, noise_px=0.5, seed=5).observations
    result = calibrate(obs, Options(free=frozenset({"f"})))
    problem, state = result.problem, result.state
    row = np.zeros(len(problem.cam), dtype=bool)
    row[len(row) // 2] = True
    twice = replace(problem, cam=np.append(problem.cam, problem.cam[row]), pt=np.append(problem.pt, problem.pt[row]),
                    uv=np.vstack([problem.uv, problem.uv[row]]))
    assert problem.layout.pairs_unique and not twice.layout.pairs_unique
    parts = [bundle.normal_equations(p, state) for p in (problem, problem.subset(row), twice)]
    for name in ("U", "W", "V", "gc", "gp"):
        np.testing.assert_allclose(getattr(parts[0], name) + getattr(parts[1], name), getattr(parts[2], name),
                                   rtol=1e-10, atol=1e-6)


def test_a_free_scale_is_reported_undetermined_and_the_rest_keeps_its_sigmas():
    """With nothing holding the baseline, the scale and the centres are unknown; focal lengths are not."""
    rig = make_rig(seed=5)
    result = calibrate(observe(rig, noise_px=0.5, seed=5).observations)
    held = covariance(result.problem, result.state)
    modes = result.problem.centre_mode.copy()
    modes[1] = CentreMode.FREE
    free_scale = covariance(replace(result.problem, centre_mode=modes), result.state)
    cols = free_scale.columns
    undetermined = free_scale.undetermined
    assert undetermined[cols[1, CEN.start]] and undetermined[cols[2, CEN]].any()  # the centres move with the scale
    assert not undetermined[cols[:, 0]].any()  # every focal length is still fixed
    sd = np.sqrt(np.diag(free_scale.cameras))[cols[:, 0]]
    assert np.all(sd > 0) and np.all(sd < 10 * np.sqrt(np.diag(held.cameras))[held.columns[:, 0]])
    assert np.isinf(scale_sigma(free_scale, result.state.X)) and np.isfinite(scale_sigma(held, result.state.X))


def test_point_blocks_invert_in_closed_form_as_the_pseudo_inverse_does():
    # Point blocks as a solve meets them: well seen, seen along nearly one ray (ill conditioned
    # but determined), along one ray exactly (rank 1 or 2), and not at all.
    rng = np.random.default_rng(3)
    A = rng.normal(size=(300, 3, 4))
    V = A @ A.transpose(0, 2, 1)
    ray = rng.normal(size=(300, 3))
    V[100:150] = 1e4 * ray[100:150, :, None] * ray[100:150, None, :] + 1e-6 * np.eye(3)  # 1e10 conditioned
    V[150:200] = 1e4 * ray[150:200, :, None] * ray[150:200, None, :]  # rank 1
    side = rng.normal(size=(50, 3))
    V[200:250] = V[150:200] + side[:, :, None] * side[:, None, :]  # rank 2
    V[250:260] = 0.0
    reference = np.linalg.pinv(V, rcond=POINT_RCOND, hermitian=True)
    scale = np.maximum(np.abs(reference).max(axis=(1, 2), keepdims=True), 1e-300)
    eig = np.linalg.eigvalsh(V)
    # Two ways to invert a block agree to its condition number (over the eigenvalues kept) times the rounding.
    kept = np.where(eig > POINT_RCOND * eig[:, -1:], eig, np.inf)
    condition = np.where(np.isfinite(kept.min(axis=1)), eig[:, -1] / kept.min(axis=1), 1.0)
    tolerance = np.maximum(1e-9, 100 * condition * np.finfo(float).eps)[:, None, None]
    assert np.all(np.abs(point_inverses(V) - reference) / scale <= tolerance)
    full_rank = eig[:, 0] > POINT_RCOND * np.maximum(eig[:, -1], 1e-300)
    np.testing.assert_array_equal(points_determined(V), full_rank)
    assert full_rank[:150].all() and full_rank[260:].all() and not full_rank[150:260].any()
