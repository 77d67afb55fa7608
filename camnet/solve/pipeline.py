"""From observations to a metric calibration.

Methods:

- ``paper``: the paper's solver alone (stereo triangulation, eq. 13); the
  principal points as given or at the image centre, no distortion.
- ``refined`` (default): a start from the data (camnet.solve.start.cold:
  the paper's solution for a parallel pair, else the essential matrix, then
  every camera through the view graph; cameras it cannot place are left
  out and named in the report), then a bundle adjustment that keeps the
  stereo pair rigid with its baseline ``baseline_m`` (and every further
  known distance), with a robust loss, outlier rejection and the
  free-intrinsics rule below. Every cold solve runs from the scale pair's
  start and from the two cameras that share the most tracks (the pair's
  other start where none is sound), keeps the one of least truncated cost,
  and names a rival that fits nearly as well yet differs, its sigmas
  widened to cover it (camnet.solve.start.choice).
- ``unconstrained``: the same adjustment with the right camera free in 3-D and
  no known distance, as structure from motion: the scale is left to the optimiser.

Which intrinsics move (``free="auto"``): the focal length of every camera
always (unless the observations fix K), and the pose of every camera outside
the stereo pair. Then, in this order, each block is freed when the data
determine it or ask for it (camnet.solve.free_rule): the right stereo
camera's pitch and roll, the direction of its baseline, its yaw, the
principal points, k1, k2 (the last three camera by camera). A block that is
neither is held at its given value (K and dist in the observations) or the
ideal (image centre, no distortion, a parallel pair; one not started as such
is free). Outliers are judged before the rule with the stereo pair free to
turn. An explicit ``free`` set replaces the rule.

Warm starts (``initial=``) reuse the previous solution's points and free
parameters; when every camera still fits its observations only the new
tracks get a robust fit before the least-squares adjustment
(the report's ``start`` says which path ran). ``reset_cameras`` places
bumped cameras again (see `calibrate`).

Every solve then asks a second opinion (``Options.halves``,
camnet.solve.halves): its scene's two halves solved apart from cold starts,
and the sigmas widened to what they disagree on.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Collection
from dataclasses import replace

import numpy as np

from camnet import blas
from camnet.errors import SolveError, in_words
from camnet.model import rowwise
from camnet.model.calibration import Calibration, StartKind
from camnet.model.camera import Camera
from camnet.model.methods import Method
from camnet.model.observations import Observations
from camnet.model.projection import INTRINSIC_NAMES, N_INTRINSICS, K_from_intrinsics, project_points
from camnet.solve import bundle
from camnet.solve.bundle import CentreMode, Problem, State
from camnet.solve.context import SolveContext
from camnet.solve.free_rule import (
    PAIR_TOLERANCE_DEG,
    choose_free,
    free_mask,
    free_names,
    held_yaw_warning,
    restore_free,
)
from camnet.solve.halves import with_halves_check
from camnet.solve.known_distances import known_distances
from camnet.solve.lens_check import with_lens_check
from camnet.solve.options import Options, World
from camnet.solve.pair_check import with_pair_check
from camnet.solve.report.assemble import (
    refuse_undetermined,
    refuse_wrong_start,
    reported_points,
    solve_report,
)
from camnet.solve.report.scale_cause import held_at_given_pose
from camnet.solve.result import Result
from camnet.solve.robust_fit import (
    fit_points,
    inliers_and_sigma,
    near_solution,
    reject_outliers,
    robust_passes,
)
from camnet.solve.start.choice import solve_from_any_start
from camnet.solve.start.cold import (
    PairStart,
    check_solvable,
    cold_start,
    only_placed,
    pair_advice,
    with_cameras_left_out,
    without_unobserved,
)
from camnet.solve.start.state import Start
from camnet.solve.start.warm import warm_start
from camnet.solve.uncertainty import (
    Covariance,
    covariance_with_pp_prior,
    held_at_tolerance,
    held_turn_columns,
    with_guessed_pp,
    with_held_turns,
)
from camnet.solve.world_frame import with_floor_frame

log = logging.getLogger(__name__)

MIN_CAMERA_INLIERS = 6  # fewer observations cannot fix a camera's pose and focal length
_DIST = slice(INTRINSIC_NAMES.index("k1"), N_INTRINSICS)  # a camera's distortion among its intrinsics


# ---------------------------------------------------------------- the adjustment


def _problem(ctx: SolveContext, rows_kept, track_rows, intr_free, rot_free, right_centre) -> Problem:
    obs, order = ctx.obs, list(ctx.order)
    m_of = np.empty(len(obs.cameras), dtype=int)
    m_of[order] = np.arange(len(order))
    pt_of = np.full(len(obs.track_ids), -1)
    pt_of[track_rows] = np.arange(len(track_rows))
    centre_mode = np.full(len(order), CentreMode.FREE)
    centre_mode[0] = CentreMode.FIXED
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
        fisheye=obs.fisheye(order),
    )


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
    A camera with no observation is left out, named in the report with why.
    """
    check_solvable(obs)  # before any start reads the pair's matches
    obs, unobserved = without_unobserved(obs)
    if unobserved:  # nothing of theirs to reset
        reset_cameras = [c for c in ([reset_cameras] if isinstance(reset_cameras, str) else reset_cameras)
                         if c not in unobserved]
    try:
        # The dense products here have a few hundred rows: BLAS threads gain little on
        # them, and on a machine shared with drivers and the matcher they stall each other.
        with blas.one_thread():
            if initial is None and options.method == Method.REFINED:  # one start may find another minimum
                result = solve_from_any_start(
                    obs, lambda pair: _calibrate(obs, options, None, reset_cameras, pair),
                    outlier_sigmas=options.outlier_sigmas, min_outlier_px=options.min_outlier_px)
            else:
                result = _calibrate(obs, options, initial, reset_cameras)
    except np.linalg.LinAlgError:
        raise SolveError(f"the observations do not determine the calibration (singular equations){pair_advice(obs)}"
                         ) from None
    if options.world == World.FLOOR:
        result = with_floor_frame(result, obs)
    if options.halves:  # after the floor frame: it widens the floor's sigmas with every other
        result = replace(result, calibration=with_second_opinion(obs, result.calibration, options))
    if not unobserved:
        return result
    report = with_cameras_left_out(result.calibration.report, unobserved)
    return replace(result, calibration=replace(result.calibration, report=report))


