"""From observations to a metric calibration.

Methods:

- ``paper``: the paper's solver alone (stereo triangulation, eq. 13); the
  principal points as given or at the image centre, no distortion.
- ``refined`` (default): the paper's solution, extended to every camera and
  track, then a bundle adjustment that keeps the stereo pair rigid with its
  baseline exactly ``baseline_m``, with a robust loss, outlier rejection
  and the free-intrinsics rule below.
- ``unconstrained``: the same adjustment with the right camera free in 3-D,
  as classical structure from motion: the scale is left to the optimiser.

Which intrinsics move (``free="auto"``): the focal length of every camera
always (unless the observations fix K), and the pose of every camera outside
the stereo pair. Then, in this order, each block is freed when the data
determine it, i.e. when its standard deviation, with it and the blocks
before it free, moves the image by at most ``determined_px`` pixels, or when
the data ask for it, i.e. when freeing it lowers the cost by more than
chance allows (a chi-square score test at false-alarm rate
``significance``, on the a-posteriori pixel variance): the right stereo
camera's pitch and roll, the direction of its baseline, its yaw, the
principal points, k1, k2 (the last three camera by camera). A block that is
neither is held at its given value (K and dist in the observations) or the
ideal (image centre, no distortion, a parallel pair). Outliers are judged
before the rule with the stereo pair free to turn. An explicit ``free`` set
replaces the rule.

Warm starts (``initial=``) reuse the previous solution's points and free
parameters; when every camera still fits its observations only the new
tracks get a robust fit before the least-squares adjustment
(``diagnostics.start`` says which path ran). ``reset_cameras`` places
bumped cameras again (see `calibrate`).
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Collection
from dataclasses import dataclass, field, replace

import numpy as np

from camnet.errors import SolveError
from camnet.geometry import bundle
from camnet.geometry.bundle import CENTRE_FIXED, CENTRE_FREE, CENTRE_ON_BASELINE, Problem, State
from camnet.geometry.camera import Camera
from camnet.geometry.initialise import (
    Start,
    camera_order,
    centred,
    initial_intrinsics,
    observation_rows,
    paper_start,
    warm_start,
)
from camnet.geometry.projection import K_from_intrinsics, project_points
from camnet.geometry.uncertainty import Covariance, covariance, residual_dof
from camnet.io.formats import Calibration, Observations

log = logging.getLogger(__name__)

METHODS = ("paper", "refined", "unconstrained")
FREE_NAMES = ("f", "aspect", "pp", "k1", "k2", "stereo_rotation", "stereo_direction")
MIN_SHARED_TRACKS = 4  # eq. 15: N >= 4 points seen by the pair and another camera
MIN_CAMERA_INLIERS = 6  # fewer observations cannot fix a camera's pose and focal length


@dataclass(frozen=True)
class Options:
    method: str = "refined"
    loss: str = "cauchy"  # robust loss of the first adjustment
    loss_scale_px: float = 2.0
    free: str | frozenset[str] = "auto"  # "auto" or a subset of FREE_NAMES
    determined_px: float = 1.0
    significance: float = 1e-3  # false-alarm rate of the auto rule's chi-square test
    outlier_sigmas: float = 4.0  # reject residuals beyond this many robust sigmas
    min_outlier_px: float = 1.5  # never reject residuals below this
    max_iterations: int = 300  # LM stops on the Gauss-Newton decrement long before this in most solves
    # 1 sigma of a guessed principal point about the image centre, as a fraction of the image size,
    # in the reported uncertainty (see `_uncertainty`); 0 reports sigmas conditional on the guess.
    pp_prior_rel: float = 0.01
    seed: int = 0


@dataclass
class Result:
    calibration: Calibration
    state: State  # cameras in problem order: left, right, then the others
    problem: Problem  # inlier observations
    order: list[int]  # problem camera m is observations camera order[m]
    track_rows: np.ndarray  # problem point j is track row track_rows[j]
    covariance: Covariance | None
    converged: bool
    reason: str
    timings_s: dict[str, float] = field(default_factory=dict)


# ---------------------------------------------------------------- validation


def check_solvable(obs: Observations) -> None:
    """Refuse observations that cannot determine a metric network (eq. 15)."""
    if len(obs.cameras) < 3:
        raise SolveError(f"cameras: {len(obs.cameras)} given; a metric solve needs at least 3 (eq. 15)")
    order = camera_order(obs)
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), dtype=bool)
    seen[obs.track_index, obs.cam_index] = True
    pair = seen[:, order[0]] & seen[:, order[1]]
    shared = pair & seen[:, order[2:]].any(axis=1)
    if shared.sum() < MIN_SHARED_TRACKS:
        raise SolveError(
            f"tracks: only {int(shared.sum())} tracks are seen by the stereo pair "
            f"({obs.stereo.left}, {obs.stereo.right}) and another camera; need at least "
            f"{MIN_SHARED_TRACKS}"
        )


# ---------------------------------------------------------------- the adjustment


def _free_mask(problem_cams: int, names: frozenset[str], fixed_K: np.ndarray, fixed_dist: np.ndarray):
    intr_free = np.zeros((problem_cams, 9), dtype=bool)
    intr_free[:, 0] = "f" in names
    intr_free[:, 1] = "aspect" in names
    intr_free[:, 2:4] = "pp" in names
    intr_free[:, 4] = "k1" in names
    intr_free[:, 5] = "k2" in names
    intr_free[fixed_K, :4] = False
    intr_free[fixed_dist, 4:] = False
    return intr_free


def _problem(obs, order, rows_kept, track_rows, intr_free, rot_free, right_centre) -> Problem:
    m_of = np.empty(len(obs.cameras), dtype=int)
    m_of[order] = np.arange(len(order))
    pt_of = np.full(len(obs.track_ids), -1)
    pt_of[track_rows] = np.arange(len(track_rows))
    centre_mode = np.full(len(order), CENTRE_FREE)
    centre_mode[0] = CENTRE_FIXED
    centre_mode[1] = right_centre
    rot_free = rot_free.copy()
    rot_free[0] = False
    return Problem(
        cam=m_of[obs.cam_index[rows_kept]],
        pt=pt_of[obs.track_index[rows_kept]],
        uv=obs.uv[rows_kept],
        intr_free=intr_free,
        rot_free=rot_free,
        centre_mode=centre_mode,
        baseline_m=obs.stereo.baseline_m,
        n_points=len(track_rows),
    )


def _reject_outliers(problem: Problem, state: State, options: Options) -> np.ndarray:
    """Observations to keep: residual within outlier_sigmas robust sigmas, tracks with >= 2 views."""
    r = np.linalg.norm(bundle.residuals(problem, state), axis=1)
    # For Gaussian noise of sigma per axis, the median of |r| is 1.1774 sigma.
    sigma = np.median(r) / 1.1774
    keep = r <= max(options.outlier_sigmas * sigma, options.min_outlier_px)
    views = np.bincount(problem.pt[keep], minlength=problem.n_points)
    return keep & (views[problem.pt] >= 2)


def _pixel_effect(name: str, state: State, cov: Covariance, widths, heights) -> float | np.ndarray:
    """Standard deviation, in pixels, of a candidate block's effect on the image."""
    cols = cov.columns
    sd = np.sqrt(np.maximum(np.diag(cov.cameras), 0.0))

    def sigma(m: int, *slots: int) -> float:
        return max(float(sd[cols[m, s]]) if cols[m, s] >= 0 else np.nan for s in slots)

    f = state.intr[:, 0]
    cams = range(len(f))
    r_max = np.hypot(np.asarray(widths) / 2, np.asarray(heights) / 2) / f
    if name == "stereo_pitch_roll":
        return f[1] * sigma(1, 9, 11)
    if name == "stereo_yaw":
        return f[1] * sigma(1, 10)
    if name == "stereo_direction":  # a sideways shift of l * angle, seen at the typical depth
        return f[1] * sigma(1, 12, 13) * np.linalg.norm(state.C[1]) / np.median(state.X[:, 2])
    if name == "pp":
        return np.array([sigma(m, 2, 3) for m in cams])
    if name == "k1":
        return np.array([f[m] * r_max[m] ** 3 * sigma(m, 4) for m in cams])
    return np.array([f[m] * r_max[m] ** 5 * sigma(m, 5) for m in cams])


