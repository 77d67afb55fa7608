"""Bundle adjustment with a rigid, known-baseline stereo pair.

Levenberg-Marquardt on reprojection error with the points eliminated by the
Schur complement, so that each step costs a dense solve of the camera
parameters only (a few hundred unknowns even for 16 cameras) plus one 3x3
inverse per point. The Jacobian is analytic (`camnet.geometry.projection`).

Gauge: camera 0 of the problem (the left stereo camera) has a fixed pose,
and the right stereo camera's centre is held on the sphere of radius
``baseline_m`` about it, so the similarity gauge of structure from motion
is fully fixed: rotation and translation by the left camera, scale by the
baseline. An unconstrained adjustment frees the right camera's centre in 3-D
and leaves the scale to float, as in classical structure from motion.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from camnet.geometry.distances import Distances
from camnet.geometry.projection import (
    FISHEYE_INTRINSIC_NAMES,
    INTRINSIC_NAMES,
    N_INTRINSICS,
    project_points,
    project_with_jacobians,
    rotation_exp,
)
from camnet.geometry.robust import robust_loss

# Local parameter slots of a camera: intrinsics (9), rotation (3), centre (3).
ROT = slice(N_INTRINSICS, N_INTRINSICS + 3)
CEN = slice(N_INTRINSICS + 3, N_INTRINSICS + 6)
N_LOCAL = N_INTRINSICS + 6

log = logging.getLogger(__name__)


class CentreMode(enum.IntEnum):
    """How a camera's centre moves in the adjustment (values of `Problem.centre_mode`)."""

    FIXED = 0  # held: the left stereo camera, which fixes the frame
    FREE = 1  # three coordinates
    ON_BASELINE = 2  # on the sphere of radius baseline_m about the left camera: two angles


GAUSS_NEWTON_LAMBDA = 1e-9  # damping of the (almost) undamped step: keeps a singular direction solvable


@dataclass(frozen=True)
class State:
    """Parameters of a network: per camera intrinsics and pose, per track a point."""

    intr: np.ndarray  # (M, 9) see camnet.geometry.projection
    R: np.ndarray  # (M, 3, 3) world -> camera rotation
    C: np.ndarray  # (M, 3) camera centres, metres
    X: np.ndarray  # (N, 3) points, metres

    def copy(self) -> State:
        return State(self.intr.copy(), self.R.copy(), self.C.copy(), self.X.copy())


