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
always (unless the observations fix K). Then, in this order, each block is
freed when the data determine it, i.e. when its standard deviation, with it
and the blocks before it free, moves the image by at most ``determined_px``
pixels: the right stereo camera's pitch and roll, its yaw, the principal
points, k1, k2. A block that is not determined is held at its given value
(K and dist in the observations) or the ideal (image centre, no distortion,
a parallel pair). An explicit ``free`` set replaces the rule.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from camnet import bundle, paper
from camnet.bundle import CENTRE_FIXED, CENTRE_FREE, CENTRE_ON_BASELINE, Problem, State
from camnet.camera import Camera
from camnet.errors import SolveError
from camnet.formats import Calibration, Observations
from camnet.projection import K_from_intrinsics
from camnet.uncertainty import Covariance, covariance

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
    outlier_sigmas: float = 4.0  # reject residuals beyond this many robust sigmas
    min_outlier_px: float = 1.5  # never reject residuals below this
    max_iterations: int = 100
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


def _camera_order(obs: Observations) -> list[int]:
    left, right = obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)
    return [left, right] + [i for i in range(len(obs.cameras)) if i not in (left, right)]


def check_solvable(obs: Observations) -> None:
    """Refuse observations that cannot determine a metric network (eq. 15)."""
    if len(obs.cameras) < 3:
        raise SolveError(f"cameras: {len(obs.cameras)} given; a metric solve needs at least 3 (eq. 15)")
    order = _camera_order(obs)
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


# ---------------------------------------------------------------- initialisation


def _initial_intrinsics(obs: Observations, order: list[int]) -> np.ndarray:
    intr = np.zeros((len(order), 9))
    for m, i in enumerate(order):
        cam = obs.cameras[i]
        if cam.K is not None:
            intr[m, :4] = cam.K[0, 0], cam.K[1, 1] / cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        else:
            intr[m, :4] = np.nan, 1.0, (cam.width - 1) / 2, (cam.height - 1) / 2
        if cam.dist is not None:
            intr[m, 4:] = cam.dist
    return intr


def _centred(obs: Observations, order: list[int], intr: np.ndarray) -> np.ndarray:
    """Observed pixels relative to each camera's principal point, undistorted where known."""
    import cv2

    m_of = np.empty(len(obs.cameras), dtype=int)
    m_of[order] = np.arange(len(order))
    m = m_of[obs.cam_index]
    xy = obs.uv - intr[m, 2:4]
    for mm in np.flatnonzero(np.any(intr[:, 4:] != 0, axis=1) & np.isfinite(intr[:, 0])):
        rows = m == mm
        K = K_from_intrinsics(intr[mm])
        und = cv2.undistortPoints(obs.uv[rows].reshape(-1, 1, 2), K, intr[mm, 4:], P=K)
        xy[rows] = und.reshape(-1, 2) - intr[mm, 2:4]
    return xy


@dataclass
class _Start:
    f: np.ndarray  # (M,)
    R: np.ndarray
    C: np.ndarray
    X: np.ndarray  # (T, 3) NaN where unknown
    registered: np.ndarray  # (M,) bool
    P0: np.ndarray
    k: float