_CANDIDATES = ("stereo_pitch_roll", "stereo_direction", "stereo_yaw", "pp", "k1", "k2")
_SLOTS = {"pp": (2, 3), "k1": (4,), "k2": (5,)}


def _with_block(problem: Problem, name: str, cameras: np.ndarray) -> Problem:
    """`problem` with the candidate block `name` also free (for `cameras` (M,) bool, per-camera blocks)."""
    intr_free, rot_free, centre_mode = problem.intr_free.copy(), problem.rot_free.copy(), problem.centre_mode.copy()
    if name == "stereo_pitch_roll":
        rot_free[1, [0, 2]] = True
    elif name == "stereo_direction":
        centre_mode[1] = CENTRE_ON_BASELINE
    elif name == "stereo_yaw":
        rot_free[1, 1] = True
    else:
        for s in _SLOTS[name]:
            intr_free[cameras, s] = True
    return replace(problem, intr_free=intr_free, rot_free=rot_free, centre_mode=centre_mode)


def _choose_free(problem: Problem, state: State, options: Options, widths, heights, held_K, held_dist):
    """Apply the free-parameter rule of the module docstring; returns (problem, decisions).

    `state` is the least-squares solution of `problem`. Both tests are
    linearised at it: the standard deviation from the covariance with the
    block free, the cost decrease from the Gauss-Newton step with it free
    (the score test, first-order equal to the likelihood ratio).
    """
    from scipy.special import chdtri

    M = problem.n_cameras
    can_move = {
        "pp": ~held_K,
        "k1": ~held_dist,
        "k2": ~held_dist,
    }
    # A block's Jacobian does not depend on which other blocks are free: one set of
    # normal equations with every candidate free serves every trial.
    everything = problem
    for name in _CANDIDATES:
        everything = _with_block(everything, name, can_move.get(name, np.ones(M, bool)))
    ne = bundle.normal_equations(everything, state)
    columns = everything.columns()[0]

    def restricted(trial: Problem):
        return bundle.restrict(ne, columns[trial.columns()[0] >= 0])

    variance = 2.0 * ne.cost / max(residual_dof(problem), 1)  # a posteriori pixel variance

    def significant(trial: Problem, base_decrease: float, k: int) -> tuple[bool, float]:
        """Whether freeing the trial's new block lowers the cost beyond chance (chi-square, k dof)."""
        statistic = 2.0 * (bundle.gauss_newton_decrease(restricted(trial)) - base_decrease) / max(variance, 1e-300)
        # An infinite decrease means the block is not determined at all: no evidence for it.
        wanted = variance > 1e-12 and np.isfinite(statistic) and statistic > chdtri(k, options.significance)
        return bool(wanted), statistic

    decisions = []
    for name in _CANDIDATES:
        base = bundle.gauss_newton_decrease(restricted(problem))
        movable = can_move.get(name, np.ones(M, bool))
        trial = _with_block(problem, name, movable)
        try:
            effect = _pixel_effect(name, state, covariance(trial, state, normal=restricted(trial)), widths, heights)
        except np.linalg.LinAlgError:  # the block is not fixed at all by these observations
            effect = np.inf if name.startswith("stereo") else np.full(M, np.inf)
        if name.startswith("stereo"):
            k = int(trial.columns()[1] - problem.columns()[1])
            wanted, statistic = significant(trial, base, k)
            free = effect <= options.determined_px or wanted
            if free:
                problem = trial
            decisions.append(
                f"{name}: {'free' if free else 'held'} (sigma {effect:.2g} px, chi2 {statistic:.3g} on {k} dof)"
            )
            continue
        k = len(_SLOTS[name])
        determined = np.isfinite(effect) & (effect <= options.determined_px) & movable
        wanted = np.zeros(M, bool)
        if significant(trial, base, k * int(movable.sum()))[0]:  # the block as a whole; then camera by camera
            for m in np.flatnonzero(movable & ~determined):
                wanted[m] = significant(_with_block(problem, name, np.arange(M) == m), base, k)[0]
        problem = _with_block(problem, name, determined | wanted)
        decisions.append(
            f"{name}: sigma px per camera {np.round(effect, 2).tolist()}; "
            f"freed by significance {[m for m in np.flatnonzero(wanted & ~determined).tolist()]}"
        )
    return problem, decisions


