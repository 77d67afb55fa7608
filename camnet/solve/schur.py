"""The normal equations of a bundle adjustment, and their solution by the Schur complement.

The Gauss-Newton system ``H d = -g`` splits into camera (c) and point (p)
blocks, ``[[U, W], [W^T, V]]``; V is block diagonal, one 3x3 block per point
(metres), so the points are eliminated and each step costs a dense solve of
the camera parameters only: ``S = U - W V^-1 W^T``. Pure functions on arrays;
the units are those of the parameters (pixels, radians, metres) and of the
residuals (pixels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

GAUSS_NEWTON_LAMBDA = 1e-9  # damping of the (almost) undamped step: keeps a singular direction solvable
BLOCK_BYTES = 1 << 19  # the points' share of a product of W formed at a time (`point_blocks`)
# A point block whose smallest eigenvalue is below this fraction of its largest leaves
# the point undetermined along that direction (in metres, so the ratio has meaning).
POINT_RCOND = 1e-12


@dataclass(frozen=True)
class NormalEquations:
    """J^T J and J^T r split into camera (c) and point (p) blocks.

    W is dense: a camera sees a good share of the points in the networks
    camnet solves, and one BLAS product on it beats sparse bookkeeping.
    """

    U: np.ndarray  # (Pc, Pc)
    W: np.ndarray  # (Pc, 3N)
    V: np.ndarray  # (N, 3, 3)
    gc: np.ndarray  # (Pc,)
    gp: np.ndarray  # (N, 3)
    cost: float


@dataclass(frozen=True)
class PointsEliminated:
    """The points eliminated, undamped, from normal equations: ``S = U - WVW`` is their reduced camera matrix.

    Formed once at a solve's final state, where the convergence test's last
    step (`gauss_newton_test`) and the covariance
    (camnet.solve.uncertainty.covariance) both need it.
    """

    V_inv: np.ndarray  # (N, 3, 3) `point_inverses` of V
    WVW: np.ndarray  # (Pc, Pc) W V^-1 W^T (V^-1 the block diagonal of V_inv)
    determined: np.ndarray  # (N,) `points_determined` of V, from the same factors


def eliminate_points(ne: NormalEquations) -> PointsEliminated:
    """The points of `ne` eliminated (see `PointsEliminated`).

    W V^-1 W^T a block of points at a time (`point_blocks`): formed whole,
    W V^-1 (megabytes) is fresh memory that the kernel maps and zeroes page
    by page, at a cost of the product's order (docs/benchmarks.md, "Evidence
    behind the solver's thresholds"). (Not as the symmetric rank-k update of
    W L^-T, V = L L^T, which is a little faster but moves the sigmas of a
    free principal point's flat valley: docs/benchmarks.md, "The engine".)
    """
    V_inv, determined = _inverses_and_determined(ne.V)
    P = len(ne.U)
    WVW = np.zeros((P, P))
    for a, b in point_blocks(len(V_inv), P) if P else ():
        W_b = ne.W[:, 3 * a : 3 * b]
        WVW += times_block_diag(W_b, V_inv[a:b]) @ W_b.T
    return PointsEliminated(V_inv, WVW, determined)


def restrict(ne: NormalEquations, columns: np.ndarray, *, out: np.ndarray | None = None) -> NormalEquations:
    """The normal equations with only the camera parameters at `columns` free.

    out: (len(columns), 3N) an array no one uses any more, to take their W (a few MB: fresh memory, which the
    kernel maps and zeroes page by page, where the allocator has none to hand).
    """
    if len(columns) == len(ne.U) and np.array_equal(columns, np.arange(len(columns))):
        return ne  # all of them, in their order
    W = np.take(ne.W, columns, axis=0, out=out, mode="clip")  # numpy buffers `out` where it checks the indices
    return NormalEquations(ne.U[np.ix_(columns, columns)], W, ne.V, ne.gc[columns], ne.gp, ne.cost)


def times_block_diag(W: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """W (P, 3N) times the block-diagonal matrix of `blocks` (N, 3, 3)."""
    P, N = len(W), len(blocks)
    # optimize=True hands the products to BLAS: eight times faster than a batched matmul here.
    return np.einsum("pni,nij->pnj", W.reshape(P, N, 3), blocks, optimize=True).reshape(P, 3 * N)


def inverse_cholesky_3x3(V: np.ndarray) -> np.ndarray:
    """L^-1 (N, 3, 3), lower triangular, of the Cholesky factors V = L L^T of V (N, 3, 3).

    NaN where a block is not positive definite. In closed form: a batched
    LAPACK call per 3x3 block costs more than the arithmetic. With it,
    ``V^-1 = L^-T L^-1``, so ``W V^-1 W^T`` is the product of ``W L^-T`` with itself.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(V[:, 0, 0])
        l10 = V[:, 1, 0] / l00
        l20 = V[:, 2, 0] / l00
        l11 = np.sqrt(V[:, 1, 1] - l10 * l10)
        l21 = (V[:, 2, 1] - l20 * l10) / l11
        l22 = np.sqrt(V[:, 2, 2] - l20 * l20 - l21 * l21)
        inv = np.zeros_like(V)
        inv[:, 0, 0] = 1.0 / l00
        inv[:, 1, 1] = 1.0 / l11
        inv[:, 2, 2] = 1.0 / l22
        inv[:, 1, 0] = -l10 * inv[:, 0, 0] * inv[:, 1, 1]
        inv[:, 2, 1] = -l21 * inv[:, 1, 1] * inv[:, 2, 2]
        inv[:, 2, 0] = -(l20 * inv[:, 0, 0] + l21 * inv[:, 1, 0]) * inv[:, 2, 2]
    return inv