def with_second_opinion(obs: Observations, cal: Calibration, options: Options) -> Calibration:
    """`cal`, solved from `obs`, with the second opinion: the scene's halves solved apart and compared
    (camnet.solve.halves), each camera's pose against its own two views (camnet.solve.pair_check), and the lenses
    nobody described freed (camnet.solve.lens_check)."""
    obs, _ = without_unobserved(obs)
    # Each half from a cold start: warm from the whole, it keeps the whole's outliers and basin and agrees.
    alone = replace(options, halves=False, world=World.LEFT_CAMERA)
    cal = with_halves_check(obs, cal, lambda half: calibrate(half, alone).calibration,
                            truncation_px=options.truncation_px(cal.rms_reprojection_px),
                            polish=lambda half, start: solved_from(half, alone, start))
    return with_lens_check(obs, with_pair_check(obs, cal), options, solved_from)


def solved_from(obs: Observations, options: Options, initial: Calibration) -> Calibration:
    """`obs` solved with `options` warm from `initial`."""
    return calibrate(obs, options, initial=initial).calibration


def _calibrate(
    obs: Observations, options: Options, initial: Calibration | None, reset_cameras: Collection[str],
    pair: PairStart = PairStart.AUTO,
) -> Result:
    if options.method not in tuple(Method):
        raise SolveError(f"method: unknown {options.method}; expected {in_words([m.value for m in Method], last='or')}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    check_solvable(obs)
    ctx = SolveContext.of(obs)
    reset = _reset_indices(ctx, reset_cameras)
    if initial is not None and reset & {0, 1}:
        log.info("a stereo camera is reset: solving from scratch")
        initial = None
    given = held_at_given_pose(initial)  # the pair's held rotation: the start's, parallel where cold
    if options.pair_tolerance_deg is None:
        # A start nobody solved here (a factory head's published pose) is held as given, as a fixed K is,
        # unless the caller says to what it is known.
        factory = initial is not None and initial.report is None
        options = replace(options, pair_tolerance_deg=0.0 if factory else PAIR_TOLERANCE_DEG)
    ctx, start = _start(ctx, initial, reset, options, pair)
    if start.left_out:  # the calibration holds the cameras placed; the report names the others
        ctx, start = only_placed(ctx, start)
    obs, held_K, held_dist = ctx.obs, ctx.held_K, ctx.held_dist
    intr = ctx.intr.copy()
    intr[:, 0] = np.where(np.isfinite(intr[:, 0]) & held_K, intr[:, 0], start.f)
    timings["initialise"] = time.perf_counter() - t0
    if options.method == Method.PAPER:
        return _paper_result(ctx, intr, start, timings)

    full, track_rows = _full_problem(ctx, start, options, initial)
    state = State(intr, start.R.copy(), start.C.copy(), start.X[track_rows])
    t1 = time.perf_counter()
    near, start_kind = False, StartKind.COLD
    if initial is not None:
        new_points = ~np.isin(obs.track_ids[track_rows], initial.point_ids)
        state = fit_points(full, state, new_points, options)
        r = bundle.residuals(full, state)
        near = near_solution(full, r, options)
        start_kind = StartKind.WARM if near else StartKind.WARM_ROBUST
    if not near:
        state = robust_passes(full, state, options, cold=initial is None, held_K=held_K, held_dist=held_dist,
                               hold_pair=start.parallel)
        r = None
    inliers, sigma_px = inliers_and_sigma(full, state, options, residuals=r)
    full = replace(full, distance_sigma_px=sigma_px)  # the distances' weight
    problem = full.subset(inliers)
    timings["robust_adjustment"] = time.perf_counter() - t1

    decisions: list[str] = []
    if options.free == "auto" and (initial is None or options.free_again) and options.method != Method.UNCONSTRAINED:
        t2 = time.perf_counter()
        # A warm start's pair stays as it was solved (or given): the rule frees more, from there.
        full, problem, state, inliers, decisions = _apply_free_rule(
            ctx, full, problem, state, inliers, options, ideal_pair=start.parallel and initial is None)
        timings["choose_free"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    guessed_pp = ctx.guessed_K & ~held_K & (options.pp_prior_rel > 0)
    problem, state, inliers, info, wider, projected = _adjust_inliers(full, problem, state, inliers, guessed_pp,
                                                                      options)
    timings["adjustment"] = time.perf_counter() - t3
    _check_camera_inliers(ctx, problem)
    t4 = time.perf_counter()
    sizes = np.array([(ctx.camera(m).width, ctx.camera(m).height) for m in range(ctx.n_cameras)], dtype=float)
    cov, warning = None, None
    if options.method != Method.UNCONSTRAINED:
        cov = covariance_with_pp_prior(problem, wider, state, info.normal, options.pp_prior_rel * sizes,
                                       info.eliminated)
        cov, warning = _held_pair(obs, problem, wider, state, cov, options.pair_tolerance_deg, given)
    timings["uncertainty"] = time.perf_counter() - t4
    timings["total"] = time.perf_counter() - t0
    result = _result(
        ctx, problem, state, track_rows, inliers, info, cov, decisions, options.method, timings,
        start=start_kind, left_out=start.left_out, projected=projected, pair_start=start.pair, pair_pose_given=given,
    )
    return result if warning is None else _with_warning(result, warning)


def _start(ctx: SolveContext, initial, reset, options: Options, pair: PairStart) -> tuple[SolveContext, Start]:
    """(context, start): from `initial` where there is one (the context then with its intrinsics), else cold (the
    paper's solver alone for its method)."""
    if initial is not None:
        return warm_start(ctx, initial, reset=reset)
    paper_only = options.method == Method.PAPER
    return ctx, cold_start(ctx, seed=options.seed, max_tracks=None if paper_only else 150, paper_only=paper_only,
                           pair=pair)


def _with_warning(result: Result, warning: str) -> Result:
    return replace(result, calibration=result.calibration.warned(warning))


def _held_pair(obs, problem: Problem, wider: Problem | None, state: State, cov: Covariance, tolerance_deg: float,
               given: bool):
    """(covariance, warning): `cov` (with the pair's held rotation axes free, where `wider` frees them) with those
    axes held at their tolerance, and the warning of a scale that rests on the yaw held (or None); given: held at
    a given rotation, not the parallel pair's."""
    held = np.zeros(0, dtype=int) if wider is None else held_turn_columns(problem, wider)
    if not len(held):
        return cov, None
    reported = held_at_tolerance(cov, held, np.radians(tolerance_deg))
    warning = None
    if not problem.rot_free[1, 1]:  # the yaw
        yaw = int(wider.columns()[0][1, bundle.ROT.start + 1])
        warning = held_yaw_warning((obs.stereo.left, obs.stereo.right), cov, yaw, held, reported, state.X,
                                   tolerance_deg, given=given)
    return reported, warning


def _full_problem(ctx: SolveContext, start: Start, options: Options, initial: Calibration | None):
    """(problem, track_rows): every observation of the tracks the start placed, and what moves at first.

    track_rows: problem point j is track row track_rows[j]. A warm start
    under the automatic rule takes over the free set of `initial`.
    """
    obs, order, held_K, held_dist = ctx.obs, ctx.order, ctx.held_K, ctx.held_dist
    M = len(order)
    has_X = np.all(np.isfinite(start.X), axis=1)
    track_rows = np.flatnonzero(has_X)
    keep_obs = has_X[obs.track_index]
    names = free_names(options.free)
    intr_free = free_mask(M, names, held_K, held_dist, fisheye=obs.fisheye(order))
    rot_free = np.zeros((M, 3), dtype=bool)
    rot_free[2:] = True  # every camera outside the stereo pair turns freely
    if "stereo_rotation" in names or options.method == Method.UNCONSTRAINED or not start.parallel:
        rot_free[1] = True
    restored = None
    if initial is not None and options.free == "auto" and initial.report is not None:
        restored = initial.report.free
    if restored is not None:
        cameras = [obs.cameras[i] for i in order]
        restore_free(restored, cameras, intr_free, rot_free, fixed_K=held_K, fixed_dist=held_dist)
    if options.method == Method.UNCONSTRAINED or obs.stereo.sigma_m > 0:  # soft: held by its distance row
        right_centre = CentreMode.FREE
    elif "stereo_direction" in names or (restored is not None and restored.stereo_direction) or not start.parallel:
        right_centre = CentreMode.ON_BASELINE
    else:
        right_centre = CentreMode.FIXED
    full = _problem(ctx, np.flatnonzero(keep_obs), track_rows, intr_free, rot_free, right_centre)
    known = full.distances if options.method == Method.UNCONSTRAINED else known_distances(obs, list(order))
    return replace(full, distances=known), track_rows


def _apply_free_rule(ctx: SolveContext, full: Problem, problem: Problem, state: State, inliers, options: Options,
                     *, ideal_pair):
    """(full, problem, state, inliers, decisions): the automatic free set, chosen at the least-squares solution
    (of the ideal pair where the pair started as the paper's); the inliers judged again if it frees distortion."""
    widths = [ctx.camera(m).width for m in range(ctx.n_cameras)]
    heights = [ctx.camera(m).height for m in range(ctx.n_cameras)]
    held_K, held_dist = ctx.held_K, ctx.held_dist
    # The rule starts from the ideal pair: its rotation held at the identity.
    R = state.R.copy()
    R[1] = np.eye(3) if ideal_pair else R[1]
    state, _ = bundle.solve(problem, State(state.intr, R, state.C, state.X), max_iterations=options.max_iterations)
    problem, state, decisions = choose_free(
        problem, state, determined_px=options.determined_px, significance=options.significance, widths=widths,
        heights=heights, held_K=held_K, held_dist=held_dist, max_iterations=options.max_iterations,
        guessed_pp=ctx.guessed_K & ~held_K, pp_prior_rel=options.pp_prior_rel,
        pair_tolerance_deg=options.pair_tolerance_deg)
    freed_dist = (problem.intr_free[:, _DIST] & ~full.intr_free[:, _DIST]).any()
    full = replace(full, intr_free=problem.intr_free, rot_free=problem.rot_free, centre_mode=problem.centre_mode)
    if freed_dist:
        # Outliers were judged with the lens held: a wide lens's good observations far from
        # the centre lay off it. Judged again, after a robust solve, with it free.
        state, _ = bundle.solve(full, state, loss=options.loss, scale_px=options.loss_scale_px,
                                max_iterations=options.max_iterations)
        inliers, sigma_px = inliers_and_sigma(full, state, options)
        full = replace(full, distance_sigma_px=sigma_px)
        problem = full.subset(inliers)
    return full, problem, state, inliers, decisions


def _adjust_inliers(full: Problem, problem: Problem, state: State, inliers, guessed_pp, options: Options):
    """Least squares on the inliers until the inlier set settles: (problem, state, inliers, info, wider,
    projected).

    wider: `problem` with the guessed principal points freed, whose normal
    equations (for the covariance) come with the solve's last step;
    projected: `problem`'s residuals (n, 2, pixels) and camera-frame points
    (n, 3, metres) at `state`, from the last outlier test (None if it was
    not at `state`).
    """

    def adjust(problem: Problem, state: State) -> tuple[State, bundle.SolveInfo, Problem | None]:
        wider = None
        if options.method != Method.UNCONSTRAINED:
            wider = with_guessed_pp(problem, guessed_pp)
            # The pair's held rotation axes, priced at their tolerance (`_held_pair`).
            turns = with_held_turns(problem if wider is None else wider) if options.pair_tolerance_deg > 0 else None
            wider = wider if turns is None else turns
        report = problem if wider is None and options.method != Method.UNCONSTRAINED else wider  # for the covariance
        return *bundle.solve(problem, state, max_iterations=options.max_iterations, report=report), wider

    state, info, wider = adjust(problem, state)
    projected = None
    for _ in range(3):
        c = full.cam
        uv, xc = project_points(state.intr[c], state.R[c], state.C[c], state.X[full.pt], full.fisheye_rows(c))
        r = uv - full.uv
        new_inliers = reject_outliers(full, state, options, residuals=r)
        if np.array_equal(new_inliers, inliers):
            projected = r[inliers], xc[inliers]  # the report's, at the final state
            break
        inliers = new_inliers
        problem = full.subset(inliers)
        state, info, wider = adjust(problem, state)
    return problem, state, inliers, info, wider, projected


def _check_camera_inliers(ctx: SolveContext, problem: Problem) -> None:
    """Refuse a solution in which some camera keeps too few observations."""
    per_camera = np.bincount(problem.cam, minlength=ctx.n_cameras)
    if per_camera.min() < MIN_CAMERA_INLIERS:
        weak = [ctx.camera(m).id for m in np.flatnonzero(per_camera < MIN_CAMERA_INLIERS)]
        raise SolveError(
            f"{in_words(weak, noun='camera')}: fewer than {MIN_CAMERA_INLIERS} of "
            f"{'its' if len(weak) == 1 else 'their'} observations agree with the solution; the tracks look wrong or "
            "the camera moved (re-solve with it reset)"
        )


def _reset_indices(ctx: SolveContext, reset_cameras: Collection[str]) -> set[int]:
    """Problem indices of the cameras named in reset_cameras."""
    if isinstance(reset_cameras, str):  # one id, not its letters
        reset_cameras = [reset_cameras]
    ids = [ctx.camera(m).id for m in range(ctx.n_cameras)]
    unknown = sorted(set(reset_cameras) - set(ids))
    if unknown:
        raise SolveError(f"reset_cameras: unknown {in_words(unknown, noun='camera')}; the observations have "
                         f"{in_words(ids)}")
    return {ids.index(c) for c in reset_cameras}


def _paper_result(ctx: SolveContext, intr, start: Start, timings) -> Result:
    """The paper's method as solved by `paper_start`: points from the stereo pair alone."""
    obs, order, rows = ctx.obs, ctx.order, ctx.rows
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
    intr[:, 0], intr[:, _DIST] = f, 0.0
    track_rows = np.flatnonzero(has_P0)
    X = start.P0[track_rows] * np.array([1.0, 1.0, f_left])
    keep = has_P0[obs.track_index]
    problem = _problem(ctx, np.flatnonzero(keep), track_rows, np.zeros((len(order), N_INTRINSICS), bool),
                       np.zeros((len(order), 3), bool), CentreMode.FIXED)
    state = State(intr, R.copy(), C.copy(), X)
    timings["eq13"] = time.perf_counter() - t0
    timings["total"] = sum(timings.values())
    info = bundle.SolveInfo(True, "eq. 13 minimised", 0, np.nan, np.nan)
    return _result(ctx, problem, state, track_rows, np.ones(len(problem.cam), bool), info, None,
                   ["paper: principal points at the image centre, no distortion"], Method.PAPER, timings)


def _result(
    ctx: SolveContext, problem, state, track_rows, inliers, info, cov, decisions, method: Method, timings, *,
    start: StartKind = StartKind.COLD, left_out: dict[str, str] | None = None,
    projected: tuple[np.ndarray, np.ndarray] | None = None, pair_start: PairStart | None = None,
    pair_pose_given: bool = False,
) -> Result:
    """projected: the problem's residuals and camera-frame points at `state`, where the caller has them."""
    obs, order = ctx.obs, list(ctx.order)
    cameras: list[Camera | None] = [None] * len(order)
    for m, i in enumerate(order):
        info_cam, R, model = obs.cameras[i], state.R[m], obs.cameras[i].model
        K = K_from_intrinsics(state.intr[m])
        dist = state.intr[m, _DIST][: model.dist_size].copy()
        cameras[i] = Camera(info_cam.id, info_cam.width, info_cam.height, K, dist, R.copy(), -R @ state.C[m], model)
    if projected is None:
        c = problem.cam
        uv, xc = project_points(state.intr[c], state.R[c], state.C[c], state.X[problem.pt], problem.fisheye_rows(c))
        projected = uv - problem.uv, xc
    r, xc = projected
    kept, dropped = reported_points(problem, state, cov, camera_points=xc)
    rms = float(np.sqrt(np.mean(rowwise.squared_lengths(r)))) if len(r) else float("nan")
    report = solve_report(
        obs, order, problem, state, cov, inliers, info, method=method, decisions=decisions, timings_s=timings,
        kept=kept, dropped=dropped, residuals_px=r, start=start, pair_pose_given=pair_pose_given,
        placed_tracks=track_rows,
    )
    report = with_cameras_left_out(report, left_out or {})
    try:
        refuse_undetermined(report)
        refuse_wrong_start(report, rms, pair_K_given=not ctx.guessed_K[:2].any())
    except SolveError as exc:
        raise SolveError(f"{exc}{pair_advice(obs)}") from None
    calibration = Calibration(
        cameras=tuple(cameras),
        point_ids=obs.track_ids[track_rows[kept]],
        points=state.X[kept],
        rms_reprojection_px=rms,
        world_frame=obs.stereo.left,
        report=report,
    )
    return Result(calibration, state, problem, tuple(order), track_rows, cov, info.converged, info.reason, timings,
                  pair_start)


__all__ = ["Options", "Result", "calibrate", "check_solvable"]