def _paper_start(
    obs: Observations,
    order: list[int],
    intr: np.ndarray,
    xy: np.ndarray,
    seed: int,
    max_tracks: int | None = None,
) -> _Start:
    """The paper's unknowns from nothing but the observations.

    max_tracks: use at most this many tracks per camera in eq. 13, which is
    plenty for a starting point; None uses all (the paper's method itself).
    """
    M, T = len(order), len(obs.track_ids)
    rows = np.full((T, len(obs.cameras)), -1)
    rows[obs.track_index, obs.cam_index] = np.arange(len(obs.uv))
    left, right = rows[:, order[0]], rows[:, order[1]]
    pair = (left >= 0) & (right >= 0)
    given_f = intr[:, 0]
    if np.isfinite(given_f[0]) and np.isfinite(given_f[1]):
        k = given_f[1] / given_f[0]
    else:
        k = paper.focal_ratio(xy[left[pair], 1], xy[right[pair], 1])
    P0 = np.full((T, 3), np.nan)
    P0_pair, valid = paper.triangulate_parallel(xy[left[pair]], xy[right[pair]], k, 1.0)
    P0[np.flatnonzero(pair)[valid]] = P0_pair[valid]
    has_P0 = np.all(np.isfinite(P0), axis=1)

    threshold = 0.01 * float(np.hypot(obs.cameras[order[0]].width, obs.cameras[order[0]].height))
    stretched = {}  # camera -> (DLT matrix on P0, its inlier tracks)
    for m in range(2, M):
        trk = np.flatnonzero(has_P0 & (rows[:, order[m]] >= 0))
        if len(trk) < 6:
            continue
        P, inl = paper.dlt_ransac(P0[trk], xy[rows[trk, order[m]]], threshold_px=threshold, seed=seed)
        stretched[m] = (P, trk[inl])
    if np.isfinite(given_f[0]):
        f_left = given_f[0]
    else:
        candidates = [paper.focals_from_stretched_dlt(P)[1] for P, _ in stretched.values()]
        finite = [c for c in candidates if np.isfinite(c) and c > 0]
        if not finite:
            raise SolveError(
                "the left camera's focal length is not determined: no other camera sees "
                "at least 6 stereo tracks in a non-degenerate configuration"
            )
        f_left = float(np.median(finite))

    # The paper's stereo cloud in metres (its baseline scaled in).
    P0 = P0 * obs.stereo.baseline_m
    X = P0 * np.array([1.0, 1.0, f_left])
    f = np.full(M, np.nan)
    f[0], f[1] = f_left, k * f_left
    R = np.tile(np.eye(3), (M, 1, 1))
    C = np.zeros((M, 3))
    C[1, 0] = obs.stereo.baseline_m
    registered = np.zeros(M, dtype=bool)
    registered[:2] = True
    # The paper's start: every camera that shares six stereo tracks, by DLT, then eq. 13.
    # A DLT on the stretched cloud P0 (f_left = 1, unit baseline) acts on the metric
    # cloud X = P0 * [l, l, l f_left] once its columns are divided by the same.
    cams, others = [], []
    to_metric = np.diag([1.0 / obs.stereo.baseline_m] * 2 + [1.0 / (obs.stereo.baseline_m * f_left), 1.0])
    for m, (P, use) in stretched.items():
        f[m], R[m], C[m] = paper.pose_from_dlt(P @ to_metric)
        if max_tracks is not None and len(use) > max_tracks:
            use = use[np.linspace(0, len(use) - 1, max_tracks).astype(int)]
        cams.append((use, xy[rows[use, order[m]]]))
        others.append(m)
    if others:
        f_left, f[others], R[others], C[others], _ = paper.refine_eq13(
            f_left, f[others], R[others], C[others], P0, cams
        )
        f[0], f[1] = f_left, k * f_left
        X = P0 * np.array([1.0, 1.0, f_left])
        registered[others] = True
    _register_and_triangulate(obs, order, xy, rows, f, R, C, X, registered, threshold, seed)
    return _Start(f, R, C, X, registered, P0, k)


def _register_and_triangulate(obs, order, xy, rows, f, R, C, X, registered, threshold, seed) -> None:
    """Alternately register cameras (DLT on known points) and triangulate tracks, in place."""
    M = len(order)
    while True:
        progress = False
        for m in np.flatnonzero(~registered):
            has_X = np.all(np.isfinite(X), axis=1) & (rows[:, order[m]] >= 0)
            trk = np.flatnonzero(has_X)
            if len(trk) < 6:
                continue
            P, _ = paper.dlt_ransac(X[trk], xy[rows[trk, order[m]]], threshold_px=threshold, seed=seed)
            f[m], R[m], C[m] = paper.pose_from_dlt(P)
            registered[m] = True
            progress = True
        progress |= _triangulate_missing(order, xy, rows, f, R, C, X, registered) > 0
        if not progress or registered.all():
            break
    if not registered.all():
        missing = [obs.cameras[order[m]].id for m in range(M) if not registered[m]]
        raise SolveError(
            f"cameras {missing}: too few tracks shared with the solved cameras to place them (need at least 6)"
        )
    _triangulate_missing(order, xy, rows, f, R, C, X, registered)


def _triangulate_missing(order, xy, rows, f, R, C, X, registered) -> int:
    """Midpoint triangulation of tracks without a point, seen by >= 2 placed cameras."""
    todo = ~np.all(np.isfinite(X), axis=1)
    A = np.zeros((len(X), 3, 3))
    b = np.zeros((len(X), 3))
    count = np.zeros(len(X), dtype=int)
    for m in np.flatnonzero(registered):
        trk = np.flatnonzero(todo & (rows[:, order[m]] >= 0))
        if not len(trk):
            continue
        p = xy[rows[trk, order[m]]] / f[m]
        d = np.concatenate([p, np.ones((len(trk), 1))], axis=1) @ R[m]  # rays in the world
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        Pm = np.eye(3) - d[:, :, None] * d[:, None, :]
        A[trk] += Pm
        b[trk] += Pm @ C[m]
        count[trk] += 1
    ok = todo & (count >= 2)
    if not ok.any():
        return 0
    det = np.linalg.det(A[ok])
    good = np.flatnonzero(ok)[det > 1e-9]
    X[good] = np.linalg.solve(A[good], b[good][:, :, None])[:, :, 0]
    return len(good)


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


