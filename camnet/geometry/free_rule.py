"""Which parameters a solve frees: the automatic rule of camnet.geometry.calibrate's
docstring, explicit free sets, and the free set a warm start takes over.

Blocks are tried in the order of `CANDIDATES`. A block is freed when the data
determine it (its standard deviation, with it and the blocks before it free,
moves the image by at most `determined_px` pixels) or when the data ask for it
(freeing it lowers the cost by more than chance allows: a chi-square score
test at false-alarm rate `significance`, on the a-posteriori pixel variance).
Every test is made at the least-squares solution of the problem as it
stands, so the network is solved again after each block that is freed. A
camera block the cameras ask for together, but none alone, is freed for all
of them; the cameras still held are then tried again (a 100 degree lens's k2
shows in one camera only once the others' is free).

The stereo pair's blocks are tried before the lens blocks, although a 100
degree lens held at k1 = k2 = 0 lends some of its misfit to the pair's yaw,
which its score test then frees. Trying k1 and k2 first does not keep the
pair held: with the lens free, the pair's rotation is determined to
0.07-0.4 px (seeds 0-2), within `determined_px`, and is freed all the
same (and tried on significance alone, the pair stays held but the stereo
cameras' principal points are determined and freed instead: the right
camera's horizontal principal point is its yaw to first order). On the
`wide` family (camnet.sim.families, seeds 0-19) the median scale error was
0.29% with k1, k2 tried first against 0.12% in this order. What the lens's
misfit did cost was observations: outliers are judged before this rule,
and a wide lens's good observations far from the image centre lie off a
lens held at zero. camnet.geometry.calibrate therefore judges them again,
after a robust solve with the free set, whenever the rule frees a
distortion coefficient.

The name `fisheye` frees the four coefficients k1..k4 of every fisheye
camera (the blocks `k1`, `k2` alone free the first two of either model).
The automatic rule frees them from the start, as it frees f: a fisheye's
polynomial is its lens, never a small correction, and holding k3 and k4 at
zero while k1 and k2 move biases a 170-degree fisheye's focal length by
several sigmas.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from camnet.errors import SolveError
from camnet.geometry import bundle, schur
from camnet.geometry.bundle import CEN, ROT, CentreMode, Problem, State
from camnet.geometry.model import CameraInfo, FreeSet, LensModel
from camnet.geometry.projection import FISHEYE_DIST_SIZE, FISHEYE_INTRINSIC_NAMES, INTRINSIC_NAMES, N_INTRINSICS
from camnet.geometry.uncertainty import Covariance, covariance, residual_dof

FREE_NAMES = ("f", "aspect", "pp", "k1", "k2", "fisheye", "stereo_rotation", "stereo_direction")
CANDIDATES = ("stereo_pitch_roll", "stereo_direction", "stereo_yaw", "pp", "k1", "k2")

_SLOT = {name: i for i, name in enumerate(INTRINSIC_NAMES)}  # a camera's intrinsic columns
_SLOTS = {"pp": (_SLOT["cx"], _SLOT["cy"]), "k1": (_SLOT["k1"],), "k2": (_SLOT["k2"],)}
_PITCH, _YAW, _ROLL = ROT.start, ROT.start + 1, ROT.start + 2  # rotation about x, y, z
_DIRECTION = (CEN.start, CEN.start + 1)  # the two tangent slots of a centre on the baseline sphere
_FISHEYE_K = slice(_SLOT["k1"], _SLOT["k1"] + FISHEYE_DIST_SIZE)  # a fisheye camera's coefficients


def free_names(free: str | frozenset[str]) -> frozenset[str]:
    """The names freed from the start: f and fisheye for "auto", else the explicit set, checked."""
    if free == "auto":
        return frozenset({"f", "fisheye"})
    unknown = set(free) - set(FREE_NAMES)
    if unknown:
        raise SolveError(f"free: unknown parameter(s) {sorted(unknown)}; expected some of {FREE_NAMES}")
    return frozenset(free)


def free_mask(
    problem_cams: int, names: frozenset[str], fixed_K: np.ndarray, fixed_dist: np.ndarray, *, fisheye=None
) -> np.ndarray:
    """(M, N_INTRINSICS) bool: the intrinsics `names` frees, except those held by the observations.

    fisheye (M,) bool: the fisheye cameras, whose four coefficients the name `fisheye` frees.
    """
    intr_free = np.zeros((problem_cams, N_INTRINSICS), dtype=bool)
    intr_free[:, _SLOT["f"]] = "f" in names
    intr_free[:, _SLOT["a"]] = "aspect" in names
    intr_free[:, list(_SLOTS["pp"])] = "pp" in names
    intr_free[:, _SLOT["k1"]] = "k1" in names
    intr_free[:, _SLOT["k2"]] = "k2" in names
    if fisheye is not None:
        intr_free[fisheye, _FISHEYE_K] |= "fisheye" in names
    _hold_given(intr_free, fixed_K, fixed_dist)
    return intr_free


def _hold_given(intr_free: np.ndarray, fixed_K: np.ndarray, fixed_dist: np.ndarray) -> None:
    """Hold (in place) K's intrinsics where fixed_K (M,), the distortion's where fixed_dist (M,)."""
    intr_free[fixed_K, : _SLOT["k1"]] = False
    intr_free[fixed_dist, _SLOT["k1"] :] = False


def restore_free(
    free: FreeSet, cameras: list[CameraInfo], intr_free: np.ndarray, rot_free: np.ndarray, *, fixed_K, fixed_dist
) -> None:
    """Take the free set of a previous solve (in place) for the cameras it knew; what is fixed stays held."""
    for m, cam in enumerate(cameras):
        names = free.intrinsics.get(cam.id)
        if names is not None:
            slots = FISHEYE_INTRINSIC_NAMES if cam.model == LensModel.FISHEYE else INTRINSIC_NAMES
            intr_free[m] = [n in names for n in slots]
    rot_free[1] = [a in free.stereo_rotation_axes for a in "xyz"]
    _hold_given(intr_free, fixed_K, fixed_dist)


def _pixel_effect(name: str, state: State, cov: Covariance, widths, heights) -> float | np.ndarray:
    """Standard deviation, in pixels, of a candidate block's effect on the image."""
    cols = cov.columns
    sd = np.where(cov.undetermined, np.inf, np.sqrt(np.maximum(np.diag(cov.cameras), 0.0)))

    def sigma(m: int, *slots: int) -> float:
        return max(float(sd[cols[m, s]]) if cols[m, s] >= 0 else np.nan for s in slots)

    f = state.intr[:, _SLOT["f"]]
    cams = range(len(f))
    r_max = np.hypot(np.asarray(widths) / 2, np.asarray(heights) / 2) / f
    if name == "stereo_pitch_roll":
        return f[1] * sigma(1, _PITCH, _ROLL)
    if name == "stereo_yaw":
        return f[1] * sigma(1, _YAW)
    if name == "stereo_direction":  # a sideways shift of l * angle, seen at the typical depth
        return f[1] * sigma(1, *_DIRECTION) * np.linalg.norm(state.C[1]) / np.median(state.X[:, 2])
    if name == "pp":
        return np.array([sigma(m, *_SLOTS["pp"]) for m in cams])
    if name == "k1":
        return np.array([f[m] * r_max[m] ** 3 * sigma(m, _SLOT["k1"]) for m in cams])
    return np.array([f[m] * r_max[m] ** 5 * sigma(m, _SLOT["k2"]) for m in cams])


