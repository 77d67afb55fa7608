"""Bundle adjustment with a rigid, known-baseline stereo pair.

Levenberg-Marquardt on reprojection error with the points eliminated by the
Schur complement, so that each step costs a dense solve of the camera
parameters only (a few hundred unknowns even for 16 cameras) plus one 3x3
inverse per point. The Jacobian is analytic (`camnet.model.projection`).

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
import scipy.sparse as sp

from camnet.model.methods import Loss
from camnet.model.projection import (
    FISHEYE_INTRINSIC_NAMES,
    INTRINSIC_NAMES,
    N_INTRINSICS,
    project_points,
    project_with_jacobians,
    rotation_exp,
)
from camnet.solve.known_distances import Distances
from camnet.solve.losses import robust_loss
from camnet.solve.observation_order import camera_by_camera
from camnet.solve.schur import (
    GAUSS_NEWTON_LAMBDA,
    NormalEquations,
    PointsEliminated,
    eliminate_points,
    gauss_newton_test,
    predicted_decrease,
    restrict,
    solve_damped,
)

# Local parameter slots of a camera: intrinsics (9), rotation (3), centre (3).
ROT = slice(N_INTRINSICS, N_INTRINSICS + 3)
CEN = slice(N_INTRINSICS + 3, N_INTRINSICS + 6)
N_LOCAL = N_INTRINSICS + 6

log = logging.getLogger(__name__)

_POINT_ITEM = np.dtype((np.void, 24))  # three float64: W's entries of one camera column and one point
# Rows of observations whose Jacobians the normal equations form at a time: their temporaries (a few
# hundred kB) are reused from the heap, where those of all rows at once (megabytes) are fresh memory on
# every call, which the kernel maps and zeroes page by page at a cost of the arithmetic's order
# (docs/benchmarks.md, "Evidence behind the solver's thresholds").
BLOCK_ROWS = 2048


class CentreMode(enum.IntEnum):
    """How a camera's centre moves in the adjustment (values of `Problem.centre_mode`)."""

    FIXED = 0  # held: the left stereo camera, which fixes the frame
    FREE = 1  # three coordinates
    ON_BASELINE = 2  # on the sphere of radius baseline_m about the left camera: two angles


@dataclass(frozen=True)
class State:
    """Parameters of a network: per camera intrinsics and pose, per track a point."""

    intr: np.ndarray  # (M, 9) see camnet.model.projection
    R: np.ndarray  # (M, 3, 3) world -> camera rotation
    C: np.ndarray  # (M, 3) camera centres, metres
    X: np.ndarray  # (N, 3) points, metres

    def copy(self) -> State:
        return State(self.intr.copy(), self.R.copy(), self.C.copy(), self.X.copy())


