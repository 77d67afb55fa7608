"""What a warm re-solve shares instead of forming again gives the numbers forming it again gives, bit for bit,
and never carries anything from one problem into another's."""

from dataclasses import replace

import numpy as np

from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, bundle, calibrate, schur
from camnet.solve.uncertainty import (
    covariance,
    scale_gradient,
    scale_sigma,
    scale_sigmas,
    scale_weights,
    with_guessed_pp,
    with_held_turns,
)


def _solved(n_cameras: int, n_points: int, seed: int):
    """A solved network's problem and state (every principal point held, as a guess)."""
    rig = make_rig(n_cameras=n_cameras, n_points=n_points, seed=seed)
    obs = observe(rig, noise_px=0.5, seed=seed, visibility=0.6).observations
    result = calibrate(obs, Options(free=frozenset({"f"})))
    return result.problem, result.state


def _assert_same_equations(a: schur.NormalEquations, b: schur.NormalEquations) -> None:
    for name in ("U", "W", "V", "gc", "gp"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.cost == b.cost


def _wider(problem: bundle.Problem) -> bundle.Problem:
    """`problem` with its guessed principal points and the pair's held turns freed, as a solve's report frees them."""
    guessed = with_guessed_pp(problem, np.ones(problem.n_cameras, dtype=bool)) or problem
    return with_held_turns(guessed) or guessed


def test_a_problem_freed_shares_its_orderings_and_builds_the_equations_a_fresh_one_builds():
    """Two networks of different shapes in a row, and a subset of one: each freed problem's normal equations are
    those of the same problem formed anew (`replace`, which shares nothing), though it sorts no observation again."""
    for n_cameras, n_points, seed in ((6, 120, 1), (4, 60, 2)):
        problem, state = _solved(n_cameras, n_points, seed)
        for own in (problem, problem.subset(np.arange(len(problem.cam)) % 7 != 0)):
            own.layout  # noqa: B018 (its orderings formed first, as a solve forms them before its report's)
            wider = _wider(own)
            fresh = replace(own, intr_free=wider.intr_free.copy(), rot_free=wider.rot_free.copy())
            _assert_same_equations(bundle.normal_equations(wider, state), bundle.normal_equations(fresh, state))
            assert wider.layout.order is own.layout.order  # shared, not sorted again: the same cameras' sequence
            np.testing.assert_array_equal(wider.layout.order, fresh.layout.order)


def test_freeing_takes_free_parameter_masks_only():
    problem, _ = _solved(4, 60, 3)
    try:
        problem.freeing(cam=problem.cam[::-1])
    except ValueError as exc:
        assert "cam" in str(exc)
    else:
        raise AssertionError("freeing changed the observations")


def test_the_equations_restricted_into_a_spare_array_are_those_restricted_afresh():
    problem, state = _solved(5, 100, 4)
    wider = _wider(problem)
    wide = bundle.normal_equations(wider, state)
    within = bundle.columns_within(problem, wider)
    spare = np.full((len(within), wide.W.shape[1]), np.nan)  # what a solve's equations before the step held
    into = schur.restrict(wide, within, out=spare)
    assert into.W is spare
    _assert_same_equations(into, schur.restrict(wide, within))


def test_solves_in_a_row_leave_each_other_s_results_as_they_were():
    """A solve with a report reuses its own equations' arrays from step to step: what it returns stays as it was
    through the next solves (of another shape, then of its own), and solving it again gives it bit for bit."""
    first, first_state = _solved(5, 100, 5)
    other, other_state = _solved(4, 70, 6)
    nudged = replace(first_state, intr=first_state.intr * np.where(np.arange(5) >= 2, 1.01, 1.0)[:, None])
    solved, info = bundle.solve(first, nudged, report=_wider(first))
    assert info.iterations >= 2 and info.normal is not None  # steps taken: the spare arrays were used
    kept = {name: getattr(info.normal, name).copy() for name in ("U", "W", "V", "gc", "gp")}
    bundle.solve(other, replace(other_state, intr=other_state.intr * 1.01), report=_wider(other))
    again, info_again = bundle.solve(first, nudged, report=_wider(first))
    for name, value in kept.items():
        np.testing.assert_array_equal(getattr(info.normal, name), value, err_msg=name)
    _assert_same_equations(info_again.normal, info.normal)
    for name in ("intr", "R", "C", "X"):
        np.testing.assert_array_equal(getattr(again, name), getattr(solved, name), err_msg=name)


def test_the_scale_sigmas_given_several_columns_at_once_are_those_given_each_alone():
    problem, state = _solved(5, 100, 7)
    wider = _wider(problem)
    cov = covariance(wider, state)
    weights = scale_weights(cov, state.X)
    cols = wider.columns()[0]
    pp, turns = cols[:, 2:4][cols[:, 2:4] >= 0], cols[1, bundle.ROT][cols[1, bundle.ROT] >= 0]
    givens = [(), pp, turns, np.concatenate([pp, turns])]
    assert all(len(g) for g in givens[1:])
    together = scale_sigmas(cov, state.X, weights, givens)
    assert together == [scale_sigma(cov, state.X, weights, given=g) for g in givens]
    g = scale_gradient(state.X, weights)
    assert cov.variances(None, g, givens) == [cov.variance(None, g, given=c) for c in givens]
    assert together[3] <= together[1] < together[0]  # each cause taken as exact lowers the sigma


def test_the_elimination_tells_which_points_are_determined_as_points_determined_does():
    """The covariance takes the points determined from the elimination's factors, not from factoring V again."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(120, 3, 4))
    V = A @ A.transpose(0, 2, 1)
    ray = rng.normal(size=(120, 3))
    V[40:60] = 1e4 * ray[40:60, :, None] * ray[40:60, None, :] + 1e-6 * np.eye(3)  # ill conditioned, determined
    V[60:80] = 1e4 * ray[60:80, :, None] * ray[60:80, None, :]  # seen along one ray
    V[80:90] = 0.0  # not seen
    ne = schur.NormalEquations(np.zeros((0, 0)), np.zeros((0, 360)), V, np.zeros(0), np.zeros((120, 3)), 0.0)
    eliminated = schur.eliminate_points(ne)
    np.testing.assert_array_equal(eliminated.determined, schur.points_determined(V))
    np.testing.assert_array_equal(eliminated.V_inv, schur.point_inverses(V))
    assert eliminated.determined[:60].all() and not eliminated.determined[60:90].any()


def test_a_warm_start_takes_each_track_s_previous_point_as_a_loop_over_the_points_would():
    """Ids repeated among the tracks or the points: the last of each, as one assignment after another leaves them."""
    from camnet.solve.start.warm import _previous_points

    rng = np.random.default_rng(11)
    for _ in range(200):
        track_ids, point_ids = rng.integers(0, 30, rng.integers(0, 40)), rng.integers(0, 30, rng.integers(0, 40))
        points = rng.normal(size=(len(point_ids), 3))
        expected = np.full((len(track_ids), 3), np.nan)
        row = {int(t): j for j, t in enumerate(track_ids)}
        for pid, p in zip(point_ids, points, strict=True):
            if int(pid) in row:
                expected[row[int(pid)]] = p
        np.testing.assert_array_equal(_previous_points(track_ids, point_ids, points), expected)