def with_block(problem: Problem, name: str, cameras: np.ndarray) -> Problem:
    """`problem` with the candidate block `name` also free (for `cameras` (M,) bool, per-camera blocks)."""
    intr_free, rot_free, centre_mode = problem.intr_free.copy(), problem.rot_free.copy(), problem.centre_mode.copy()
    if name == "stereo_pitch_roll":
        rot_free[1, [0, 2]] = True
    elif name == "stereo_direction":
        if centre_mode[1] == CentreMode.FIXED:  # a FREE centre (a soft stereo baseline) turns already
            centre_mode[1] = CentreMode.ON_BASELINE
    elif name == "stereo_yaw":
        rot_free[1, 1] = True
    else:
        for s in _SLOTS[name]:
            intr_free[cameras, s] = True
    return replace(problem, intr_free=intr_free, rot_free=rot_free, centre_mode=centre_mode)


def choose_free(
    problem: Problem, state: State, *, determined_px: float, significance: float, widths, heights, held_K, held_dist,
    max_iterations: int = 300,
) -> tuple[Problem, State, list[str]]:
    """Apply the rule of the module docstring; returns (problem, state, decisions).

    `state` is the least-squares solution of `problem`. Both tests are
    linearised at the least-squares solution of the problem as it stands:
    the standard deviation from the covariance with the block free, the cost
    decrease from the Gauss-Newton step with it free (the score test,
    first-order equal to the likelihood ratio). Each freed block moves the
    solution, so it is solved again before the next test: a test made away
    from the minimum measures the distance to it, not the block.
    """
    decisions = []
    for name in CANDIDATES:
        # A camera block is tried again for the cameras still held once others are freed:
        # their misfit, spread over every camera before, then stands out.
        for _ in range(1 if name.startswith("stereo") else problem.n_cameras):
            trial, decision = _try_block(name, problem, state, determined_px, significance, widths, heights,
                                         held_K, held_dist)
            if decision:
                decisions.append(decision)
            if trial is problem:
                break
            problem = trial
            state, _ = bundle.solve(problem, state, max_iterations=max_iterations)
    return problem, state, decisions


