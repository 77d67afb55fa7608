"""Which parameters a solve frees: the automatic rule of camnet.solve.pipeline's
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

A stereo block is weighed by what freeing it costs the scale as well as by
the image. Freeing a block whose true value is the held one (the ideal,
parallel pair) buys nothing and adds D = sigma_free^2 - sigma_held^2 to the
scale's variance; holding a block whose true value is not biases the scale
by some b. Freeing pays, in the scale's mean square error, only where b^2 >
D. A block that barely moves the image can cost the scale dearly: a ring
head's yaw (0.12 m baseline, 2 m away, 950 px: a 57 px disparity) is
determined to about 1 px, but one pixel is 1.75% of its disparity: freed,
that pixel's sigma is the scale's. So where freeing a stereo block
more than doubles the scale's sigma (`COSTLY_INFLATION`: more than a
determined block's price), it is freed only when the data ask for it (the
score test) and the scale's shift with it free shows, beyond chance at
`significance`, that b^2 > D: the shift in units of sqrt D is normal with
unit variance and mean b / sqrt D, and its square must pass the noncentral
chi-square quantile (1 dof, noncentrality 1; 16.7 at 1e-3 against the score
test's 10.8). Where freeing costs the scale little (the pitch and roll, the
baseline's direction) the pixel rule above decides. The sigmas are those the
report gives: with principal points nobody gave uncertain (their prior,
`pp_prior_rel`), and the right camera's horizontal principal point is its
yaw to first order, so where those are guessed, freeing the yaw costs the
scale little more than the guess has, and held, the yaw could not take up
their column offset's misfit. A costly yaw that is merely determined, or
that the score test alone asks for (a false alarm at `significance`), is
held (docs/benchmarks.md, "Rigs unlike the paper's"). The price is the
threshold: a toed-in head's yaw is freed from 4.1 of its sigmas (the root
of 16.7) rather than 3.3 (of 10.8), and below that its scale is off by the
yaw's share of the disparity under either rule: a parallel pair is the paper's assumption, and each stereo line
of the report's free_rule says what freeing the block would cost the scale.
The reported sigmas count a held rotation axis as known to the pair's
tolerance (`PAIR_TOLERANCE_DEG`, uncertainty.held_at_tolerance), which
covers such a toe-in (docs/benchmarks.md, "A stereo pair held parallel"),
and the report warns where the scale rests on the held yaw. A costly block
whose tolerance costs the scale more than twice what freeing it does (the
data know it several times better than the tolerance) is freed.

The stereo pair's blocks are tried before the lens blocks, although a wide
lens held at k1 = k2 = 0 lends some of its misfit to the pair's yaw, which
its score test then frees. Tried the other way round, the lens first, the
stereo cameras' principal points are freed instead (the right camera's
horizontal principal point is its yaw to first order), which costs the
scale more (docs/benchmarks.md, "Rigs unlike the paper's"). So the rotation
blocks the rule freed are tried again, from the ideal pair, once a camera
block has been freed after them. Where the principal points are guessed,
the yaw costs the scale nothing beyond the guess and is freed again, but
where the pair's K is given the yaw, with the lens free, no longer asks,
costs the scale several times its held sigma, and is held again. A lens held
at zero also costs observations: outliers are judged before this rule, and
a wide lens's good observations far from the image centre lie off a lens
held at zero. camnet.solve.pipeline therefore judges them again, after a
robust solve with the free set, whenever the rule frees a distortion
coefficient. The measurements behind each choice are in docs/benchmarks.md,
"Evidence behind the solver's thresholds".

The name `fisheye` frees the four coefficients k1..k4 of every fisheye
camera (the blocks `k1`, `k2` alone free the first two of either model).
The automatic rule frees them from the start, as it frees f: a fisheye's
polynomial is its lens, never a small correction, and holding k3 and k4 at
zero while k1 and k2 move biases a 170-degree fisheye's focal length by
several sigmas.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.errors import SolveError, in_words
from camnet.model.calibration import FreeSet
from camnet.model.camera import CameraInfo, LensModel
from camnet.model.projection import FISHEYE_DIST_SIZE, FISHEYE_INTRINSIC_NAMES, INTRINSIC_NAMES, N_INTRINSICS
from camnet.solve import bundle, schur
from camnet.solve.bundle import CEN, ROT, CentreMode, Problem, State
from camnet.solve.report.scale_cause import GIVE_PAIR_ROTATION, HELD_YAW_SHARE, TIGHTEN_PAIR_TOLERANCE
from camnet.solve.uncertainty import (
    Covariance,
    covariance,
    covariance_with_pp_prior,
    held_at_tolerance,
    residual_dof,
    scale_gradient,
    scale_sigma,
    scale_sigmas,
    scale_weights,
    with_guessed_pp,
)

FREE_NAMES = ("f", "aspect", "pp", "k1", "k2", "fisheye", "stereo_rotation", "stereo_direction")
CANDIDATES = ("stereo_pitch_roll", "stereo_direction", "stereo_yaw", "pp", "k1", "k2")

# Freeing a stereo block that moves the scale's sigma by more than this needs the data to ask for it (module
# docstring). 2 parts the two kinds: the pitch, roll and baseline direction barely move the scale's sigma on any
# family, a yaw where the principal points are given or free multiplies it (docs/benchmarks.md, "Evidence
# behind the solver's thresholds").
COSTLY_INFLATION = 2.0
# 1 sigma, degrees, of each rotation axis of a stereo pair held as the ideal parallel pair, in the reported
# uncertainty (`held_at_tolerance`; calibrate.Options.pair_tolerance_deg). A factory-rectified head (ZED, OAK-D,
# RealSense) is parallel to 0.01-0.02 degrees, but camnet cannot tell rectified images from raw ones, whose
# modules are aligned mechanically to a few tenths of a degree; what the rule cannot see decides: a toe-in too
# small for it to free (below 4 of the yaw's sigmas, module docstring: about a quarter of a degree on a ring
# head) must lie within 3 of the reported sigmas, and a tolerance of 0.08 degrees covers such toe-ins where
# smaller ones do not (docs/benchmarks.md, "A stereo pair held parallel"); a head known to be better gives its own.
PAIR_TOLERANCE_DEG = 0.08
_SLOT = {name: i for i, name in enumerate(INTRINSIC_NAMES)}  # a camera's intrinsic columns
_SLOTS = {"pp": (_SLOT["cx"], _SLOT["cy"]), "k1": (_SLOT["k1"],), "k2": (_SLOT["k2"],)}
_PITCH, _YAW, _ROLL = ROT.start, ROT.start + 1, ROT.start + 2  # rotation about x, y, z
_TURNS = {"stereo_pitch_roll": (0, 2), "stereo_yaw": (1,)}  # the right camera's rotation axes a block frees
_DIRECTION = (CEN.start, CEN.start + 1)  # the two tangent slots of a centre on the baseline sphere
_FISHEYE_K = slice(_SLOT["k1"], _SLOT["k1"] + FISHEYE_DIST_SIZE)  # a fisheye camera's coefficients


def free_names(free: str | frozenset[str]) -> frozenset[str]:
    """The names freed from the start: f and fisheye for "auto", else the explicit set, checked."""
    if free == "auto":
        return frozenset({"f", "fisheye"})
    unknown = set(free) - set(FREE_NAMES)
    if unknown:
        raise SolveError(f"free: unknown {in_words(sorted(unknown), noun='parameter')}; expected some of "
                         f"{in_words(FREE_NAMES)}")
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


@dataclass(frozen=True)
class ScaleCost:
    """What freeing a block does to the network's scale (relative, 0.001 = 0.1%), at the held solution."""

    held: float  # the scale's standard deviation with the block held
    free: float  # with it free
    shift: float  # the change of the scale the Gauss-Newton step with the block free makes
    assumed: float = 0.0  # with it held at the pair's tolerance (the sigma a held block is reported with)

    @property
    def added_variance(self) -> float:
        return max(self.free**2 - self.held**2, 0.0)

    @property
    def inflation(self) -> float:
        """free / held: how much the scale's sigma grows with the block free."""
        return self.free / self.held if self.held > 0 else np.inf

    @property
    def costly(self) -> bool:
        """Whether freeing the block more than doubles the scale's sigma (`COSTLY_INFLATION`)."""
        return bool(np.isfinite(self.held) and self.free > COSTLY_INFLATION * self.held)

    @property
    def shift_sigmas(self) -> float:
        """The shift in units of the sigma freeing adds: a standard normal if the block's true value is the held
        one (the Hausman statistic's root); its mean is the held block's bias on the scale in those units."""
        return abs(self.shift) / np.sqrt(self.added_variance) if self.added_variance > 0 else 0.0