@dataclass(frozen=True)
class Problem:
    """Observations and which parameters move.

    ``cam[k]``, ``pt[k]``, ``uv[k]``: observation k is point ``pt[k]`` seen at
    pixel ``uv[k]`` by camera ``cam[k]``. ``intr_free`` (M, 9) and
    ``rot_free`` (M, 3) mark free intrinsics and rotation axes; ``centre_mode``
    (M,) holds `CentreMode` values; ``fisheye`` (M,) bool marks the cameras
    with the fisheye lens model (None: every camera is a pinhole).
    ``distances``: known distances between camera centres, residual rows
    weighted by ``distance_sigma_px`` (the pixel noise sigma,
    camnet.geometry.distances).
    """

    cam: np.ndarray
    pt: np.ndarray
    uv: np.ndarray
    intr_free: np.ndarray
    rot_free: np.ndarray
    centre_mode: np.ndarray
    baseline_m: float
    n_points: int
    distances: Distances = field(default_factory=Distances.none)
    distance_sigma_px: float = 1.0
    fisheye: np.ndarray | None = None

    def fisheye_rows(self, cam: np.ndarray) -> np.ndarray | None:
        """Per observation of cameras `cam`, whether its camera is a fisheye (None: none is)."""
        return None if self.fisheye is None else self.fisheye[cam]

    def intrinsic_names(self, m: int) -> tuple[str, ...]:
        """The names of camera m's intrinsic slots: its lens model's."""
        return FISHEYE_INTRINSIC_NAMES if self.fisheye is not None and self.fisheye[m] else INTRINSIC_NAMES

    @property
    def n_cameras(self) -> int:
        return len(self.centre_mode)

    def columns(self) -> tuple[np.ndarray, int]:
        """(M, 15) global column of each local camera slot (-1: held), and their count."""
        free = np.zeros((self.n_cameras, N_LOCAL), dtype=bool)
        free[:, :N_INTRINSICS] = self.intr_free
        free[:, ROT] = self.rot_free
        free[:, CEN] = (self.centre_mode == CentreMode.FREE)[:, None]
        free[self.centre_mode == CentreMode.ON_BASELINE, CEN.start : CEN.start + 2] = True
        cols = np.full(free.shape, -1)
        cols[free] = np.arange(free.sum())
        return cols, int(free.sum())

    @cached_property
    def camera_groups(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Cameras grouped by their free local slots, for the normal equations.

        Per group ``(slots (k,), cameras (c,), rows, starts (c,))``: the
        observations of its cameras that have any, sorted by camera, and where
        each camera's run begins in `rows`.
        """
        cols, _ = self.columns()
        counts = np.bincount(self.cam, minlength=self.n_cameras)
        patterns: dict[bytes, list[int]] = {}
        for m in np.flatnonzero((counts > 0) & np.any(cols >= 0, axis=1)):
            patterns.setdefault((cols[m] >= 0).tobytes(), []).append(int(m))
        order = np.argsort(self.cam, kind="stable")
        bounds = np.searchsorted(self.cam[order], np.arange(self.n_cameras + 1))
        groups = []
        for cams in patterns.values():
            rows = np.concatenate([order[bounds[m] : bounds[m + 1]] for m in cams])
            starts = np.concatenate([[0], np.cumsum(counts[cams])[:-1]])
            groups.append((np.flatnonzero(cols[cams[0]] >= 0), np.array(cams), rows, starts))
        return groups

    @cached_property
    def pairs_unique(self) -> bool:
        """Whether no camera observes a point twice."""
        return len(self.cam) == 0 or np.bincount(self.cam * self.n_points + self.pt).max() == 1

    @cached_property
    def point_sum(self) -> sp.csr_matrix:
        """(N, n) incidence matrix: summing per-observation terms into their points."""
        n = len(self.pt)
        return sp.csr_matrix((np.ones(n), (self.pt, np.arange(n))), shape=(self.n_points, n))

    def subset(self, keep: np.ndarray) -> Problem:
        """The same problem with only the observations where `keep` is true."""
        return replace(self, cam=self.cam[keep], pt=self.pt[keep], uv=self.uv[keep])


@dataclass(frozen=True)
class SolveInfo:
    converged: bool
    reason: str
    iterations: int
    initial_cost: float
    final_cost: float
    normal: NormalEquations | None = None  # at the final state, weighted by the loss (solve's `report`)


# ---------------------------------------------------------------- model evaluation


def residuals(problem: Problem, state: State) -> np.ndarray:
    """Reprojection residuals (n, 2), predicted minus observed, in pixels."""
    c = problem.cam
    uv, _ = project_points(state.intr[c], state.R[c], state.C[c], state.X[problem.pt], problem.fisheye_rows(c))
    return uv - problem.uv


def _cost(problem: Problem, state: State, loss: str, scale_px: float) -> float:
    r = residuals(problem, state)
    z = np.sum(r * r, axis=1) / scale_px**2
    rho, _ = robust_loss(z, loss)
    if not np.all(np.isfinite(rho)):
        return np.inf
    distance_px = problem.distances.weights_px_per_m(problem.distance_sigma_px) * problem.distances.errors_m(state.C)
    return 0.5 * scale_px**2 * float(np.sum(rho)) + 0.5 * float(distance_px @ distance_px)


def _centre_derivative(problem: Problem, state: State, m: int) -> np.ndarray:
    """(3, 3): how camera m's centre moves with its three centre slots (zero where held)."""
    mode = problem.centre_mode[m]
    if mode == CentreMode.FREE:
        return np.eye(3)
    D = np.zeros((3, 3))
    if mode == CentreMode.ON_BASELINE:
        D[:, :2] = problem.baseline_m * _tangent_basis(state.C[m] / np.linalg.norm(state.C[m]))
    return D


def distance_rows(
    problem: Problem, state: State, *, columns: tuple[np.ndarray, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The known distances' weighted residuals (B,), pixels, and their Jacobian (B, Pc) in the camera columns.

    Not robust: a known distance is no outlier. columns: another column
    layout (``Problem.columns()`` of a wider problem) to place the Jacobian in.
    """
    known = problem.distances
    cols, n_cols = problem.columns() if columns is None else columns
    w = known.weights_px_per_m(problem.distance_sigma_px)
    u = known.directions(state.C)
    J = np.zeros((len(known), n_cols))
    for k, (a, b) in enumerate(known.cams):
        for m, sign in ((a, 1.0), (b, -1.0)):
            c = cols[m, CEN]
            J[k, c[c >= 0]] += (sign * w[k] * u[k] @ _centre_derivative(problem, state, m))[c >= 0]
    return w * known.errors_m(state.C), J


def _tangent_basis(u: np.ndarray) -> np.ndarray:
    """Two orthonormal vectors (3, 2) orthogonal to the unit vector u."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(u[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    b1 = np.cross(u, helper)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(u, b1)], axis=1)


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


def _row_products(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A_k^T B_k for stacks of two-row matrices A (n, 2, i), B (n, 2, j): (n, i, j).

    Faster than a batched matmul for 3x3 results, slower for wider ones.
    """
    return A[:, 0, :, None] * B[:, 0, None, :] + A[:, 1, :, None] * B[:, 1, None, :]


def normal_equations(problem: Problem, state: State, *, loss: str = "linear", scale_px: float = 1.0) -> NormalEquations:
    """Gauss-Newton normal equations at `state`, rows weighted by the robust loss."""
    c, p = problem.cam, problem.pt
    n, N = len(c), problem.n_points
    uv, J_intr, J_rot, J_cen, J_pt = project_with_jacobians(
        state.intr[c], state.R[c], state.C[c], state.X[p], problem.fisheye_rows(c)
    )
    r = uv - problem.uv
    z = np.sum(r * r, axis=1) / scale_px**2
    rho, drho = robust_loss(z, loss)
    sw = np.sqrt(drho)[:, None]
    r = r * sw

    J_local = np.concatenate([J_intr, J_rot, J_cen], axis=2) * sw[:, :, None]
    J_pt = J_pt * sw[:, :, None]
    for m in np.flatnonzero(problem.centre_mode == CentreMode.ON_BASELINE):
        rows = c == m
        B = problem.baseline_m * _tangent_basis(state.C[m] / np.linalg.norm(state.C[m]))
        J_local[rows, :, CEN.start : CEN.start + 2] = J_local[rows, :, CEN] @ B
        J_local[rows, :, CEN.start + 2] = 0.0

    cols, n_cols = problem.columns()
    U = np.zeros((n_cols, n_cols))
    gc = np.zeros(n_cols)
    W = np.zeros((n_cols, N, 3))
    # An observation touches one camera only: U is block diagonal, one block per camera.
    # Cameras with the same free slots are handled together.
    for slots, cams, rows, starts in problem.camera_groups:
        cm = cols[cams][:, slots]  # (cameras, k)
        Jg = J_local[rows][:, :, slots]  # (n_g, 2, k), rows sorted by camera
        for c_m, (a, b) in zip(cm, zip(starts, [*starts[1:], len(rows)], strict=True), strict=True):
            flat = Jg[a:b].reshape(-1, len(slots))
            U[np.ix_(c_m, c_m)] = flat.T @ flat
        g = np.add.reduceat(Jg[:, 0] * r[rows, :1] + Jg[:, 1] * r[rows, 1:], starts, axis=0)
        gc[cm] = g
        # W[column, point, axis]: one term per observation, so an assignment unless a camera
        # sees a track twice (then the terms add up).
        obs_cols = np.repeat(cm, np.diff(np.append(starts, len(rows))), axis=0)  # (n_g, k)
        terms = Jg.transpose(0, 2, 1) @ J_pt[rows]  # (n_g, k, 3); a batched matmul beats _row_products here
        if problem.pairs_unique:
            W[obs_cols, p[rows][:, None]] = terms
        else:
            np.add.at(W, (obs_cols, p[rows][:, None]), terms)

    point_terms = np.concatenate(
        [_row_products(J_pt, J_pt).reshape(n, 9), J_pt[:, 0] * r[:, :1] + J_pt[:, 1] * r[:, 1:]], axis=1
    )
    summed = problem.point_sum @ point_terms
    V, gp = summed[:, :9], summed[:, 9:]
    r_dist, J_dist = distance_rows(problem, state)  # rows on camera columns only: U and gc
    return NormalEquations(
        U=U + J_dist.T @ J_dist,
        W=W.reshape(n_cols, 3 * N),
        V=V.reshape(N, 3, 3),
        gc=gc + J_dist.T @ r_dist,
        gp=gp,
        cost=0.5 * scale_px**2 * float(np.sum(rho)) + 0.5 * float(r_dist @ r_dist),
    )


def columns_within(problem: Problem, wider: Problem) -> np.ndarray:
    """The column of `wider` that holds each of `problem`'s free camera parameters."""
    own, _ = problem.columns()
    theirs, _ = wider.columns()
    free = own >= 0
    if np.any(theirs[free] < 0):
        raise ValueError("the wider problem holds a parameter the problem frees")
    within = np.empty(int(free.sum()), dtype=int)
    within[own[free]] = theirs[free]
    return within


def restrict(ne: NormalEquations, columns: np.ndarray) -> NormalEquations:
    """The normal equations with only the camera parameters at `columns` free."""
    return NormalEquations(ne.U[np.ix_(columns, columns)], ne.W[columns], ne.V, ne.gc[columns], ne.gp, ne.cost)


def times_block_diag(W: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """W (P, 3N) times the block-diagonal matrix of `blocks` (N, 3, 3)."""
    P, N = len(W), len(blocks)
    # optimize=True hands the products to BLAS: eight times faster than a batched matmul here.
    return np.einsum("pni,nij->pnj", W.reshape(P, N, 3), blocks, optimize=True).reshape(P, 3 * N)


def _solve_damped(ne: NormalEquations, lam: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Solve (H + lam diag H) d = -g by the Schur complement; None if not positive definite."""
    dU = np.diag(ne.U).copy()
    U = ne.U + np.diag(lam * np.maximum(dU, 1e-9))
    dV = np.einsum("nii->ni", ne.V)
    V = ne.V + (lam * np.maximum(dV, 1e-9))[:, :, None] * np.eye(3)
    try:
        Vinv = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return None
    WVinv = times_block_diag(ne.W, Vinv)
    S = U - WVinv @ ne.W.T
    rhs = -ne.gc + WVinv @ ne.gp.reshape(-1)
    try:
        dc = scipy.linalg.cho_solve(scipy.linalg.cho_factor(S), rhs) if len(rhs) else rhs
    except np.linalg.LinAlgError:
        return None
    dp = -np.einsum("nij,nj->ni", Vinv, ne.gp + (ne.W.T @ dc).reshape(-1, 3))
    if not (np.all(np.isfinite(dc)) and np.all(np.isfinite(dp))):
        return None
    return dc, dp


def apply_step(problem: Problem, state: State, dc: np.ndarray, dp: np.ndarray) -> State:
    """The state moved by a camera step `dc` (in `problem.columns()` order) and point step `dp`."""
    cols, _ = problem.columns()
    intr, R, C = state.intr.copy(), state.R.copy(), state.C.copy()
    for m in range(problem.n_cameras):
        cm = cols[m]
        d = np.where(cm >= 0, dc[np.maximum(cm, 0)] if len(dc) else 0.0, 0.0)
        intr[m] += d[:N_INTRINSICS]
        if np.any(d[ROT]):
            R[m] = rotation_exp(d[ROT]) @ R[m]
        mode = problem.centre_mode[m]
        if mode == CentreMode.FREE:
            C[m] += d[CEN]
        elif mode == CentreMode.ON_BASELINE:
            u = C[m] / np.linalg.norm(C[m])
            u = u + _tangent_basis(u) @ d[CEN.start : CEN.start + 2]
            C[m] = problem.baseline_m * u / np.linalg.norm(u)
    return State(intr, R, C, state.X + dp)


def _predicted_decrease(ne: NormalEquations, lam: float, dc: np.ndarray, dp: np.ndarray) -> float:
    """Decrease of the Gauss-Newton model cost along the damped step (dc, dp), >= 0."""
    # With (H + lam D) d = -g: -g.d - d.H.d / 2 = (lam d.D.d - g.d) / 2.
    dU = np.maximum(np.diag(ne.U), 1e-9)
    dV = np.maximum(np.einsum("nii->ni", ne.V), 1e-9)
    damped = lam * (float(dc @ (dU * dc)) + float(np.sum(dV * dp * dp)))
    return 0.5 * (damped - float(ne.gc @ dc) - float(np.sum(ne.gp * dp)))


def solve(
    problem: Problem,
    state: State,
    *,
    loss: str = "linear",
    scale_px: float = 1.0,
    max_iterations: int = 100,
    ftol: float = 1e-6,
    report: Problem | None = None,
) -> tuple[State, SolveInfo]:
    """Minimise the (robust) reprojection cost by Levenberg-Marquardt from `state`.

    Damping by Nielsen's rule (the gain ratio of actual to predicted
    decrease), starting almost undamped. It stops when the cost is exact to
    rounding, or when an undamped Gauss-Newton step promises to lower it by
    less than ``ftol`` relative: near the minimum that promise is kept to
    rounding, and a small decrease under heavy damping is no minimum.

    report: the same observations with more camera parameters free than
    `problem` (a superset); SolveInfo.normal is then its normal equations at
    the solution, for a covariance over parameters the solve held. They are
    built in place of the solve's own after each step, which they contain,
    so a solve of one or two steps gets them almost free.
    """
    lam, nu = GAUSS_NEWTON_LAMBDA, 2.0
    within = None if report is None else columns_within(problem, report)

    def equations(at: State) -> tuple[NormalEquations, NormalEquations | None]:
        """The solve's normal equations at `at`, and report's (None without one)."""
        if within is None:
            return normal_equations(problem, at, loss=loss, scale_px=scale_px), None
        wide = normal_equations(report, at, loss=loss, scale_px=scale_px)
        return restrict(wide, within), wide

    ne = normal_equations(problem, state, loss=loss, scale_px=scale_px)
    wide = None  # report's normal equations at `state`, once a step has built them
    initial = ne.cost
    if not np.isfinite(initial):
        return state, SolveInfo(False, "the initial state projects points behind a camera", 0, initial, initial)
    exact_cost = 0.5 * len(problem.cam) * 1e-18  # residuals of 1e-9 px: rounding
    reason, converged = "reached the iteration limit", False
    iterations = 0
    gauss_newton_step = None  # the convergence check's step at the current state, reused when lam is as small
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported after the loop)
        if ne.cost <= exact_cost:
            reason, converged = "the observations are fitted exactly", True
            break
        if gauss_newton_step is not None and lam <= GAUSS_NEWTON_LAMBDA:
            step, step_lam = gauss_newton_step, GAUSS_NEWTON_LAMBDA
        else:
            step, step_lam = _solve_damped(ne, lam), lam
        gauss_newton_step = None
        if step is None:
            lam, nu = lam * nu, 2.0 * nu
            if lam > 1e12:
                reason = "the normal equations are singular (the geometry does not fix the parameters)"
                break
            continue
        trial = apply_step(problem, state, *step)
        trial_cost = _cost(problem, trial, loss, scale_px)
        decrease = ne.cost - trial_cost
        if decrease > 0:
            gain = decrease / max(_predicted_decrease(ne, step_lam, *step), 1e-300)
            state = trial
            ne, wide = equations(state)
            lam, nu = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-12), 2.0
            gauss_newton_step, small = _gauss_newton_test(ne, ftol, decrease=decrease, lam=lam)
            if small:
                reason, converged = "a Gauss-Newton step would lower the cost by less than ftol (relative)", True
                break
        else:
            lam, nu = lam * nu, 2.0 * nu
            if lam > 1e10:
                reason, converged = "no step decreases the cost further", True
                break
    if report is not None and wide is None:  # no step was taken
        wide = normal_equations(report, state, loss=loss, scale_px=scale_px)
    return state, SolveInfo(converged, reason, iterations, initial, ne.cost, ne if report is None else wide)


def _gauss_newton_decrease(ne: NormalEquations, step: tuple[np.ndarray, np.ndarray] | None) -> float:
    return np.inf if step is None else _predicted_decrease(ne, GAUSS_NEWTON_LAMBDA, *step)


def _gauss_newton_test(
    ne: NormalEquations, ftol: float, *, decrease: float, lam: float
) -> tuple[tuple[np.ndarray, np.ndarray] | None, bool]:
    """solve's convergence test after a step: the undamped step at the new state, and whether it
    promises to lower the cost by at most ``ftol`` relative (then the solve has converged).

    The step is returned so that the next iteration, if it is as undamped, need not solve again;
    `decrease` (the step's actual decrease) and `lam` are only logged.
    """
    step = _solve_damped(ne, GAUSS_NEWTON_LAMBDA)
    remaining = _gauss_newton_decrease(ne, step)
    log.debug(
        "LM: cost %.9g (-%.3g), lambda %.2g, a Gauss-Newton step would gain %.3g", ne.cost, decrease, lam, remaining
    )
    return step, remaining <= ftol * ne.cost


def gauss_newton_decrease(ne: NormalEquations) -> float:
    """The decrease an (almost) undamped step promises; infinite if it cannot be solved."""
    return _gauss_newton_decrease(ne, _solve_damped(ne, GAUSS_NEWTON_LAMBDA))
