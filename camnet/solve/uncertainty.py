"""Covariance of a bundle adjustment solution, and the Cramer-Rao bound.

At a least-squares solution the covariance of the parameters is
``sigma^2 (J^T J)^-1``. With the points eliminated, the camera block is
``sigma^2 S^-1`` (S the Schur complement) and any scalar function g of the
parameters has variance ``sigma^2 grad(g)^T H^-1 grad(g)``, evaluated here
without forming the dense inverse. With the true parameters and the true
noise sigma, the same quantities are the Cramer-Rao bound.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.linalg

from camnet.model.projection import N_INTRINSICS
from camnet.solve.bundle import ROT, Problem, State, distance_rows, normal_equations
from camnet.solve.bundle import residuals as reprojection_residuals
from camnet.solve.schur import (
    NormalEquations,
    PointsEliminated,
    eliminate_points,
    point_quadratic_forms,
    points_determined,
    times_block_diag,
)

# An eigenvalue of the unit-diagonal camera matrix below this (per parameter) is a direction
# no observation fixes: well-posed but weak directions sit many orders of magnitude above it.
NULL_EIGENVALUE = 1e-13
NULL_COMPONENT = 1e-6  # a unit vector with this much of its square in the null space is undetermined
EXTENT_REL = 1e-9  # a cloud whose RMS spread is below this share of its coordinates is one point: it has no scale


@dataclass(frozen=True)
class Covariance:
    sigma_px: float  # pixel noise sigma the covariance is scaled by
    S_inv: np.ndarray  # (Pc, Pc) inverse Schur complement (unscaled)
    W: np.ndarray  # (Pc, 3N)
    V_inv: np.ndarray  # (N, 3, 3) pseudo-inverses of the point blocks V
    V: np.ndarray  # (N, 3, 3)
    columns: np.ndarray  # (M, 15) problem.columns()
    # (Pc, k) orthonormal basis, in unit-diagonal coordinates (see `inverse_spd`), of the
    # camera directions no observation fixes; S_inv is the pseudo-inverse on the rest.
    null: np.ndarray | None = None
    unit: np.ndarray | None = None  # (Pc,) the scaling to unit-diagonal coordinates
    S: np.ndarray | None = None  # (Pc, Pc) the Schur complement itself (unscaled)
    determined: np.ndarray | None = None  # (N,) schur.points_determined of V, where the elimination had it

    @property
    def cameras(self) -> np.ndarray:
        """(Pc, Pc) covariance of the camera parameters (finite: see `undetermined`)."""
        return self.sigma_px**2 * self.S_inv

    @property
    def undetermined(self) -> np.ndarray:
        """(Pc,) camera columns that move along a direction no observation fixes (infinite variance)."""
        if self.null is None or not self.null.shape[1]:
            return np.zeros(self.S_inv.shape[0], dtype=bool)
        return np.sum(self.null**2, axis=1) > NULL_COMPONENT

    def _determines(self, reduced: np.ndarray) -> bool:
        """Whether a function with this reduced camera gradient is blind to the undetermined directions."""
        if self.null is None or not self.null.shape[1]:
            return True
        r = reduced / self.unit
        return bool(np.linalg.norm(self.null.T @ r) <= np.sqrt(NULL_COMPONENT) * np.linalg.norm(r))

    def variance(self, g_cam: np.ndarray | None, g_pts: np.ndarray | None, *, given: np.ndarray = ()) -> float:
        """Variance of a linear function with gradient (g_cam (Pc,), g_pts (N, 3)).

        given: camera columns whose values are taken as exactly known (the
        Gaussian conditional: what a prior on them no longer matters to).
        """
        return self.variances(g_cam, g_pts, [given])[0]

    def variances(self, g_cam: np.ndarray | None, g_pts: np.ndarray | None, givens: list) -> list[float]:
        """`variance` of one function given each of `givens` (lists of camera columns, as `given`) in turn:
        the products with W and the inverse, which cost the most, once for them all."""
        Pc, N = self.S_inv.shape[0], len(self.V_inv)
        gc = np.zeros(Pc) if g_cam is None else g_cam
        gp = np.zeros((N, 3)) if g_pts is None else g_pts
        # g^T H^-1 g by the Schur complement: with y = V^-1 g_p, r = g_c - W y and x_c = S^-1 r, it is
        # g_p.y + r.x_c (the points' part of H^-1 g, y - V^-1 W^T x_c, need not be formed: one product with W).
        y = np.einsum("nij,nj->ni", self.V_inv, gp)
        reduced = gc - self.W @ y.reshape(-1)
        if not self._determines(reduced):
            return [np.inf] * len(givens)
        xc = self.S_inv @ reduced
        var = np.sum(gp * y) + reduced @ xc
        out = []
        for given in givens:
            conditional = var
            if len(given):  # var(g | c) = var(g) - cov(g, c) var(c)^-1 cov(c, g); cov(c, g) = x_c
                c = np.asarray(given)
                conditional = var - xc[c] @ np.linalg.solve(self.S_inv[np.ix_(c, c)], xc[c])
            out.append(float(self.sigma_px**2 * conditional))
        return out

    @cached_property  # the points' dense products cost more than the rest of the covariance
    def point_covariances_m2(self) -> np.ndarray:
        """(N, 3, 3) covariance of each point, m^2; infinite for a point not fixed in some direction."""
        N = len(self.V_inv)
        extra = point_quadratic_forms(self.W, self.S_inv, self.V_inv)  # (W V^-1)_n^T S_inv (W V^-1)_n per point
        determined = points_determined(self.V) if self.determined is None else self.determined
        cov = self.sigma_px**2 * (self.V_inv + extra)
        cov[~determined] = np.inf
        if self.null is not None and self.null.shape[1]:  # points a free camera direction moves
            WV = times_block_diag(self.W, self.V_inv)
            along_null = np.einsum("pk,pnj->nkj", self.null, (WV / self.unit[:, None]).reshape(-1, N, 3))
            size = np.linalg.norm((WV / self.unit[:, None]).reshape(-1, N, 3), axis=0)  # (N, 3)
            moved = np.linalg.norm(along_null, axis=1) > np.sqrt(NULL_COMPONENT) * np.maximum(size, 1e-300)
            cov[moved.any(axis=1)] = np.inf
        return cov

    def point_sigmas_m(self) -> np.ndarray:
        """(N,) RMS over axes of each point's standard deviation, metres (infinite: not fixed)."""
        return np.sqrt(np.maximum(np.einsum("nii->n", self.point_covariances_m2), 0.0) / 3.0)