def solve_damped(ne: NormalEquations, lam: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(dc (Pc,), dp (N, 3)) solving (H + lam diag H) d = -g; None if not positive definite."""
    S = ne.U + np.diag(lam * np.maximum(np.diag(ne.U), 1e-9))
    dV = np.einsum("nii->ni", ne.V)
    L_inv = inverse_cholesky_3x3(ne.V + (lam * np.maximum(dV, 1e-9))[:, :, None] * np.eye(3))
    if not np.all(np.isfinite(L_inv)):
        return None
    Lg = np.einsum("nij,nj->ni", L_inv, ne.gp).reshape(-1)
    L_inv_T = L_inv.transpose(0, 2, 1)
    rhs = -ne.gc
    for a, b in point_blocks(len(L_inv), len(S)) if len(S) else ():  # no camera moves: the points alone
        WL = times_block_diag(ne.W[:, 3 * a : 3 * b], L_inv_T[a:b])  # W L^-T of these points
        rhs = rhs + WL @ Lg[3 * a : 3 * b]
        # S's upper triangle, all that the Cholesky factorisation reads: a symmetric
        # rank-k update does half the work of the full product.
        # (Passed as WL^T, which is in the column order BLAS reads: no copy of WL.)
        S = scipy.linalg.blas.dsyrk(-1.0, WL.T, beta=1.0, c=S, overwrite_c=True, trans=1)
    dc = _solve_positive_definite(S, rhs)
    if dc is None:
        return None
    z = np.einsum("nij,nj->ni", L_inv, ne.gp + (ne.W.T @ dc).reshape(-1, 3))
    dp = -np.einsum("nji,nj->ni", L_inv, z)  # -V^-1 (gp + W^T dc)
    if not (np.all(np.isfinite(dc)) and np.all(np.isfinite(dp))):
        return None
    return dc, dp


def solve_eliminated(
    ne: NormalEquations, eliminated: PointsEliminated, within: np.ndarray, lam: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """(dc (Pc,), dp (N, 3)) solving (H + lam diag U) d = -g, the cameras damped and the points not.

    eliminated: the points eliminated from wider normal equations at the same
    state, of which `ne` holds the camera columns `within` (`restrict`);
    the reduced camera matrix is then a block of theirs. None if it is not
    positive definite.
    """
    S = ne.U + np.diag(lam * np.maximum(np.diag(ne.U), 1e-9)) - eliminated.WVW[np.ix_(within, within)]
    y = np.einsum("nij,nj->ni", eliminated.V_inv, ne.gp)  # V^-1 g_p
    rhs = -ne.gc + ne.W @ y.reshape(-1)
    dc = _solve_positive_definite(S, rhs)
    if dc is None:
        return None
    dp = -np.einsum("nij,nj->ni", eliminated.V_inv, ne.gp + (ne.W.T @ dc).reshape(-1, 3))
    if not (np.all(np.isfinite(dc)) and np.all(np.isfinite(dp))):
        return None
    return dc, dp


def point_blocks(n_points: int, n_columns: int) -> list[tuple[int, int]]:
    """[start, stop) ranges of points whose share of a (n_columns, 3 N) product fits BLOCK_BYTES.

    Products of W (a few MB) formed whole are fresh memory on every call, which the
    allocator maps and the kernel zeroes page by page, at a cost of the arithmetic's order.
    Blocks of a few hundred kB are reused from the heap.
    """
    size = max(1, BLOCK_BYTES // (24 * max(n_columns, 1)))
    return [(a, min(a + size, n_points)) for a in range(0, n_points, size)] or [(0, 0)]


def point_quadratic_forms(WV: np.ndarray, A: np.ndarray, V_inv: np.ndarray | None = None) -> np.ndarray:
    """(N, 3, 3) ``WV_n^T A WV_n`` per point n, for WV (Pc, 3N) and A (Pc, Pc) symmetric positive semi-definite.

    V_inv (N, 3, 3): given, `WV` is W and the forms are those of W V^-1 (V^-1
    the block diagonal of V_inv), as ``V_inv_n^T (W_n^T A W_n) V_inv_n``:
    W V^-1 is never formed, which saves its fresh memory.
    Where A has a Cholesky factor A = L L^T, as ``Y_n^T Y_n`` with Y = L^T WV:
    a triangular product, half the work of A WV, and each point's six
    distinct entries as sums over Y's columns. Else (a singular A) through
    A WV. A block of points at a time (`point_blocks`). Timings:
    docs/benchmarks.md, "Evidence behind the solver's thresholds".
    """
    if V_inv is not None:
        return V_inv.transpose(0, 2, 1) @ point_quadratic_forms(WV, A) @ V_inv
    N = WV.shape[1] // 3
    out = np.empty((N, 3, 3))
    try:
        L = np.linalg.cholesky(A) if len(A) else None
    except np.linalg.LinAlgError:
        L = None
    for a, b in point_blocks(N, len(WV)):
        WV_b = WV[:, 3 * a : 3 * b]
        if L is None:  # WV_n^T (A WV_n), one 3x3 per point: a batched matmul (plain einsum is several times slower)
            left, right = WV_b.reshape(-1, b - a, 3), (A @ WV_b).reshape(-1, b - a, 3)
            out[a:b] = left.transpose(1, 2, 0) @ right.transpose(1, 0, 2)
            continue
        # WV_b^T L in BLAS's column order (WV_b^T is WV_b read as Fortran), transposed: Y = L^T WV_b.
        Y = scipy.linalg.blas.dtrmm(1.0, L, WV_b.T, side=1, lower=1).T.reshape(-1, b - a, 3)
        for i in range(3):
            for j in range(i, 3):
                out[a:b, i, j] = out[a:b, j, i] = np.einsum("pn,pn->n", Y[:, :, i], Y[:, :, j])
    return out


def predicted_decrease(
    ne: NormalEquations, lam: float, dc: np.ndarray, dp: np.ndarray, *, points_damped: bool = True
) -> float:
    """Decrease of the Gauss-Newton model cost along the damped step (dc, dp), >= 0.

    points_damped: False for a step whose points were not damped (`solve_eliminated`).
    """
    # With (H + lam D) d = -g: -g.d - d.H.d / 2 = (lam d.D.d - g.d) / 2.
    dU = np.maximum(np.diag(ne.U), 1e-9)
    dV = np.maximum(np.einsum("nii->ni", ne.V), 1e-9) if points_damped else np.zeros_like(dp)
    damped = lam * (float(dc @ (dU * dc)) + float(np.sum(dV * dp * dp)))
    return 0.5 * (damped - float(ne.gc @ dc) - float(np.sum(ne.gp * dp)))


def gauss_newton_decrease(ne: NormalEquations) -> float:
    """The decrease an (almost) undamped step promises; infinite if it cannot be solved."""
    step = solve_damped(ne, GAUSS_NEWTON_LAMBDA)
    return np.inf if step is None else predicted_decrease(ne, GAUSS_NEWTON_LAMBDA, *step)


def gauss_newton_test(
    ne: NormalEquations, ftol: float, *, eliminated: PointsEliminated | None = None, within: np.ndarray | None = None
) -> tuple[tuple[np.ndarray, np.ndarray] | None, float, bool]:
    """A solve's convergence test after a step: (the undamped step at the new state, the decrease it
    promises, whether that is at most ``ftol`` of the cost, relative: then the solve has converged).

    eliminated, within: the points eliminated from wider normal equations at
    the same state, of which `ne` holds the columns `within`: the step is
    then taken from their reduced camera matrix (`solve_eliminated`, the
    points undamped) rather than forming one.
    """
    if eliminated is None:
        step = solve_damped(ne, GAUSS_NEWTON_LAMBDA)
        remaining = np.inf if step is None else predicted_decrease(ne, GAUSS_NEWTON_LAMBDA, *step)
    else:
        step = solve_eliminated(ne, eliminated, within, GAUSS_NEWTON_LAMBDA)
        remaining = np.inf if step is None else predicted_decrease(ne, GAUSS_NEWTON_LAMBDA, *step, points_damped=False)
    return step, remaining, remaining <= ftol * ne.cost


def point_inverses(V: np.ndarray) -> np.ndarray:
    """(N, 3, 3) pseudo-inverses of the point blocks V (N, 3, 3), cut off at POINT_RCOND.

    In closed form (``L^-T L^-1`` of the Cholesky factors) where a block is
    well conditioned: a LAPACK call per 3x3 block costs more than the
    arithmetic. The others (a point seen along one ray) take the pseudo-inverse.
    """
    V_inv, well = _closed_form_inverses(V)
    if not well.all():
        V_inv[~well] = np.linalg.pinv(V[~well], rcond=POINT_RCOND, hermitian=True)
    return V_inv


def _inverses_and_determined(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(`point_inverses`, `points_determined`) of V (N, 3, 3), from one set of closed-form inverses."""
    V_inv, well = _closed_form_inverses(V)
    determined = well.copy()
    if not well.all():
        V_inv[~well] = np.linalg.pinv(V[~well], rcond=POINT_RCOND, hermitian=True)
        eig = np.linalg.eigvalsh(V[~well])
        determined[~well] = eig[:, 0] > POINT_RCOND * np.maximum(eig[:, -1], 1e-300)
    return V_inv, determined