@functools.cache
def _blas_controller():
    """The BLAS libraries loaded (numpy's, scipy's), found once: a search costs milliseconds."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def calibrate(
    obs: Observations,
    options: Options = Options(),
    *,
    initial: Calibration | None = None,
    reset_cameras: Collection[str] = (),
) -> Result:
    """Solve the network described by `obs`. Raises SolveError when it cannot.

    initial: a previous calibration of the same rig to start from (a warm
    start): its cameras, its points, its free parameters; only new tracks
    are triangulated and, when every camera still fits its observations,
    only they get the robust pass.
    reset_cameras: ids of cameras whose pose in `initial` is no longer
    trusted (a camera that was bumped). A non-stereo camera keeps only its
    intrinsics and is placed again by PnP RANSAC on the points the other
    cameras determine, before the joint adjustment. Resetting a stereo
    camera moves the frame and the scale of every point, so it falls back
    to a cold solve. Ignored without `initial`.
    """
    try:
        # The dense products here have a few hundred rows: BLAS threads gain little on
        # them, and on a machine shared with drivers and the matcher they stall each other.
        with _blas_controller().limit(limits=1, user_api="blas"):
            return _calibrate(obs, options, initial, reset_cameras)
    except np.linalg.LinAlgError:
        raise SolveError("the observations do not determine the calibration (singular equations)") from None


def _calibrate(
    obs: Observations, options: Options, initial: Calibration | None, reset_cameras: Collection[str]
) -> Result:
    if options.method not in METHODS:
        raise SolveError(f"method: unknown {options.method!r}; expected one of {METHODS}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    check_solvable(obs)
    order = camera_order(obs)
    M = len(order)
    reset = _reset_indices(obs, order, reset_cameras)
    if initial is not None and reset & {0, 1}:
        log.info("a stereo camera is reset: solving from scratch")
        initial = None
    intr = initial_intrinsics(obs, order)
    held_K = np.array([obs.cameras[i].K is not None and "K" in obs.cameras[i].fixed for i in order])
    held_dist = np.array([obs.cameras[i].dist is not None and "dist" in obs.cameras[i].fixed for i in order])
    xy = centred(obs, order, intr)
    rows = observation_rows(obs)

    if initial is not None:
        start = warm_start(obs, order, intr, xy, rows, initial, seed=options.seed, reset=reset)
    else:
        max_tracks = None if options.method == "paper" else 150
        start = paper_start(obs, order, intr, xy, rows, options.seed, max_tracks=max_tracks)
    intr[:, 0] = np.where(np.isfinite(intr[:, 0]) & held_K, intr[:, 0], start.f)
    timings["initialise"] = time.perf_counter() - t0

    if options.method == "paper":
        return _paper_result(obs, order, intr, rows, start, timings)

    has_X = np.all(np.isfinite(start.X), axis=1)
    track_rows = np.flatnonzero(has_X)
    keep_obs = has_X[obs.track_index]
    names = _free_names(options)
    intr_free = _free_mask(M, names, held_K, held_dist)
    rot_free = np.zeros((M, 3), dtype=bool)
    rot_free[2:] = True  # every camera outside the stereo pair turns freely
    if "stereo_rotation" in names or options.method == "unconstrained":
        rot_free[1] = True
    if initial is not None and options.free == "auto":
        _restore_free(initial, [obs.cameras[i].id for i in order], intr_free, rot_free)
        intr_free[held_K, :4] = False
        intr_free[held_dist, 4:] = False
    unconstrained = options.method == "unconstrained"
    if unconstrained:
        right_centre = CENTRE_FREE
    elif "stereo_direction" in names or _restored_direction(initial, options):
        right_centre = CENTRE_ON_BASELINE
    else:
        right_centre = CENTRE_FIXED
    full = _problem(obs, order, np.flatnonzero(keep_obs), track_rows, intr_free, rot_free, right_centre)
    state = State(intr, start.R, start.C, start.X[track_rows])

    t1 = time.perf_counter()
    near, start_kind = False, "cold"
    if initial is not None:
        new_points = ~np.isin(obs.track_ids[track_rows], initial.point_ids)
        state = _fit_points(full, state, new_points, options)
        near = _near_solution(full, state, options)
        start_kind = "warm" if near else "warm, robust"
    if not near:
        state = _robust_passes(full, state, options, cold=initial is None, held_K=held_K, held_dist=held_dist)
    inliers = _reject_outliers(full, state, options)
    problem = full.subset(inliers)
    timings["robust_adjustment"] = time.perf_counter() - t1

    decisions: list[str] = []
    if options.free == "auto" and initial is None and not unconstrained:
        t2 = time.perf_counter()
        widths = [obs.cameras[i].width for i in order]
        heights = [obs.cameras[i].height for i in order]
        # The rule starts from the ideal pair: its rotation held at the identity.
        R = state.R.copy()
        R[1] = np.eye(3)
        state, _ = bundle.solve(problem, State(state.intr, R, state.C, state.X), max_iterations=options.max_iterations)
        problem, decisions = _choose_free(problem, state, options, widths, heights, held_K, held_dist)
        full = replace(full, intr_free=problem.intr_free, rot_free=problem.rot_free, centre_mode=problem.centre_mode)
        timings["choose_free"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    guessed_pp = np.array([obs.cameras[i].K is None for i in order]) & ~held_K & (options.pp_prior_rel > 0)

    def adjust(problem: Problem, state: State) -> tuple[State, bundle.SolveInfo, Problem | None]:
        # The covariance's normal equations (guessed principal points freed for their
        # prior) come with the solve's last step.
        wider = None if unconstrained else _with_guessed_pp(problem, guessed_pp)
        return *bundle.solve(problem, state, max_iterations=options.max_iterations, report=wider), wider

    state, info, wider = adjust(problem, state)
    for _ in range(3):  # least squares on the inliers until the inlier set settles
        new_inliers = _reject_outliers(full, state, options)
        if np.array_equal(new_inliers, inliers):
            break
        inliers = new_inliers
        problem = full.subset(inliers)
        state, info, wider = adjust(problem, state)
    timings["adjustment"] = time.perf_counter() - t3
    per_camera = np.bincount(problem.cam, minlength=M)
    if per_camera.min() < MIN_CAMERA_INLIERS:
        weak = [obs.cameras[order[m]].id for m in np.flatnonzero(per_camera < MIN_CAMERA_INLIERS)]
        raise SolveError(
            f"cameras {weak}: fewer than {MIN_CAMERA_INLIERS} of their observations agree with the "
            "solution; the tracks look wrong or the camera moved (re-solve with it reset)"
        )
    t4 = time.perf_counter()
    sizes = np.array([(obs.cameras[i].width, obs.cameras[i].height) for i in order], dtype=float)
    cov = None if unconstrained else _uncertainty(problem, wider, state, info.normal, options.pp_prior_rel * sizes)
    timings["uncertainty"] = time.perf_counter() - t4
    timings["total"] = time.perf_counter() - t0
    if not info.converged:
        raise SolveError(f"the adjustment did not converge: {info.reason}")
    return _result(
        obs, order, problem, state, track_rows, inliers, info, cov, decisions, options, timings, start=start_kind
    )


def _with_guessed_pp(problem: Problem, guessed_pp: np.ndarray) -> Problem | None:
    """`problem` with the guessed principal points it holds freed, or None if it holds none.

    guessed_pp (M,): cameras whose principal point was guessed (the image
    centre), not given.
    """
    consider = guessed_pp & ~problem.intr_free[:, 2]
    if not consider.any():
        return None
    intr_free = problem.intr_free.copy()
    intr_free[consider, 2:4] = True
    return replace(problem, intr_free=intr_free)


def _uncertainty(problem: Problem, wider: Problem | None, state: State, normal, prior_px: np.ndarray) -> Covariance:
    """Covariance at the solution, not conditional on principal points that are only guessed.

    A principal point held at the image centre because nobody gave one is
    not known exactly: a real lens's sits a percent or so of the image size
    away (`Options.pp_prior_rel`). Held but unknown, it biases focal lengths
    and scale by amounts the conditional covariance does not show (the data
    of a small object cannot tell a 10 px offset from a focal length or a
    rotation, and a column difference in the stereo pair shifts every
    disparity). Its uncertainty enters as a prior on the held columns, so
    the reported sigmas include what the guess may cost.
    wider: `problem` with those principal points freed (`_with_guessed_pp`),
    or None; normal: the normal equations of `wider` (else of `problem`) at
    `state`; prior_px (M, 2): 1 sigma of the guess in x and y, pixels.
    """
    sigma_px = float(np.sqrt(2.0 * normal.cost / max(residual_dof(problem), 1)))
    if wider is None:
        return covariance(problem, state, sigma_px=sigma_px, normal=normal)
    cols = wider.columns()[0]
    U = normal.U.copy()
    for m in np.flatnonzero(wider.intr_free[:, 2] & ~problem.intr_free[:, 2]):
        for slot, prior in ((2, prior_px[m, 0]), (3, prior_px[m, 1])):
            U[cols[m, slot], cols[m, slot]] += (sigma_px / prior) ** 2
    return covariance(wider, state, sigma_px=sigma_px, normal=replace(normal, U=U))


def _reset_indices(obs: Observations, order: list[int], reset_cameras: Collection[str]) -> set[int]:
    """Problem indices of the cameras named in reset_cameras."""
    if isinstance(reset_cameras, str):  # one id, not its letters
        reset_cameras = [reset_cameras]
    ids = [obs.cameras[i].id for i in order]
    unknown = sorted(set(reset_cameras) - set(ids))
    if unknown:
        raise SolveError(f"reset_cameras: unknown camera(s) {unknown}; the observations have {ids}")
    return {ids.index(c) for c in reset_cameras}


def _robust_passes(full: Problem, state: State, options: Options, *, cold: bool, held_K, held_dist) -> State:
    """The robust adjustment of every parameter that moves, from a rough start."""
    robust = dict(loss=options.loss, scale_px=options.loss_scale_px, max_iterations=options.max_iterations)
    if cold and options.method != "unconstrained":
        # Continuation: a first pass moves focal lengths and the poses outside the
        # stereo pair only; freeing
        # principal points or distortion far from the solution lets the adjustment
        # settle in a wrong valley.
        M = full.n_cameras
        first = replace(
            full,
            intr_free=full.intr_free & _free_mask(M, frozenset({"f"}), held_K, held_dist),
            rot_free=full.rot_free & (np.arange(M) != 1)[:, None],
            centre_mode=np.where(np.arange(M) == 1, CENTRE_FIXED, full.centre_mode),
        )
        state, _ = bundle.solve(first, state, **robust)
    if cold and options.free == "auto" and options.method == "refined":
        # Outliers are judged with the stereo pair free to turn: a pair that is not quite
        # parallel, or principal points off centre, must not cost it its observations.
        full = replace(full, rot_free=full.rot_free | (np.arange(full.n_cameras) == 1)[:, None])
    state, _ = bundle.solve(full, state, **robust)
    return state


def _fit_points(full: Problem, state: State, which: np.ndarray, options: Options) -> State:
    """Robust fit of the points marked in `which` (N,) with every camera held."""
    rows = which[full.pt]
    if not rows.any():
        return state
    # Only these points and their observations: with the cameras held, the rest take no part.
    points = np.flatnonzero(which)
    points_only = replace(
        full.subset(rows),
        pt=np.searchsorted(points, full.pt[rows]),
        n_points=len(points),
        intr_free=np.zeros_like(full.intr_free),
        rot_free=np.zeros_like(full.rot_free),
        centre_mode=np.full_like(full.centre_mode, CENTRE_FIXED),
    )
    # A start for the joint adjustment, which refines these points again: loose tolerance.
    fitted, _ = bundle.solve(
        points_only,
        replace(state, X=state.X[points]),
        loss=options.loss,
        scale_px=options.loss_scale_px,
        max_iterations=options.max_iterations,
        ftol=1e-6,
    )
    X = state.X.copy()
    X[points] = fitted.X
    return replace(state, X=X)


def _near_solution(problem: Problem, state: State, options: Options) -> bool:
    """Whether every camera's median residual is within the outlier threshold (no camera moved)."""
    r = np.linalg.norm(bundle.residuals(problem, state), axis=1)
    threshold = max(options.outlier_sigmas * np.median(r) / 1.1774, options.min_outlier_px)
    for m in range(problem.n_cameras):
        mine = r[problem.cam == m]
        if len(mine) and np.median(mine) > threshold:
            return False
    return True