def covariance(
    problem: Problem, state: State, *, sigma_px: float | None = None, normal: NormalEquations | None = None,
    eliminated: PointsEliminated | None = None,
) -> Covariance:
    """Covariance at `state`; sigma_px None estimates it from the residuals (a posteriori).

    normal: the unweighted normal equations at `state` when the caller has them;
    eliminated: their points eliminated (`schur.eliminate_points`; it does not
    depend on U, so holds for `normal` with a prior added to U), when the
    caller has them (a solve's `SolveInfo.eliminated`).
    """
    ne = normal_equations(problem, state) if normal is None else normal
    # A point left without observations (all rejected), or seen along one ray only
    # (no parallax), carries no information in some directions: the pseudo-inverse
    # gives it no weight in the cameras' equations, and `point_sigmas_m` an
    # infinite error.
    points = eliminate_points(ne) if eliminated is None else eliminated
    S = ne.U - points.WVW
    S_inv, null, unit = inverse_spd(S)
    if sigma_px is None:
        sigma_px = float(np.sqrt(2.0 * ne.cost / max(residual_dof(problem), 1)))
    return Covariance(sigma_px, S_inv, ne.W, points.V_inv, ne.V, problem.columns()[0], null, unit, S, points.determined)


def distance_checks(
    problem: Problem, state: State, cov: Covariance, *, normal: NormalEquations | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """What the rest of the data say each known distance is: (metres (B,), their 1 sigma (B,)).

    Each distance's row is taken out of the Schur complement (exactly: it
    touches camera columns only), and a Newton step on the other rows from
    `state` moves the solution to where they put it. The step starts from
    the pixels' own gradient, not from the row's residual, which for a
    stiff row is rounding. Infinite sigma: nothing else fixes the distance.
    `cov`: the covariance of `problem`, or of it with more intrinsics free;
    normal: the unweighted normal equations at `state` in cov's column layout
    (the solve's `SolveInfo.normal`), when the caller has them.
    """
    # cov's column layout: a held stereo rotation it prices (`with_held_turns`) is one of its columns
    wider = problem.freeing(intr_free=cov.columns[:, :N_INTRINSICS] >= 0, rot_free=cov.columns[:, ROT] >= 0)
    ne = normal if normal is not None and normal.U.shape == cov.S.shape else normal_equations(wider, state)
    r, J = distance_rows(wider, state)
    gradient = ne.gc - times_block_diag(ne.W, cov.V_inv) @ ne.gp.reshape(-1)  # points eliminated
    known = problem.distances
    w = known.weights_px_per_m(problem.distance_sigma_px)
    scene_m = known.metres + known.errors_m(state.C)
    sigma_m = np.full(len(known), np.inf)
    for k, j in enumerate(J):
        try:
            factor = scipy.linalg.cho_factor(cov.S - np.outer(j, j))
        except np.linalg.LinAlgError:  # the other rows leave it free
            continue
        scene_m[k] -= j @ scipy.linalg.cho_solve(factor, gradient - j * r[k]) / w[k]
        sigma_m[k] = cov.sigma_px * np.sqrt(j @ scipy.linalg.cho_solve(factor, j)) / w[k]
    return scene_m, sigma_m


def residual_dof(problem: Problem) -> int:
    """Degrees of freedom of the residuals: observation coordinates minus the parameters they fix.

    A point seen once fits its two coordinates exactly and uses two of its
    three unknowns; a point left without observations uses none. Counting
    three for every point would shrink the count (and inflate the a-posteriori
    sigma) wherever outlier rejection leaves tracks with a single view.
    Each known distance is one more residual (an exact one, held by a stiff
    row, one parameter fewer).
    """
    views = np.bincount(problem.pt, minlength=problem.n_points)
    n_rows = 2 * len(problem.cam) + len(problem.distances)
    return int(n_rows - problem.columns()[1] - np.minimum(3, 2 * views).sum())


def pixel_sigma(problem: Problem, state: State, *, residuals: np.ndarray | None = None) -> float:
    """The a-posteriori pixel noise sigma of the (least-squares) reprojection residuals at `state`.

    residuals (n, 2): `bundle.residuals` of `problem` at `state`, pixels, where the caller has them.
    """
    r = reprojection_residuals(problem, state) if residuals is None else residuals
    return float(np.sqrt(np.sum(r * r) / max(residual_dof(problem) - len(problem.distances), 1)))


def with_guessed_pp(problem: Problem, guessed_pp: np.ndarray) -> Problem | None:
    """`problem` with the guessed principal points it holds freed, or None if it holds none.

    guessed_pp (M,): cameras whose principal point was guessed (the image
    centre), not given.
    """
    consider = guessed_pp & ~problem.intr_free[:, 2]
    if not consider.any():
        return None
    intr_free = problem.intr_free.copy()
    intr_free[consider, 2:4] = True
    return problem.freeing(intr_free=intr_free)


def covariance_with_pp_prior(
    problem: Problem, wider: Problem | None, state: State, normal, prior_px: np.ndarray,
    eliminated: PointsEliminated | None = None,
) -> Covariance:
    """Covariance at the solution, not conditional on principal points that are only guessed.

    A principal point held at the image centre because nobody gave one is
    not known exactly: a real lens's sits a percent or so of the image size
    away (camnet.solve.options.Options.pp_prior_rel). Held but unknown, it biases focal lengths
    and scale by amounts the conditional covariance does not show (the data
    of a small object cannot tell a 10 px offset from a focal length or a
    rotation, and a column difference in the stereo pair shifts every
    disparity). Its uncertainty enters as a prior on the held columns, so
    the reported sigmas include what the guess may cost.
    wider: `problem` with those principal points freed (`with_guessed_pp`),
    or None; normal: the normal equations of `wider` (else of `problem`) at
    `state`; prior_px (M, 2): 1 sigma of the guess in x and y, pixels;
    eliminated: the points eliminated from `normal`, where the caller has them.
    """
    sigma_px = float(np.sqrt(2.0 * normal.cost / max(residual_dof(problem), 1)))
    if wider is None:
        return covariance(problem, state, sigma_px=sigma_px, normal=normal, eliminated=eliminated)
    cols = wider.columns()[0]
    U = normal.U.copy()
    for m in np.flatnonzero(wider.intr_free[:, 2] & ~problem.intr_free[:, 2]):
        for slot, prior in ((2, prior_px[m, 0]), (3, prior_px[m, 1])):
            U[cols[m, slot], cols[m, slot]] += (sigma_px / prior) ** 2
    return covariance(wider, state, sigma_px=sigma_px, normal=replace(normal, U=U), eliminated=eliminated)


def with_held_turns(problem: Problem) -> Problem | None:
    """`problem` with the rotation axes of the right stereo camera (camera 1) that it holds freed, or None if it
    holds none: the layout `held_at_tolerance` takes them from."""
    if problem.n_cameras < 2 or problem.rot_free[1].all():
        return None
    rot_free = problem.rot_free.copy()
    rot_free[1] = True
    return problem.freeing(rot_free=rot_free)


def held_turn_columns(problem: Problem, wider: Problem) -> np.ndarray:
    """The columns of `wider` that hold the right stereo camera's rotation axes `problem` holds."""
    cols = wider.columns()[0][1, ROT]
    return cols[(cols >= 0) & ~problem.rot_free[1]]


def held_at_tolerance(cov: Covariance, columns: np.ndarray, sigma: float) -> Covariance:
    """The covariance of an estimate that holds `columns` at assumed values, each known to `sigma` (1 sigma, in
    the columns' units: radians for a rotation), from `cov`, its covariance with them free.

    Holding a parameter whose true value is off the assumed one by d moves
    the rest by C d (C = Sigma_xc Sigma_cc^-1, their regression on it), so
    over d ~ N(0, sigma^2) the held estimate's covariance is the conditional
    one, Sigma - C Sigma_cc C^T, plus C sigma^2 C^T: a rank-k update of the
    camera block, which the points' covariances follow through W. This is
    not the posterior of a prior on the columns (the principal points'
    `covariance_with_pp_prior`): that is the covariance of an estimate that
    frees them, and smaller wherever the data know them as well as the
    assumption does, which a held estimate does not profit from. In
    information form the update adds sigma^-2 - Sigma_cc^-1 to the held
    columns (negative where the data know them better than the assumption:
    holding them then costs more than freeing them would).
    """
    c = np.asarray(columns, dtype=int)
    if not len(c):
        return cov
    if cov.undetermined[c].any():
        # The data do not fix them at all: the held estimate's covariance is then the posterior of the prior.
        S = cov.S.copy()
        S[c, c] += (cov.sigma_px / sigma) ** 2
        S_inv, null, unit = inverse_spd(S)
        return replace(cov, S_inv=S_inv, S=S, null=null, unit=unit)
    S_cc = cov.S_inv[np.ix_(c, c)]
    C = cov.S_inv[:, c] @ np.linalg.inv(S_cc)
    prior = (sigma / cov.sigma_px) ** 2 * np.eye(len(c))  # the covariance's unscaled units
    S_inv = cov.S_inv + C @ (prior - S_cc) @ C.T
    S = None
    if cov.S is not None:
        S = cov.S.copy()
        S[np.ix_(c, c)] += np.linalg.inv(prior) - np.linalg.inv(S_cc)
    return replace(cov, S_inv=S_inv, S=S)


def inverse_spd(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inverse, null, unit) of a symmetric positive semi-definite matrix of mixed units.

    The camera parameters mix pixels, radians and metres, so the eigenvalues of
    S span twenty orders of magnitude even when every direction is
    determined. A pseudo-inverse with a cut-off relative to the largest
    eigenvalue would drop the weakest directions, which are exactly the
    nearly flat valleys (focal length against principal point and depth)
    whose large variance must be reported. Scaling to a unit diagonal first
    (``unit``, (P,): ``S_unit = S / outer(unit, unit)``) leaves only the true
    conditioning. Directions that no observation fixes at all (a parameter
    with no effect, or a rank defect the solve did not remove) form ``null``
    (P, k), an orthonormal basis in those coordinates; the inverse is the
    pseudo-inverse on the rest, and `Covariance` reports them as undetermined
    rather than refusing the whole result.
    """
    if not len(S):
        return S, np.zeros((0, 0)), np.ones(0)
    diag = np.diag(S)
    unit = np.sqrt(np.where(diag > 0, diag, 1.0))
    scaled = S / unit[:, None] / unit[None, :]
    try:
        if not np.all(diag > 0):
            raise np.linalg.LinAlgError("a camera parameter has no effect on any observation")
        inv = scipy.linalg.cho_solve(scipy.linalg.cho_factor(scaled), np.eye(len(S)))
        # Rounding may leave a Cholesky factor of a singular matrix; its inverse then has a diagonal entry of
        # at least 1 / (P * least eigenvalue), and the eigenvalues must decide which directions are null.
        if np.max(np.diag(inv)) * NULL_EIGENVALUE * len(S) ** 2 >= 1.0:
            raise np.linalg.LinAlgError("singular but for rounding")
        null = np.zeros((len(S), 0))
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(scaled)
        fixed = w > NULL_EIGENVALUE * len(S)
        inv = (V[:, fixed] / w[fixed]) @ V[:, fixed].T
        null = V[:, ~fixed]
    return inv / unit[:, None] / unit[None, :], null, unit


def scale_gradient(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Gradient of the similarity scale of a point cloud with respect to its points.

    The weighted least-squares similarity that maps the true cloud onto the
    estimate has, to first order, the scale ``1 + sum(w_j c_j . e_j) /
    sum(w_j |c_j|^2)`` (c_j the true points centred on their weighted mean,
    e_j the errors, w_j the weights, default equal); rotation and
    translation errors do not enter it. NaN where the points that weigh
    span no more than rounding (`EXTENT_REL` of their coordinates): a
    single point has no scale.
    """
    w = np.ones(len(points)) if weights is None else weights
    if not w.sum() > 0:  # no point weighs: there is no scale to measure
        return np.full_like(points, np.nan)
    c = points - (w @ points) / w.sum()
    spread = np.sum(w[:, None] * c * c)
    reach = np.sqrt(np.sum(w[:, None] * points * points) / w.sum())  # a far point of no weight sets no yardstick
    if not np.sqrt(spread / w.sum()) > EXTENT_REL * reach:  # the points that weigh coincide
        return np.full_like(points, np.nan)
    return w[:, None] * c / spread


def scale_weights(cov: Covariance, points: np.ndarray, kept: np.ndarray | None = None) -> np.ndarray:
    """(N,) weights of the points in the network's scale, 0 for points left out.

    What matters for the scale is a point's error along its lever arm (from
    the cloud's median point): points as precise there as the cloud's median
    point or better weigh 1, less precise ones their inverse variance
    relative to it. Tracks with little parallax land far away with large
    depth errors, right along their lever arm, and with equal weights they
    would swamp the scale of the cloud's body, which is what the scale is
    about (a fully known stereo pair leaves the scale no freedom, yet a few
    far points would report percents). Capping the weight at 1 keeps a few
    deceptively precise points (a false match close to the cameras) from
    taking the scale over.
    """
    kept = np.ones(len(points), dtype=bool) if kept is None else kept
    if not kept.any():
        return np.zeros(len(points))
    arm = points - np.median(points[kept], axis=0)
    arm /= np.maximum(np.linalg.norm(arm, axis=1, keepdims=True), 1e-300)
    with np.errstate(invalid="ignore"):  # inf * 0 for undetermined points: weight 0 below
        along = np.sqrt(np.abs(np.einsum("ni,nij,nj->n", arm, cov.point_covariances_m2, arm)))
    along = np.where(np.isfinite(along), along, np.inf)
    typical = np.median(along[kept])
    if not np.isfinite(typical):  # most points move along a direction nothing fixes: weigh them alike
        return kept.astype(float)
    w = np.minimum(1.0, typical / np.maximum(along, 1e-300)) ** 2
    return np.where(kept, w, 0.0)


def scale_sigma(cov: Covariance, points: np.ndarray, weights: np.ndarray | None = None, *,
                given: np.ndarray = ()) -> float:
    """Standard deviation of the network's scale (relative, 0.001 = 0.1%).

    The scale is the similarity scale of the cloud with the given point
    weights (default `scale_weights` of `cov`), the one
    `camnet.model.accuracy.scale_error` measures with the same weights. given: as
    in `Covariance.variance`.
    """
    return scale_sigmas(cov, points, weights, [given])[0]


def scale_sigmas(cov: Covariance, points: np.ndarray, weights: np.ndarray | None, givens: list) -> list[float]:
    """`scale_sigma` given each of `givens` in turn (`Covariance.variances`)."""
    w = scale_weights(cov, points) if weights is None else weights
    return [float(np.sqrt(max(v, 0.0))) for v in cov.variances(None, scale_gradient(points, w), givens)]


def shape_rms_bound_m(cov: Covariance, points: np.ndarray) -> float:
    """Expected RMS point error (m) after similarity alignment, ``sqrt(tr(P Sigma P) / N)``.

    P removes the 7 similarity directions (translation, rotation, scale).
    """
    N = len(points)
    c = points - points.mean(axis=0)
    basis = []
    for k in range(3):
        e = np.zeros((N, 3))
        e[:, k] = 1.0
        basis.append(e)
        w = np.zeros(3)
        w[k] = 1.0
        basis.append(np.cross(w, c))
    basis.append(c)
    Q, _ = np.linalg.qr(np.stack([b.reshape(-1) for b in basis], axis=1))
    WV = times_block_diag(cov.W, cov.V_inv)
    trace_total = float(np.einsum("nii->", cov.V_inv)) + float(np.sum(cov.S_inv * (WV @ WV.T)))
    VQ = np.einsum("nij,njk->nik", cov.V_inv, Q.reshape(N, 3, -1)).reshape(3 * N, -1)
    WVQ = WV @ Q
    trace_sim = float(np.trace(Q.T @ VQ) + np.trace(WVQ.T @ cov.S_inv @ WVQ))
    return cov.sigma_px * float(np.sqrt(max(trace_total - trace_sim, 0.0) / N))