def _scale_covariance(everything: Problem, problem: Problem, state: State, cov: Covariance, prior_px):
    """(covariance, block): the covariance with the block free that the scale's sigmas are taken from, and the
    block's columns in it; with the guessed principal points uncertain where prior_px (as `_try_block`'s)."""
    new = (problem.columns()[0] < 0) & (everything.columns()[0] >= 0)
    wider = None if prior_px is None else with_guessed_pp(everything, prior_px[:, 0] > 0)
    if wider is None:
        return cov, everything.columns()[0][new]
    prior = covariance_with_pp_prior(everything, wider, state, bundle.normal_equations(wider, state), prior_px)
    return prior, wider.columns()[0][new]


def _scale_cost(cov: Covariance, block: np.ndarray, ne_free, ne_held, points: np.ndarray,
                tolerance_rad: float = 0.0) -> ScaleCost:
    """The ScaleCost of freeing the camera columns `block` of `cov` (the covariance with them free).

    ne_free, ne_held: the normal equations with the block free and held, at the held least-squares solution;
    tolerance_rad: 1 sigma of a held rotation block (its `assumed` sigma).
    """
    weights = scale_weights(cov, points)
    free, held = scale_sigmas(cov, points, weights, [(), block])
    assumed = scale_sigma(held_at_tolerance(cov, block, tolerance_rad), points, weights) if tolerance_rad else held
    steps = [schur.solve_damped(ne, schur.GAUSS_NEWTON_LAMBDA) for ne in (ne_free, ne_held)]
    if steps[0] is None or steps[1] is None:
        return ScaleCost(held, free, 0.0, assumed)
    shift = float(np.sum(scale_gradient(points, weights) * (steps[0][1] - steps[1][1])))
    return ScaleCost(held, free, shift, assumed)