def _free_names(options: Options) -> frozenset[str]:
    if options.free == "auto":
        return frozenset({"f"})
    unknown = set(options.free) - set(FREE_NAMES)
    if unknown:
        raise SolveError(f"free: unknown parameter(s) {sorted(unknown)}; expected some of {FREE_NAMES}")
    return frozenset(options.free)


def _restore_free(initial: Calibration, ids: list[str], intr_free, rot_free) -> None:
    """Take the free-parameter mask of a previous solve (in place), for cameras it knew."""
    from camnet.geometry.projection import INTRINSIC_NAMES

    free = initial.extra.get("diagnostics", {}).get("free", {})
    for m, cam_id in enumerate(ids):
        names = free.get("intrinsics", {}).get(cam_id)
        if names is not None:
            intr_free[m] = [n in names for n in INTRINSIC_NAMES]
    axes = free.get("stereo_rotation_axes")
    if axes is not None:
        rot_free[1] = [a in axes for a in "xyz"]


def _restored_direction(initial: Calibration | None, options: Options) -> bool:
    if initial is None or options.free != "auto":
        return False
    return bool(initial.extra.get("diagnostics", {}).get("free", {}).get("stereo_direction", False))


def _paper_result(obs, order, intr, rows, start: Start, timings) -> Result:
    """The paper's method as solved by `paper_start`: points from the stereo pair alone."""
    t0 = time.perf_counter()
    has_P0 = np.all(np.isfinite(start.P0), axis=1)
    for m in range(2, len(order)):
        shared = int(np.sum(has_P0 & (rows[:, order[m]] >= 0)))
        if shared < 6:
            raise SolveError(
                f"cameras[{obs.cameras[order[m]].id}]: the paper's method needs 6 tracks seen by "
                f"it and the stereo pair; it has {shared}"
            )
    f, R, C = start.f, start.R, start.C
    f_left = f[0]
    intr = intr.copy()
    intr[:, 0], intr[:, 4:] = f, 0.0
    track_rows = np.flatnonzero(has_P0)
    X = start.P0[track_rows] * np.array([1.0, 1.0, f_left])
    keep = has_P0[obs.track_index]
    problem = _problem(
        obs,
        order,
        np.flatnonzero(keep),
        track_rows,
        np.zeros((len(order), 9), bool),
        np.zeros((len(order), 3), bool),
        CENTRE_FIXED,
    )
    state = State(intr, R, C, X)
    timings["eq13"] = time.perf_counter() - t0
    timings["total"] = sum(timings.values())
    info = bundle.SolveInfo(True, "eq. 13 minimised", 0, np.nan, np.nan)
    return _result(
        obs,
        order,
        problem,
        state,
        track_rows,
        np.ones(len(problem.cam), bool),
        info,
        None,
        ["paper: principal points at the image centre, no distortion"],
        Options("paper"),
        timings,
    )