def _try_block(name, problem: Problem, state: State, determined_px, significance, widths, heights, held_K, held_dist):
    """(problem with the block `name` freed where the rule says so, the decision's text)."""
    from scipy.special import chdtri

    M = problem.n_cameras
    movable = {"pp": ~held_K, "k1": ~held_dist, "k2": ~held_dist}.get(name, np.ones(M, bool))
    if not name.startswith("stereo"):
        movable = movable & ~problem.intr_free[:, _SLOTS[name][0]]
        if not movable.any():
            return problem, ""  # freed for every camera by an earlier round
    # A block's Jacobian does not depend on which other blocks are free: one set of
    # normal equations with the whole block free serves every trial.
    everything = with_block(problem, name, movable)
    ne = bundle.normal_equations(everything, state)
    columns = everything.columns()[0]

    def restricted(trial: Problem):
        return schur.restrict(ne, columns[trial.columns()[0] >= 0])

    variance = 2.0 * ne.cost / max(residual_dof(problem), 1)  # a posteriori pixel variance
    base = schur.gauss_newton_decrease(restricted(problem))

    def significant(trial: Problem, k: int) -> tuple[bool, float]:
        """Whether freeing the trial's new block lowers the cost beyond chance (chi-square, k dof)."""
        statistic = 2.0 * (schur.gauss_newton_decrease(restricted(trial)) - base) / max(variance, 1e-300)
        # An infinite decrease means the block is not determined at all: no evidence for it.
        wanted = variance > 1e-12 and np.isfinite(statistic) and statistic > chdtri(k, significance)
        return bool(wanted), statistic

    if name == "stereo_direction" and everything.columns()[1] == problem.columns()[1]:
        return problem, f"{name}: free (the right camera's centre is free: its baseline is soft)"
    # Infinite where the block is not fixed at all by these observations.
    effect = _pixel_effect(name, state, covariance(everything, state, normal=restricted(everything)), widths, heights)
    if name.startswith("stereo"):
        k = int(everything.columns()[1] - problem.columns()[1])
        wanted, statistic = significant(everything, k)
        free = effect <= determined_px or wanted
        text = f"{name}: {'free' if free else 'held'} (sigma {effect:.2g} px, chi2 {statistic:.3g} on {k} dof)"
        return (everything if free else problem), text
    k = len(_SLOTS[name])
    determined = np.isfinite(effect) & (effect <= determined_px) & movable
    wanted = np.zeros(M, bool)
    if significant(everything, k * int(movable.sum()))[0]:  # the block as a whole; then camera by camera
        for m in np.flatnonzero(movable & ~determined):
            wanted[m] = significant(with_block(problem, name, np.arange(M) == m), k)[0]
        if not (wanted | determined).any():
            # The cameras together ask for it, none alone does (one lens model shared by
            # all, each camera's evidence weak): free it where it can move.
            wanted = movable.copy()
    text = (
        f"{name}: sigma px per camera {np.round(effect, 2).tolist()}; "
        f"freed by significance {np.flatnonzero(wanted & ~determined).tolist()}"
    )
    freed = determined | wanted
    return (with_block(problem, name, freed) if freed.any() else problem), text