def _choose_free(problem: Problem, state: State, options: Options, widths, heights, held_K, held_dist):
    """Apply the free-parameter rule of the module docstring; returns (problem, decisions)."""
    intr_free, rot_free = problem.intr_free.copy(), problem.rot_free.copy()
    decisions = []
    centre_mode = problem.centre_mode.copy()
    candidates = [
        ("stereo_pitch_roll", None),
        ("stereo_direction", None),
        ("stereo_yaw", None),
        ("pp", (2, 3)),
        ("k1", (4,)),
        ("k2", (5,)),
    ]
    for name, slots in candidates:
        trial_intr, trial_rot, trial_centre = intr_free.copy(), rot_free.copy(), centre_mode.copy()
        if name == "stereo_pitch_roll":
            trial_rot[1, [0, 2]] = True
        elif name == "stereo_direction":
            trial_centre[1] = CENTRE_ON_BASELINE
        elif name == "stereo_yaw":
            trial_rot[1, 1] = True
        else:
            held = held_K if name == "pp" else held_dist
            for s in slots:
                trial_intr[~held, s] = True
        trial = replace(problem, intr_free=trial_intr, rot_free=trial_rot, centre_mode=trial_centre)
        effect = _pixel_effect(name, state, covariance(trial, state), widths, heights)
        if name.startswith("stereo"):
            if effect <= options.determined_px:
                rot_free, centre_mode = trial_rot, trial_centre
            decisions.append(f"{name}: {'free' if effect <= options.determined_px else 'held'} (sigma {effect:.2g} px)")
        else:
            for m in range(len(effect)):
                if np.isfinite(effect[m]) and effect[m] <= options.determined_px:
                    for s in slots:
                        intr_free[m, s] = True
            decisions.append(f"{name}: sigma px per camera {np.round(effect, 2).tolist()}")
    return replace(problem, intr_free=intr_free, rot_free=rot_free, centre_mode=centre_mode), decisions


def calibrate(obs: Observations, options: Options = Options(), *, initial: Calibration | None = None) -> Result:
    """Solve the network described by `obs`. Raises SolveError when it cannot."""
    try:
        return _calibrate(obs, options, initial)
    except np.linalg.LinAlgError:
        raise SolveError("the observations do not determine the calibration (singular equations)") from None