@dataclass(frozen=True)
class Layout:
    """A problem's observations reordered for its normal equations.

    Cameras with the same free local slots form a group; the observations
    come group by group and, within a group, camera by camera (those of
    cameras with nothing free last), so that each camera's and each group's
    rows are one slice. Per group ``(intrinsic slots, rotation slots, centre
    slots, cameras)``; ``runs[m]``: camera m's rows [start, stop). ``blocks``:
    ``(group, cameras, start, stop)``, the rows in runs of whole cameras of one
    group (group -1: cameras with nothing free) of at most BLOCK_ROWS rows (or
    one camera's), which the normal equations take one at a time.
    """

    order: np.ndarray  # (n,) observation index of each row
    cam: np.ndarray  # (n,)
    pt: np.ndarray  # (n,)
    uv: np.ndarray  # (n, 2) pixels
    runs: np.ndarray  # (M, 2)
    groups: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    pairs_unique: bool  # no camera observes a point twice
    point_sum: sp.csr_matrix  # (N, n) summing per-row terms into their points
    blocks: list[tuple[int, np.ndarray, int, int]]


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
    camnet.solve.known_distances).
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
        """(M, 15) global column of each local camera slot (-1: held, read-only), and their count."""
        return self._columns

    @cached_property
    def _columns(self) -> tuple[np.ndarray, int]:
        free = np.zeros((self.n_cameras, N_LOCAL), dtype=bool)
        free[:, :N_INTRINSICS] = self.intr_free
        free[:, ROT] = self.rot_free
        free[:, CEN] = (self.centre_mode == CentreMode.FREE)[:, None]
        free[self.centre_mode == CentreMode.ON_BASELINE, CEN.start : CEN.start + 2] = True
        cols = np.full(free.shape, -1)
        cols[free] = np.arange(free.sum())
        cols.setflags(write=False)  # shared by every caller
        return cols, int(free.sum())

    @cached_property
    def layout(self) -> Layout:
        """The observations in the order the normal equations take them (see `Layout`)."""
        cols, _ = self.columns()
        counts = np.bincount(self.cam, minlength=self.n_cameras)
        patterns: dict[bytes, list[int]] = {}
        for m in np.flatnonzero((counts > 0) & np.any(cols >= 0, axis=1)):
            patterns.setdefault((cols[m] >= 0).tobytes(), []).append(int(m))
        grouped = [m for cams in patterns.values() for m in cams]
        cameras = grouped + [m for m in range(self.n_cameras) if m not in set(grouped)]
        order, runs, point_sum = self._ordered(tuple(cameras))
        groups = []
        for cams in patterns.values():
            slots = np.flatnonzero(cols[cams[0]] >= 0)
            groups.append((slots[slots < ROT.start], slots[(slots >= ROT.start) & (slots < CEN.start)] - ROT.start,
                           slots[slots >= CEN.start] - CEN.start, np.array(cams)))
        rest = [m for m in cameras[len(grouped) :] if counts[m]]
        blocks = _blocks([g[3] for g in groups] + [np.array(rest, dtype=int)], runs)
        return Layout(order, self.cam[order], self.pt[order], self.uv[order], runs, groups, self._pairs_unique,
                      point_sum, blocks)

    def freeing(self, **free: np.ndarray) -> Problem:
        """The same observations with other parameters free (``intr_free``, ``rot_free``, ``centre_mode``).

        It shares the observations' orderings (`_ordered`) with this problem, so that the normal
        equations of both (a solve's and its report's) sort the observations once.
        """
        if not set(free) <= {"intr_free", "rot_free", "centre_mode"}:
            raise ValueError(f"freeing: {sorted(free)} are not free-parameter masks")
        other = replace(self, **free)
        other.__dict__["_orderings"] = self._orderings
        other.__dict__["_pairs_unique"] = self._pairs_unique
        return other

    @cached_property
    def _orderings(self) -> dict[tuple[int, ...], tuple[np.ndarray, np.ndarray, sp.csr_matrix]]:
        """`_ordered`'s results by sequence of cameras: they depend on the observations alone."""
        return {}

    @cached_property
    def _pairs_unique(self) -> bool:
        """No camera observes a point twice."""
        return len(self.cam) == 0 or np.bincount(self.cam * self.n_points + self.pt).max() == 1

    def _ordered(self, cameras: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
        """(order, runs, point_sum) of `Layout` for the observations taken camera by camera in `cameras`."""
        if cameras not in self._orderings:
            self._orderings[cameras] = camera_by_camera(self.cam, self.pt, self.n_cameras, self.n_points, cameras)
        return self._orderings[cameras]

    @cached_property
    def by_point(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, starts): the observations sorted by point (stably), and where each point's run of
        rows starts (N + 1,): point j's observations are ``rows[starts[j]:starts[j + 1]]``."""
        rows = np.argsort(self.pt, kind="stable")
        return rows, np.searchsorted(self.pt[rows], np.arange(self.n_points + 1))

    def subset(self, keep: np.ndarray) -> Problem:
        """The same problem with only the observations where `keep` is true."""
        return replace(self, cam=self.cam[keep], pt=self.pt[keep], uv=self.uv[keep])


def _blocks(groups: list[np.ndarray], runs: np.ndarray) -> list[tuple[int, np.ndarray, int, int]]:
    """`Layout.blocks` from each group's cameras (the last entry: the cameras with nothing free) and their runs."""
    blocks = []
    for g, cams in enumerate(groups):
        group = g if g < len(groups) - 1 else -1
        start = 0
        for i in range(1, len(cams) + 1):
            if i == len(cams) or runs[cams[i], 1] - runs[cams[start], 0] > BLOCK_ROWS:
                blocks.append((group, cams[start:i], int(runs[cams[start], 0]), int(runs[cams[i - 1], 1])))
                start = i
    return blocks


@dataclass(frozen=True)
class SolveInfo:
    converged: bool
    reason: str
    iterations: int
    initial_cost: float
    final_cost: float
    normal: NormalEquations | None = None  # at the final state, weighted by the loss (solve's `report`)
    eliminated: PointsEliminated | None = None  # normal's points eliminated, where the convergence test did


# ---------------------------------------------------------------- model evaluation


def residuals(problem: Problem, state: State) -> np.ndarray:
    """Reprojection residuals (n, 2), predicted minus observed, in pixels."""
    c = problem.cam
    uv, _ = project_points(state.intr[c], state.R[c], state.C[c], state.X[problem.pt], problem.fisheye_rows(c))
    return uv - problem.uv


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


def normal_equations(problem: Problem, state: State, *, loss: str = "linear", scale_px: float = 1.0) -> NormalEquations:
    """Gauss-Newton normal equations at `state`, rows weighted by the robust loss."""
    lay = problem.layout
    N, n = problem.n_points, len(lay.cam)
    distortion = any(np.any(si >= INTRINSIC_NAMES.index("k1")) for si, *_ in lay.groups)
    cols, n_cols = problem.columns()
    U = np.zeros((n_cols, n_cols))
    gc = np.zeros(n_cols)
    W = np.zeros((n_cols, N, 3))
    W_items = W.view(_POINT_ITEM)[:, :, 0]  # (n_cols, N)
    rho = np.empty(n)
    point_terms = np.empty((n, 12))
    for g, cams, a, b in lay.blocks:
        c, p = lay.cam[a:b], lay.pt[a:b]
        uv, J_intr, J_rot, J_cen, J_pt = project_with_jacobians(
            state.intr[c], state.R[c], state.C[c], state.X[p], problem.fisheye_rows(c), distortion=distortion)
        r = uv - lay.uv[a:b]
        z = (r[:, 0] * r[:, 0] + r[:, 1] * r[:, 1]) / scale_px**2
        rho[a:b], drho = robust_loss(z, loss)
        sw = None if loss == Loss.LINEAR else np.sqrt(drho)[:, None, None]  # rho' = 1: the rows as they are
        if sw is not None:
            r, J_pt = r * sw[:, :, 0], J_pt * sw
        # Per row J_pt^T [J_pt | r]: J_pt^T J_pt (3x3) beside J_pt^T r, in one batched matmul.
        point_terms[a:b] = (J_pt.transpose(0, 2, 1) @ np.concatenate([J_pt, r[:, :, None]], axis=2)).reshape(-1, 12)
        if g >= 0:
            _camera_terms(problem, state, lay.groups[g][:3], cams, (a, r, J_intr, J_rot, J_cen, J_pt, sw),
                          U, gc, W, W_items)
    summed = lay.point_sum @ point_terms
    r_dist, J_dist = distance_rows(problem, state)  # rows on camera columns only: U and gc
    return NormalEquations(
        U=U + J_dist.T @ J_dist,
        W=W.reshape(n_cols, 3 * N),
        V=np.ascontiguousarray(summed.reshape(N, 3, 4)[:, :, :3]),
        gc=gc + J_dist.T @ r_dist,
        gp=np.ascontiguousarray(summed.reshape(N, 3, 4)[:, :, 3]),
        cost=0.5 * scale_px**2 * float(np.sum(rho)) + 0.5 * float(r_dist @ r_dist),
    )


def _camera_terms(problem: Problem, state: State, slots, cams: np.ndarray, rows, U, gc, W, W_items) -> None:
    """Add the camera terms of a block of rows (`Layout.blocks`) to U, gc and W, in place.

    slots: the group's free (intrinsic, rotation, centre) slots; rows: (its
    first row, then its residuals and Jacobians, weighted but for Jg, and the
    rows' weights or None).
    """
    lay = problem.layout
    cols = problem.columns()[0]
    a, r, J_intr, J_rot, J_cen, J_pt, sw = rows
    si, sr, sc = slots
    for m in cams:
        if problem.centre_mode[m] == CentreMode.ON_BASELINE:
            s, e = lay.runs[m] - a
            B = problem.baseline_m * _tangent_basis(state.C[m] / np.linalg.norm(state.C[m]))
            J_cen[s:e, :, :2] = J_cen[s:e] @ B
            J_cen[s:e, :, 2] = 0.0
    # An observation touches one camera only: U is block diagonal, one block per camera, and
    # a camera's free columns are consecutive. Cameras with the same free slots go together.
    Jg = np.concatenate([J_intr[:, :, si], J_rot[:, :, sr], J_cen[:, :, sc]], axis=2)
    if sw is not None:
        Jg *= sw
    k = Jg.shape[2]
    terms = Jg.transpose(0, 2, 1) @ J_pt  # (n_b, k, 3): a batched matmul
    # Each (column, point) entry of W as one 24-byte item: the scatter below copies whole
    # items, twice as fast as three doubles at a time.
    items = terms.view(_POINT_ITEM)[:, :, 0].T  # (k, n_b)
    p = lay.pt
    for m in cams:
        s, e = lay.runs[m]
        c0 = cols[m][cols[m] >= 0][0]
        flat = Jg[s - a : e - a].reshape(-1, k)
        U[c0 : c0 + k, c0 : c0 + k] = flat.T @ flat
        gc[c0 : c0 + k] = flat.T @ r[s - a : e - a].reshape(-1)
        # W[column, point, axis]: one term per observation, so an assignment unless a camera
        # sees a track twice (then the terms add up).
        if lay.pairs_unique:
            W_items[c0 : c0 + k, p[s:e]] = items[:, s - a : e - a]
        else:
            np.add.at(W[c0 : c0 + k], (slice(None), p[s:e]), terms[s - a : e - a].transpose(1, 0, 2))


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


def apply_step(problem: Problem, state: State, dc: np.ndarray, dp: np.ndarray) -> State:
    """The state moved by a camera step `dc` (in `problem.columns()` order) and point step `dp`."""
    cols, _ = problem.columns()
    d = np.where(cols >= 0, dc[np.maximum(cols, 0)] if len(dc) else 0.0, 0.0)  # (M, 15) local steps
    intr, R, C = state.intr + d[:, :N_INTRINSICS], state.R.copy(), state.C.copy()
    turning = np.any(d[:, ROT] != 0, axis=1)
    R[turning] = rotation_exp(d[turning, ROT]) @ R[turning]
    free = problem.centre_mode == CentreMode.FREE
    C[free] += d[free, CEN]
    for m in np.flatnonzero(problem.centre_mode == CentreMode.ON_BASELINE):
        u = C[m] / np.linalg.norm(C[m])
        u = u + _tangent_basis(u) @ d[m, CEN.start : CEN.start + 2]
        C[m] = problem.baseline_m * u / np.linalg.norm(u)
    return State(intr, R, C, state.X + dp)


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
    so a solve of one or two steps gets them almost free; the convergence
    test after each step takes its step from their points eliminated
    (SolveInfo.eliminated, which the covariance takes).
    """
    lam, nu = GAUSS_NEWTON_LAMBDA, 2.0
    within = None if report is None else columns_within(problem, report)

    def own(built: NormalEquations, spare: np.ndarray) -> NormalEquations:
        """The solve's normal equations from those built at a step taken (report's, where there is one). Their
        W goes into `spare`, the W of the solve's equations before the step, which nothing uses any more."""
        return built if within is None else restrict(built, within, out=spare)

    ne = normal_equations(problem, state, loss=loss, scale_px=scale_px)
    wide = eliminated = None  # report's normal equations at `state` once a step has built them; their points eliminated
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
        step, step_lam = _next_step(ne, lam, gauss_newton_step, own=eliminated is None)
        gauss_newton_step = None
        if step is None:
            lam, nu = lam * nu, 2.0 * nu
            if lam > 1e12:
                reason = "the normal equations are singular (the geometry does not fix the parameters)"
                break
            continue
        trial = apply_step(problem, state, *step)
        # The normal equations at the trial carry its cost: nearly every step is taken, and
        # then they are needed, so building them first saves evaluating the cost apart.
        built = normal_equations(problem if report is None else report, trial, loss=loss, scale_px=scale_px)
        decrease = ne.cost - built.cost
        if decrease > 0:
            gain = decrease / max(predicted_decrease(ne, step_lam, *step), 1e-300)
            state, ne, wide = trial, own(built, ne.W), None if report is None else built
            lam, nu = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-12), 2.0
            eliminated = None if wide is None else eliminate_points(wide)
            gauss_newton_step, remaining, small = gauss_newton_test(ne, ftol, eliminated=eliminated, within=within)
            log.debug("LM: cost %.9g (-%.3g), lambda %.2g, Gauss-Newton gain %.3g", ne.cost, decrease, lam, remaining)
            if small:
                reason, converged = f"another step would lower the cost by less than {ftol:g} of it", True
                break
        else:
            lam, nu = lam * nu, 2.0 * nu
            if lam > 1e10:
                reason, converged = "no step decreases the cost further", True
                break
    if report is not None and wide is None:  # no step was taken
        wide = normal_equations(report, state, loss=loss, scale_px=scale_px)
    return state, SolveInfo(converged, reason, iterations, initial, ne.cost, ne if report is None else wide, eliminated)


def _next_step(ne: NormalEquations, lam: float, tested, *, own: bool) -> tuple[tuple | None, float]:
    """solve's next step at `ne` and its damping: `tested`, the convergence test's step at the same state (or
    None), where lam is as small and it is the solve's own (`own`: its points damped as the solve damps them;
    along a nearly flat valley a step with them undamped parts from it by far more than the damping)."""
    if tested is not None and lam <= GAUSS_NEWTON_LAMBDA:
        return (tested if own else solve_damped(ne, GAUSS_NEWTON_LAMBDA)), GAUSS_NEWTON_LAMBDA
    return solve_damped(ne, lam), lam