def _stereo_free(effect: float, wanted: bool, cost: ScaleCost, determined_px: float, significance: float) -> bool:
    """Whether the module docstring's rule frees a stereo block: determined or asked for, and where freeing
    it costs the scale, its scale shift showing beyond chance that holding it costs the scale more."""
    from scipy.stats import ncx2

    if not cost.costly:
        return bool(effect <= determined_px or wanted)
    if cost.assumed > COSTLY_INFLATION * cost.free:
        return True  # the data know it several times better than its tolerance: held, it costs more than freed
    # H0: the held block's bias on the scale is at most the sigma freeing it adds (holding costs the scale's
    # mean square error no more than freeing): the shift in added sigmas is then N(<= 1, 1).
    return bool(wanted and cost.shift_sigmas**2 > ncx2.isf(significance, 1, 1.0))


def with_block(problem: Problem, name: str, cameras: np.ndarray) -> Problem:
    """`problem` with the candidate block `name` also free (for `cameras` (M,) bool, per-camera blocks)."""
    intr_free, rot_free, centre_mode = problem.intr_free.copy(), problem.rot_free.copy(), problem.centre_mode.copy()
    if name in _TURNS:
        rot_free[1, list(_TURNS[name])] = True
    elif name == "stereo_direction":
        if centre_mode[1] == CentreMode.FIXED:  # a FREE centre (a soft stereo baseline) turns already
            centre_mode[1] = CentreMode.ON_BASELINE
    else:
        for s in _SLOTS[name]:
            intr_free[cameras, s] = True
    return problem.freeing(intr_free=intr_free, rot_free=rot_free, centre_mode=centre_mode)