def reported_points(
    problem: Problem, state: State, cov: Covariance | None, *, camera_points: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, int]]:
    """(N,) mask of the points a calibration reports, and how many were left out, by reason.

    A point is reported when at least two inlier views see it, it lies in
    front of every camera that sees it (a false match along an epipolar
    line fits two views just as well behind them), and, where the
    uncertainty is known, its 1-sigma position error is smaller than its
    distance from the nearest camera that sees it (tracks with no parallax
    land anywhere along their rays, some at millions of metres).
    camera_points (n, 3): each observation's point in its camera's frame at
    `state`, metres, where the caller has them.
    """
    views = np.bincount(problem.pt, minlength=problem.n_points)
    xc = camera_points
    if xc is None:
        _, xc = project_points(state.intr[problem.cam], state.R[problem.cam], state.C[problem.cam], state.X[problem.pt])
    behind = np.zeros(problem.n_points, dtype=bool)
    behind[problem.pt[xc[:, 2] <= 0]] = True
    nearest = np.full(problem.n_points, np.inf)
    np.minimum.at(nearest, problem.pt, np.linalg.norm(xc, axis=1))
    undetermined = np.zeros(problem.n_points, dtype=bool)
    if cov is not None:
        undetermined = np.sqrt(3.0) * cov.point_sigmas_m() >= nearest
    few = views < 2
    kept = ~few & ~behind & ~undetermined
    dropped = {
        "fewer_than_two_views": int(few.sum()),
        "behind_a_camera": int((~few & behind).sum()),
        "undetermined": int((~few & ~behind & undetermined).sum()),
    }
    return kept, dropped


