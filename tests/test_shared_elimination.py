"""The points eliminated once at a solve's final state: its convergence test and the covariance share them."""

from dataclasses import replace

import numpy as np

from camnet.model.calibration import StartKind
from camnet.sim.simulate import make_rig, observe
from camnet.solve import Options, bundle, calibrate, schur, uncertainty
from camnet.solve.uncertainty import covariance


def _solved(seed: int):
    """A solved network, the problem with its principal points freed (wider), and a start off the solution."""
    rig = make_rig(n_cameras=5, n_points=80, seed=seed)
    result = calibrate(observe(rig, noise_px=0.5, seed=seed).observations, Options(free=frozenset({"f"})))
    problem, state = result.problem, result.state
    intr_free = problem.intr_free.copy()
    intr_free[:, 2:4] = True
    nudged = state.intr.copy()
    nudged[2:, 0] *= 1.01
    return problem, replace(problem, intr_free=intr_free), state, replace(state, intr=nudged)


def test_the_shared_elimination_gives_the_covariance_and_the_convergence_test_of_their_own():
    problem, wider, state, nudged = _solved(4)
    within = bundle.columns_within(problem, wider)
    for start in (state, nudged):  # converged already (no step), then steps to take
        solved, info = bundle.solve(problem, start, report=wider)
        if info.eliminated is None:  # no step was taken: nothing was eliminated, the covariance does it
            assert start is state
            continue
        direct = schur.eliminate_points(info.normal)
        for name in ("V_inv", "WVW"):
            np.testing.assert_array_equal(getattr(info.eliminated, name), getattr(direct, name))
        shared = covariance(wider, solved, normal=info.normal, eliminated=info.eliminated)
        own = covariance(wider, solved, normal=info.normal)
        np.testing.assert_array_equal(shared.S_inv, own.S_inv)  # bit for bit: the same products
        np.testing.assert_array_equal(shared.point_covariances_m2, own.point_covariances_m2)
        # The convergence test from the wider elimination promises what the solve's own Schur step does.
        narrow = schur.restrict(info.normal, within)
        # (Their steps part along nearly flat directions, which the points' damping moves: not compared.)
        _, promised, small = schur.gauss_newton_test(narrow, 1e-6, eliminated=info.eliminated, within=within)
        _, own_promised, own_small = schur.gauss_newton_test(narrow, 1e-6)
        assert small == own_small and info.converged
        np.testing.assert_allclose(promised, own_promised, rtol=1e-6, atol=1e-12 * narrow.cost)


def test_a_warm_re_solve_reduces_its_cameras_once_per_step_and_once_at_the_end(monkeypatch):
    """One Schur step per Levenberg-Marquardt step; the convergence test at the final state and the covariance
    take the one elimination of the points."""
    rig = make_rig(n_cameras=6, n_points=200, seed=2)
    obs = observe(rig, noise_px=0.5, seed=2, visibility=0.6).observations
    n_old = int(0.95 * 200)
    first = obs.track_index < n_old
    old = replace(obs, cam_index=obs.cam_index[first], track_index=obs.track_index[first], uv=obs.uv[first],
                  track_ids=obs.track_ids[:n_old])
    previous = calibrate(old).calibration
    counts = {"schur steps": 0, "eliminations": 0}

    def counting(name, real, cameras_only=False):
        def spy(ne, *args, **kwargs):
            if not cameras_only or len(ne.U):  # the new tracks' fit holds every camera: no camera matrix
                counts[name] += 1
            return real(ne, *args, **kwargs)
        return spy

    steps = counting("schur steps", schur.solve_damped, cameras_only=True)
    monkeypatch.setattr(schur, "solve_damped", steps)
    monkeypatch.setattr(bundle, "solve_damped", steps)
    real = getattr(schur, "eliminate_points", None)
    if real is not None:  # (the version before the shared elimination had none)
        eliminations = counting("eliminations", real)
        for module in (schur, bundle, uncertainty):
            monkeypatch.setattr(module, "eliminate_points", eliminations)
    result = calibrate(obs, Options(halves=False), initial=previous)  # the solve's steps, not its second opinion's
    report = result.calibration.report
    assert report.start == StartKind.WARM and result.covariance is not None
    # Every step taken (near the solution, none is refused): one Schur step each, then one elimination each
    # for its convergence test, the last of which the covariance takes; not two Schur steps per step (the
    # second the convergence test's) nor an elimination of the covariance's own.
    assert counts == {"schur steps": report.iterations, "eliminations": report.iterations}