def choose_free(
    problem: Problem, state: State, *, determined_px: float, significance: float, widths, heights, held_K, held_dist,
    max_iterations: int = 300, guessed_pp: np.ndarray | None = None, pp_prior_rel: float = 0.0,
    pair_tolerance_deg: float = 0.0,
) -> tuple[Problem, State, list[str]]:
    """Apply the rule of the module docstring; returns (problem, state, decisions).

    `state` is the least-squares solution of `problem`. Both tests are
    linearised at the least-squares solution of the problem as it stands:
    the standard deviation from the covariance with the block free, the cost
    decrease from the Gauss-Newton step with it free (the score test,
    first-order equal to the likelihood ratio). Each freed block moves the
    solution, so it is solved again before the next test: a test made away
    from the minimum measures the distance to it, not the block.

    guessed_pp (M,) bool: the cameras whose principal point is held at the
    image centre because nobody gave one; pp_prior_rel: 1 sigma of such a
    guess, relative to the image's width and height. A stereo block's cost
    to the scale is weighed with them uncertain, as the reported sigma is.
    pair_tolerance_deg: 1 sigma of a held rotation block (calibrate.Options):
    a costly one whose tolerance costs the scale more than twice what
    freeing it does is freed (the data know it better than the tolerance).
    """
    prior_px = None
    if guessed_pp is not None and pp_prior_rel > 0 and guessed_pp.any():
        prior_px = np.where(guessed_pp[:, None], pp_prior_rel * np.column_stack([widths, heights]), 0.0)
    tests = (determined_px, significance, widths, heights, held_K, held_dist, prior_px, np.radians(pair_tolerance_deg))
    decisions, turned = [], []
    after_stereo = problem.intr_free  # what the camera blocks free comes after the stereo blocks
    for name in CANDIDATES:
        # A camera block is tried again for the cameras still held once others are freed:
        # their misfit, spread over every camera before, then stands out.
        for _ in range(1 if name.startswith("stereo") else problem.n_cameras):
            trial, decision = _try_block(name, problem, state, *tests)
            if decision:
                decisions.append(decision)
            if trial is problem:
                break
            if name in _TURNS and trial.columns()[1] > problem.columns()[1]:
                turned.append(name)
            problem = trial
            state, _ = bundle.solve(problem, state, max_iterations=max_iterations)
        if name == "stereo_yaw":  # the last of the stereo blocks
            after_stereo = problem.intr_free
    # Tried again where a camera block was freed after them: its misfit may have been what asked for them.
    for name in turned if (problem.intr_free != after_stereo).any() else ():
        rot_free = problem.rot_free.copy()
        rot_free[1, list(_TURNS[name])] = False
        held = problem.freeing(rot_free=rot_free)
        R = state.R.copy()
        R[1] = np.eye(3)  # the ideal pair's, where the rule started; the axes still free find their angles again
        held_state, _ = bundle.solve(held, replace(state, R=R), max_iterations=max_iterations)
        trial, decision = _try_block(name, held, held_state, *tests)
        if trial is held:
            problem, state = held, held_state
            decisions.append(f"{decision}, tried again")
    return problem, state, decisions