def _result(
    obs, order, problem, state, track_rows, inliers, info, cov, decisions, options, timings, *, start: str = "cold"
) -> Result:
    from camnet.geometry.diagnostics import describe

    cameras_by_m = []
    for m, i in enumerate(order):
        info_cam = obs.cameras[i]
        R = state.R[m]
        cameras_by_m.append(
            Camera(
                info_cam.id,
                info_cam.width,
                info_cam.height,
                K_from_intrinsics(state.intr[m]),
                state.intr[m, 4:].copy(),
                R.copy(),
                -R @ state.C[m],
            )
        )
    cameras = [None] * len(order)
    for m, i in enumerate(order):
        cameras[i] = cameras_by_m[m]
    c = problem.cam
    uv, xc = project_points(state.intr[c], state.R[c], state.C[c], state.X[problem.pt])
    r = uv - problem.uv
    kept, dropped = reported_points(problem, state, cov, camera_points=xc)
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1)))) if len(r) else float("nan")
    extra = describe(obs, order, problem, state, cov, inliers, info, decisions, options, timings, kept, r)
    extra["diagnostics"]["points_left_out"] = dropped
    extra["diagnostics"]["start"] = start
    calibration = Calibration(
        cameras=cameras,
        point_ids=obs.track_ids[track_rows[kept]],
        points=state.X[kept],
        rms_reprojection_px=rms,
        world_frame=obs.stereo.left,
        extra=extra,
    )
    return Result(calibration, state, problem, order, track_rows, cov, info.converged, info.reason, timings)


__all__ = ["Options", "Result", "calibrate", "check_solvable"]