def _calibrate(obs: Observations, options: Options, initial: Calibration | None) -> Result:
    if options.method not in METHODS:
        raise SolveError(f"method: unknown {options.method!r}; expected one of {METHODS}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    check_solvable(obs)
    order = _camera_order(obs)
    M = len(order)
    intr = _initial_intrinsics(obs, order)
    held_K = np.array([obs.cameras[i].K is not None and "K" in obs.cameras[i].fixed for i in order])
    held_dist = np.array([obs.cameras[i].dist is not None and "dist" in obs.cameras[i].fixed for i in order])
    xy = _centred(obs, order, intr)
    rows = np.full((len(obs.track_ids), len(obs.cameras)), -1)
    rows[obs.track_index, obs.cam_index] = np.arange(len(obs.uv))

    if initial is not None:
        start = _warm_start(obs, order, intr, xy, rows, initial, options.seed)
    else:
        start = _paper_start(obs, order, intr, xy, options.seed, max_tracks=None if options.method == "paper" else 150)
    intr[:, 0] = np.where(np.isfinite(intr[:, 0]) & held_K, intr[:, 0], start.f)
    timings["initialise"] = time.perf_counter() - t0

    if options.method == "paper":
        return _paper_result(obs, order, intr, xy, rows, start, timings)

    has_X = np.all(np.isfinite(start.X), axis=1)
    track_rows = np.flatnonzero(has_X)
    keep_obs = has_X[obs.track_index]
    names = _free_names(options)
    intr_free = _free_mask(M, names, held_K, held_dist)
    rot_free = np.zeros((M, 3), dtype=bool)
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
    # Continuation: from a cold start, a first robust pass moves focal lengths and
    # poses only; freeing principal points or distortion far from the solution
    # lets the adjustment settle in a wrong valley.
    first = full
    if initial is None and not unconstrained:
        first = replace(
            full,
            intr_free=intr_free & _free_mask(M, frozenset({"f"}), held_K, held_dist),
            rot_free=np.zeros_like(rot_free),
            centre_mode=np.where(np.arange(M) == 1, CENTRE_FIXED, full.centre_mode),
        )
    state, info = bundle.solve(
        first, state, loss=options.loss, scale_px=options.loss_scale_px, max_iterations=options.max_iterations
    )
    if first is not full:
        state, info = bundle.solve(
            full, state, loss=options.loss, scale_px=options.loss_scale_px, max_iterations=options.max_iterations
        )
    inliers = _reject_outliers(full, state, options)
    problem = full.subset(inliers)
    timings["robust_adjustment"] = time.perf_counter() - t1

    decisions: list[str] = []
    if options.free == "auto" and initial is None and not unconstrained:
        t2 = time.perf_counter()
        widths = [obs.cameras[i].width for i in order]
        heights = [obs.cameras[i].height for i in order]
        state, _ = bundle.solve(problem, state, max_iterations=options.max_iterations)
        problem, decisions = _choose_free(problem, state, options, widths, heights, held_K, held_dist)
        full = replace(full, intr_free=problem.intr_free, rot_free=problem.rot_free, centre_mode=problem.centre_mode)
        timings["choose_free"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    for _ in range(4):  # least squares on the inliers until the inlier set settles
        state, info = bundle.solve(problem, state, max_iterations=options.max_iterations)
        new_inliers = _reject_outliers(full, state, options)
        if np.array_equal(new_inliers, inliers):
            break
        inliers = new_inliers
        problem = full.subset(inliers)
    timings["adjustment"] = time.perf_counter() - t3
    per_camera = np.bincount(problem.cam, minlength=M)
    if per_camera.min() < MIN_CAMERA_INLIERS:
        weak = [obs.cameras[order[m]].id for m in np.flatnonzero(per_camera < MIN_CAMERA_INLIERS)]
        raise SolveError(
            f"cameras {weak}: fewer than {MIN_CAMERA_INLIERS} of their observations agree with the "
            "solution; the tracks look wrong"
        )
    t4 = time.perf_counter()
    cov = None if unconstrained else covariance(problem, state)
    timings["uncertainty"] = time.perf_counter() - t4
    timings["total"] = time.perf_counter() - t0
    if not info.converged:
        raise SolveError(f"the adjustment did not converge: {info.reason}")
    return _result(obs, order, problem, state, track_rows, inliers, info, cov, decisions, options, timings)


def _free_names(options: Options) -> frozenset[str]:
    if options.free == "auto":
        return frozenset({"f"})
    unknown = set(options.free) - set(FREE_NAMES)
    if unknown:
        raise SolveError(f"free: unknown parameter(s) {sorted(unknown)}; expected some of {FREE_NAMES}")
    return frozenset(options.free)


def _restore_free(initial: Calibration, ids: list[str], intr_free, rot_free) -> None:
    """Take the free-parameter mask of a previous solve (in place), for cameras it knew."""
    from camnet.projection import INTRINSIC_NAMES

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


def _warm_start(obs, order, intr, xy, rows, initial: Calibration, seed: int) -> _Start:
    """Start from a previous calibration: its cameras, its points, new tracks triangulated."""
    by_id = {c.id: c for c in initial.cameras}
    M = len(order)
    f = np.full(M, np.nan)
    R = np.tile(np.eye(3), (M, 1, 1))
    C = np.zeros((M, 3))
    registered = np.zeros(M, dtype=bool)
    for m, i in enumerate(order):
        cam = by_id.get(obs.cameras[i].id)
        if cam is None:
            continue
        intr[m, :4] = cam.K[0, 0], cam.K[1, 1] / cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        intr[m, 4:] = cam.dist
        f[m], R[m], C[m] = cam.K[0, 0], cam.R, cam.centre
        registered[m] = True
    if not registered[:2].all():
        raise SolveError("initial calibration: it does not hold both stereo cameras")
    xy[:] = _centred(obs, order, intr)
    X = np.full((len(obs.track_ids), 3), np.nan)
    index = {int(t): j for j, t in enumerate(obs.track_ids)}
    for pid, p in zip(initial.point_ids, initial.points, strict=True):
        if int(pid) in index:
            X[index[int(pid)]] = p
    threshold = 0.01 * float(np.hypot(obs.cameras[order[0]].width, obs.cameras[order[0]].height))
    _register_and_triangulate(obs, order, xy, rows, f, R, C, X, registered, threshold, seed)
    return _Start(f, R, C, X, registered, np.full_like(X, np.nan), f[1] / f[0])


def _paper_result(obs, order, intr, xy, rows, start: _Start, timings) -> Result:
    """The paper's method as solved by `_paper_start`: points from the stereo pair alone."""
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


def _result(obs, order, problem, state, track_rows, inliers, info, cov, decisions, options, timings) -> Result:
    from camnet.diagnostics import describe

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
    # Points kept: tracks with at least two inlier views.
    views = np.bincount(problem.pt, minlength=problem.n_points)
    kept = views >= 2
    r = bundle.residuals(problem, state)
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1)))) if len(r) else float("nan")
    extra = describe(obs, order, problem, state, cov, inliers, info, decisions, options, timings)
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
