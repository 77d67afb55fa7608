"""The bundle adjustment's normal equations, formed a block of rows at a time, and the memory the
Schur steps take: the same equations as in one piece, with temporaries bounded by the block size."""

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from camnet.model.projection import N_INTRINSICS, intrinsics_from_K
from camnet.sim.simulate import make_rig, observe
from camnet.solve import bundle, schur
from camnet.solve.bundle import CentreMode, Problem, State
from camnet.solve.uncertainty import covariance

MB = 1 << 20


def _network(n_cameras: int, n_points: int, *, duplicate: bool = False) -> tuple[Problem, State]:
    """A simulated network at its truth, the left camera held, the right on its baseline, k1 free in two
    cameras, and one camera a fisheye; `duplicate`: one observation given twice (a camera seeing a track twice)."""
    rig = make_rig(n_cameras=n_cameras, n_points=n_points, seed=3)
    obs = observe(rig, noise_px=0.5, seed=3, visibility=0.6).observations
    M = len(rig.cameras)
    intr = np.zeros((M, N_INTRINSICS))
    for m, c in enumerate(rig.cameras):
        values = intrinsics_from_K(c.K, c.dist)
        intr[m, : len(values)] = values
    state = State(intr, np.array([c.R for c in rig.cameras]), np.array([c.centre for c in rig.cameras]),
                  rig.points.copy())
    intr_free = np.zeros((M, N_INTRINSICS), dtype=bool)
    intr_free[1:, 0] = True  # the left camera with nothing free: rows without camera columns
    intr_free[[2, 3], 4] = True
    rot_free = np.ones((M, 3), dtype=bool)
    rot_free[0] = False
    centre_mode = np.full(M, CentreMode.FREE)
    centre_mode[0], centre_mode[1] = CentreMode.FIXED, CentreMode.ON_BASELINE
    rows = np.arange(len(obs.uv))
    if duplicate:
        rows = np.append(rows, rows[len(rows) // 2])
    problem = Problem(cam=obs.cam_index[rows], pt=obs.track_index[rows], uv=obs.uv[rows], intr_free=intr_free,
                      rot_free=rot_free, centre_mode=centre_mode, baseline_m=rig.baseline_m, n_points=n_points,
                      fisheye=np.arange(M) == M - 1)
    return problem, state


@pytest.mark.parametrize("duplicate", [False, True])
@pytest.mark.parametrize("loss", ["linear", "cauchy"])
def test_blocks_of_rows_give_the_equations_of_one_piece(monkeypatch, loss, duplicate):
    problem, state = _network(6, 300, duplicate=duplicate)
    assert len(problem.cam) > 1000
    monkeypatch.setattr(bundle, "BLOCK_ROWS", 10**9)
    whole = bundle.normal_equations(replace(problem), state, loss=loss, scale_px=2.0)
    layout = replace(problem).layout
    assert len(layout.blocks) == len(layout.groups) + 1  # a block per group, one for the left camera's rows
    for rows in (350, 150):  # some groups split; every camera a block of its own
        monkeypatch.setattr(bundle, "BLOCK_ROWS", rows)
        blocked = replace(problem)
        assert rows > 150 or len(blocked.layout.blocks) == problem.n_cameras
        parts = bundle.normal_equations(blocked, state, loss=loss, scale_px=2.0)
        for name in ("U", "W", "V", "gc", "gp", "cost"):
            np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name), err_msg=f"{name}, {rows} rows")


def _peak_beyond(f, keep_bytes: int) -> int:
    """Bytes that f() held at its peak beyond `keep_bytes` (what it returns), as tracemalloc counts them."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        f()
        return tracemalloc.get_traced_memory()[1] - base - keep_bytes
    finally:
        tracemalloc.stop()


def test_schur_steps_take_bounded_memory():
    """At M = 16, N = 1000 (10,000 observations, W 2.4 MB) the normal equations, a damped step, the points'
    elimination and the points' covariances hold 2.9, 1.3, 0.7 and 1.0 MB beyond what they return; formed whole,
    6.8, 5.1, 3 and 2.6 MB."""
    problem, state = _network(16, 1000)
    problem.layout  # noqa: B018 (cached: not the equations' own)
    ne = bundle.normal_equations(problem, state)
    out = ne.U.nbytes + ne.W.nbytes + ne.V.nbytes + ne.gc.nbytes + ne.gp.nbytes
    assert ne.W.nbytes > 2 * MB
    assert _peak_beyond(lambda: bundle.normal_equations(problem, state), out) < 4 * MB
    assert _peak_beyond(lambda: schur.solve_damped(ne, 1e-3), 0) < 2.5 * MB
    assert _peak_beyond(lambda: schur.eliminate_points(ne), ne.V.nbytes) < 1.2 * MB  # whole, W V^-1 alone: 2.4 MB
    cov = covariance(problem, state, sigma_px=0.5, normal=ne)
    assert _peak_beyond(lambda: replace(cov).point_covariances_m2, cov.V.nbytes) < 1.8 * MB


def test_points_quadratic_forms_by_a_triangular_factor_and_without_one():
    """WV_n^T A WV_n per point: through A's Cholesky factor, and through A itself where A is singular."""
    rng = np.random.default_rng(5)
    B = rng.normal(size=(40, 40))
    units = np.logspace(-4, 4, 40)  # parameters of mixed units, as a camera block's
    WV = rng.normal(size=(40, 3 * 700))
    for A in (B @ B.T + np.eye(40), B[:, :30] @ B[:, :30].T):  # positive definite; of rank 30
        A = units[:, None] * A * units[None, :]
        direct = np.einsum("pni,pq,qnj->nij", WV.reshape(40, -1, 3), A, WV.reshape(40, -1, 3))
        np.testing.assert_allclose(schur.point_quadratic_forms(WV, A), direct, rtol=1e-9,
                                   atol=1e-12 * np.abs(direct).max())
    # With V^-1 given: the forms of W V^-1 without forming it.
    C = rng.normal(size=(700, 3, 3))
    V_inv = C @ C.transpose(0, 2, 1)
    W = WV
    WV = schur.times_block_diag(W, V_inv)
    direct = np.einsum("pni,pq,qnj->nij", WV.reshape(40, -1, 3), A, WV.reshape(40, -1, 3))
    np.testing.assert_allclose(schur.point_quadratic_forms(W, A, V_inv), direct, rtol=1e-9,
                               atol=1e-12 * np.abs(direct).max())