def _try_block(name, problem: Problem, state: State, determined_px, significance, widths, heights, held_K, held_dist,
               prior_px, tolerance_rad):
    """(problem with the block `name` freed where the rule says so, the decision's text).

    prior_px (M, 2) or None: 1 sigma of the guessed principal points, pixels (0: not guessed).
    """
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
    cov = covariance(everything, state, normal=restricted(everything))
    effect = _pixel_effect(name, state, cov, widths, heights)
    if name.startswith("stereo"):
        k = int(everything.columns()[1] - problem.columns()[1])
        wanted, statistic = significant(everything, k)
        cost = _scale_cost(*_scale_covariance(everything, problem, state, cov, prior_px), restricted(everything),
                           restricted(problem), state.X, tolerance_rad if name in _TURNS else 0.0)
        free = _stereo_free(effect, wanted, cost, determined_px, significance)
        # What freeing costs the scale, and where it is costly, the scale's evidence for it.
        shift = f", its shift {cost.shift_sigmas:.2g} of the sigma it adds" if cost.costly else ""
        if cost.costly and cost.assumed > cost.held:
            shift += f"; held, at the pair's tolerance x{cost.assumed / cost.held:.2g}"
        text = (f"{name}: {'free' if free else 'held'} (sigma {effect:.2g} px, chi2 {statistic:.3g} on {k} dof; "
                f"free, the scale's sigma x{cost.inflation:.2g}{shift})")
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


def held_yaw_warning(pair: tuple[str, str], data: Covariance, yaw: int, held: np.ndarray, reported: Covariance,
                     points: np.ndarray, tolerance_deg: float, *, given: bool = False) -> str | None:
    """The warning of a solve whose scale rests on the pair's yaw held (parallel, or at a given rotation), or None.

    data: the covariance with the held rotation axes free (their data alone); yaw: its column of the
    right camera's yaw; held: its columns of every held axis; reported: the covariance reported, with
    the axes held at `tolerance_deg`; given: the axes are held at a rotation given (a factory head's,
    scale_cause.held_at_given_pose), not at the parallel pair. It warns where the reported sigma is more
    than HELD_YAW_SHARE times that of a pair exactly as held: the scale then rests on the assumption,
    and the verdict names it (camnet.solve.report.scale_cause). A tolerance so small that it adds little (a
    head known to be that parallel, a pose given as exact) leaves nothing to warn of, however much freeing
    the yaw would cost.
    """
    weights = scale_weights(reported, points)
    g = scale_gradient(points, weights)
    # The scale's regression on the yaw below takes var(scale | yaw): all three share their products with W.
    free, exact, given_yaw = data.variances(None, g, [(), held, [yaw]])
    yaw_sd = np.sqrt(data.cameras[yaw, yaw])
    sigma = scale_sigma(reported, points, weights)
    if not (exact > 0 and yaw_sd > 0 and sigma > HELD_YAW_SHARE * np.sqrt(exact)):
        return None
    # The scale's regression on the yaw: cov(scale, yaw) / var(yaw), from var(scale) - var(scale | yaw).
    per_tenth = np.sqrt(max(free - given_yaw, 0.0)) / yaw_sd * np.radians(0.1)
    # What freeing it costs the scale, where the data determine it.
    freed = f"free its rotation (--free stereo_rotation: {100 * np.sqrt(free):.2g}%)" if np.isfinite(free) else ""
    said = f"the scale is uncertain by {100 * sigma:.2g}% (1 sigma) and rests on the stereo pair ({pair[0]}, {pair[1]})"
    if given:  # its rotation is there already: what is unknown is how well it holds
        return (f"{said} held at its given rotation in yaw (stereo_yaw held), counted to {tolerance_deg:g} degrees "
                f"(1 sigma): {100 * np.sqrt(exact):.2g}% were it exactly as given, and each 0.1 degree its yaw is "
                f"off moves the scale by {100 * per_tenth:.2g}%: {TIGHTEN_PAIR_TOLERANCE}"
                + (f"; if it may be off more, {freed}" if freed else ""))
    # Worded as the report's other messages of an uncertain scale, of which it is then the one.
    return (f"{said} held parallel in yaw (stereo_yaw held), counted parallel to {tolerance_deg:g} degrees "
            f"(1 sigma): {100 * np.sqrt(exact):.2g}% were it exactly parallel, and each 0.1 degree it is toed in "
            f"moves the scale by {100 * per_tenth:.2g}%: {GIVE_PAIR_ROTATION}"
            + (f"; if it may be toed in more, {freed}" if freed else ""))