def points_determined(V: np.ndarray) -> np.ndarray:
    """(N,) whether each point block V (N, 3, 3) fixes its point in every direction (no eigenvalue
    under POINT_RCOND of the largest)."""
    _, determined = _closed_form_inverses(V)
    if not determined.all():
        eig = np.linalg.eigvalsh(V[~determined])
        determined[~determined] = eig[:, 0] > POINT_RCOND * np.maximum(eig[:, -1], 1e-300)
    return determined


def _closed_form_inverses(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inverses (N, 3, 3), well (N,)): V^-1 from its Cholesky factors, and where it is well conditioned.

    ``|V|_F |V^-1|_F`` bounds the condition number from above: a block under
    a tenth of 1 / POINT_RCOND has no eigenvalue under the cut-off, so its
    pseudo-inverse is its inverse. NaN (no Cholesky factor) is not well.
    """
    L_inv = inverse_cholesky_3x3(V)
    with np.errstate(invalid="ignore", over="ignore"):
        V_inv = L_inv.transpose(0, 2, 1) @ L_inv
        bound = np.linalg.norm(V, axis=(1, 2)) * np.linalg.norm(V_inv, axis=(1, 2))
    return V_inv, bound < 0.1 / POINT_RCOND


def _solve_positive_definite(S: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """S^-1 rhs by Cholesky; None where S is not positive definite (an empty system solves to itself)."""
    if not len(rhs):
        return rhs
    try:
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(S, check_finite=False), rhs)
    except np.linalg.LinAlgError:
        return None
