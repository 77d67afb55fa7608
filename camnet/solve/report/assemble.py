"""The solve report of a calibration: uncertainty, per-camera statistics, warnings,
and which points the calibration reports.

Documented in docs/calibration-keys.md.
"""

from __future__ import annotations

import numpy as np

from camnet.errors import SolveError, in_words
from camnet.model import rowwise
from camnet.model.calibration import (
    CameraStats,
    FreeSet,
    PointsLeftOut,
    Sigma,
    SolveReport,
    StartKind,
    Uncertainty,
)
from camnet.model.methods import Method
from camnet.model.projection import project_points
from camnet.solve.bundle import ROT, CentreMode, Problem, State
from camnet.solve.report.camera_sigmas import camera_sigmas_by_id, undetermined_names
from camnet.solve.report.residual_structure import structure_warnings
from camnet.solve.report.scale_cause import (
    GIVE_STEREO_K,
    HELD_YAW_SHARE,
    ScaleCause,
    pair_rotation_todo,
    scale_cause,
)
from camnet.solve.uncertainty import Covariance, distance_checks, scale_sigmas, scale_weights

MIN_CAMERA_OBSERVATIONS = 12
MIN_PARALLAX_DEG = 2.0
COPLANAR_RATIO = 0.02
POOR_FOCAL_REL = 0.05
POOR_SCALE_REL = 0.01
UNDETERMINED_SCALE = "not determined by the observations"
MAX_LINEAR_FOCAL_REL = 0.15  # a stereo focal length's relative sigma beyond which the scale has no linear sigma
# A freed principal point this far from where it was given (the image centre where nobody gave it), as a share
# of the image's width or height, is no lens's (they sit a percent or so away): the data trade it with the
# camera's rotation and focal length along a curved, nearly flat valley of the cost, where linear sigmas mean
# nothing (docs/benchmarks.md, "Real images: the temple ring").
MAX_PP_OFFSET_REL = 0.1
MAX_DEPTH_BASELINES = 1000.0  # a scene farther than this many baselines has next to no disparity
DISTANCE_SIGMAS = 3.0  # a known distance this many sigmas from where the scene puts it is reported
# A start that left cameras out, then a solution of the rest that rejects many of their observations: the
# start was wrong and the sigmas mean nothing. A sound solve keeps nearly all of its observations, and a camera
# placed right in a live pool of real matches this share or more, while a wrong start's solution keeps well
# under it; the RMS tells nothing apart (docs/benchmarks.md, "Rigs unlike the paper's").
WRONG_START_INLIER_SHARE = 0.8


def _parallax_deg(problem, state) -> np.ndarray:
    """Per point, the widest angle between two of its viewing rays."""
    rays = state.X[problem.pt] - state.C[problem.cam]
    rays /= rowwise.lengths(rays)[:, None]
    # The angle to the mean ray, doubled, is a cheap stand-in for the widest pair.
    mean = np.stack([np.bincount(problem.pt, rays[:, k], minlength=problem.n_points) for k in range(3)], axis=1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    cosang = np.clip(rowwise.dots(rays, mean[problem.pt]), -1.0, 1.0)
    return 2.0 * _per_point_max(problem, np.degrees(np.arccos(cosang)), 0.0)


def _per_point_max(problem: Problem, values: np.ndarray, empty: float) -> np.ndarray:
    """(N,) the largest of `values` (n,), one per observation of `problem`, per point; `empty` where a
    point has none."""
    rows, starts = problem.by_point
    seen = starts[1:] > starts[:-1]
    out = np.full(problem.n_points, empty)
    if seen.any():
        out[seen] = np.maximum.reduceat(values[rows], starts[:-1][seen])
    return out


def _held_disparity_warning(obs, order, problem, state) -> list[str]:
    """The scale's sensitivity to the difference of the stereo pair's principal-point columns, when held.

    A column difference shifts every disparity by as much; with the right
    camera's yaw and principal point held, the uncertainty cannot show it.
    """
    right = obs.cameras[order[1]]
    known = right.K is not None and "K" in right.fixed
    if known or problem.rot_free[1, 1] or problem.intr_free[1, 2]:
        return []
    depth_m = float(np.median(state.X[:, 2])) if len(state.X) else np.nan
    disparity_px = state.intr[0, 0] * np.linalg.norm(state.C[1]) / depth_m
    if not np.isfinite(disparity_px) or disparity_px <= 0:
        return []
    return [
        f"the scale assumes the stereo cameras' principal points in the same column: each pixel of "
        f"difference moves it by {100 / disparity_px:.2f}% (give the pair's K, or free stereo_rotation)"
    ]


def free_parameters(problem: Problem, camera_ids: list[str]) -> FreeSet:
    """Which intrinsics and stereo rotation axes moved: reused by warm starts."""
    return FreeSet(
        intrinsics={
            cam_id: tuple(n for n, free in zip(problem.intrinsic_names(m), problem.intr_free[m], strict=True) if free)
            for m, cam_id in enumerate(camera_ids)
        },
        stereo_rotation_axes=tuple(ax for ax, free in zip("xyz", problem.rot_free[1], strict=True) if free),
        stereo_direction=bool(problem.centre_mode[1] == CentreMode.ON_BASELINE),
    )


def reported_points(
    problem: Problem, state: State, cov: Covariance | None, *, camera_points: np.ndarray | None = None
) -> tuple[np.ndarray, PointsLeftOut]:
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
    nearest = -_per_point_max(problem, -rowwise.lengths(xc), -np.inf)
    undetermined = np.zeros(problem.n_points, dtype=bool)
    if cov is not None:
        undetermined = np.sqrt(3.0) * cov.point_sigmas_m() >= nearest
    few = views < 2
    kept = ~few & ~behind & ~undetermined
    dropped = PointsLeftOut(
        fewer_than_two_views=int(few.sum()),
        behind_a_camera=int((~few & behind).sum()),
        undetermined=int((~few & ~behind & undetermined).sum()),
    )
    return kept, dropped


def _uncertainty(ids: list[str], problem, state, cov: Covariance, kept, warnings: list[str],
                 notes: list[str], normal, pair_pose_given: bool, far_pp: dict[int, float],
                 pp_guessed: np.ndarray) -> Uncertainty:
    """The solution's uncertainty; appends the warnings and notes it gives rise to.

    normal: the solve's unweighted normal equations at `state` in cov's layout (or None);
    pair_pose_given: the pair's held rotation axes are held at a given pose, not the parallel pair's;
    far_pp: problem camera -> how far its freed principal point moved (_far_pp_rel), where beyond
    MAX_PP_OFFSET_REL; pp_guessed (M,): no principal point was given (it started at the image centre).
    """
    weights = scale_weights(cov, state.X, kept)
    exact_columns = _exact_columns(problem, cov)
    sigmas = _scale_sigmas(cov, state.X, weights, exact_columns) if kept.any() else None
    scale = None if sigmas is None else sigmas[0]
    undetermined_scale = scale is not None and not np.isfinite(scale)
    if undetermined_scale:
        scale = None
    per_cam = camera_sigmas_by_id(ids, problem, state, cov)
    # Depth goes with the stereo cameras' focal lengths: known only to tens of percent, the
    # solution is beyond where a linear sigma means anything (docs/benchmarks.md, "Evidence
    # behind the solver's thresholds", MAX_LINEAR_FOCAL_REL).
    pair_focal_rel = max(per_cam[ids[m]].f_px / state.intr[m, 0] for m in (0, 1))
    pair_loose_pp = [m for m in (0, 1) if m in far_pp]
    nonlinear = scale is not None and (pair_focal_rel > MAX_LINEAR_FOCAL_REL or bool(pair_loose_pp))
    if nonlinear:
        scale = None
    warnings += _distance_warnings(ids, problem, state, cov, normal)
    for m, cam_id in enumerate(ids):
        unknown = undetermined_names(per_cam[cam_id])
        if unknown:
            warnings.append(
                f"camera {cam_id}: {', '.join(unknown)} not determined by the observations (sigma null); "
                "give them (K, dist) or add views that share more points with it"
            )
        elif per_cam[cam_id].f_px > POOR_FOCAL_REL * state.intr[m, 0]:
            warnings.append(f"camera {cam_id}: focal length poorly determined (sigma {per_cam[cam_id].f_px:.0f} px)")
        if m in far_pp and not unknown:
            warnings.append(
                f"camera {cam_id}: its principal point, freed, moved {100 * far_pp[m]:.0f}% of the image from "
                f"{_pp_start([pp_guessed[m]], 'it was')} (no lens's is that far off): it trades with the focal length "
                "and rotation, which may be wrong by several of their sigmas; give its K"
            )
    scale_if_pp, scale_if_pair, scale_if_both = _scale_if_exact(exact_columns, sigmas, scale)
    unknown_scale = UNDETERMINED_SCALE
    if nonlinear and pair_loose_pp:
        unknown_scale = (f"the stereo cameras' principal points, freed, moved up to "
                         f"{100 * max(far_pp[m] for m in pair_loose_pp):.0f}% of the image from "
                         f"{_pp_start(pp_guessed[pair_loose_pp], 'they were')}, trading with their focal lengths "
                         "beyond where a linear sigma holds; give their K")
        warnings.append(f"the scale is not determined: {unknown_scale}")
    elif nonlinear:
        unknown_scale = (f"the stereo cameras' focal lengths are known to {100 * pair_focal_rel:.0f}% only (1 sigma); "
                         "give their K")
        warnings.append(f"the scale is not determined: {unknown_scale}")
    elif undetermined_scale:
        warnings.append("the scale is not determined by the observations and the known distances")
    elif scale is None:
        warnings.append("no point is determined: the scale is unknown")
    uncertainty = Uncertainty(
        sigma_px=cov.sigma_px,
        scale_rel=Sigma(scale) if scale is not None else Sigma.unknown(unknown_scale),
        scale_rel_if_pp_exact=(
            Sigma(scale_if_pp) if scale_if_pp is not None else Sigma.unknown("no principal point was guessed")
        ),
        scale_rel_if_pair_exact=(
            Sigma(scale_if_pair) if scale_if_pair is not None
            else Sigma.unknown("no rotation axis of the stereo pair was held at a tolerance")
        ),
        scale_rel_if_pp_and_pair_exact=(
            Sigma(scale_if_both) if scale_if_both is not None
            else Sigma.unknown("not both a principal point guessed and a pair's axis held")
        ),
        cameras=per_cam,
        point_weights=weights[kept],
        point_sigma_m=cov.point_sigmas_m()[kept],
    )
    if scale is not None and scale > POOR_SCALE_REL:
        _scale_message(scale_cause(uncertainty), bool(problem.n_cameras >= 2 and not problem.rot_free[1, 1]),
                       warnings, notes, given=pair_pose_given)
    return uncertainty


def _pp_start(guessed, were: str) -> str:
    """Where principal points started, as a message says it: "the image centre" where none was given, "where
    {were} given" where all were; `guessed`: whether each was not given."""
    if all(guessed):
        return "the image centre"
    return f"where {were} given" if not any(guessed) else "where given (the image centre where not)"


def _far_pp_rel(problem, state, m: int, given_px: np.ndarray, size_px: np.ndarray) -> float:
    """Camera m's freed principal point's offset from `given_px` as a share of the image (the larger of x / width
    and y / height), where beyond MAX_PP_OFFSET_REL; else 0."""
    if not problem.intr_free[m, 2:4].any():
        return 0.0
    rel = float(np.max(np.abs(state.intr[m, 2:4] - given_px) / size_px))
    return rel if rel > MAX_PP_OFFSET_REL else 0.0


def _scale_message(cause: ScaleCause, yaw_held: bool, warnings: list[str], notes: list[str], *,
                   given: bool = False) -> None:
    """Append the message of a scale uncertain beyond POOR_SCALE_REL, with what it rests on (scale_cause).

    yaw_held: whether the pair's yaw is held, and so whether free_rule.held_yaw_warning says what the scale
    rests on where the held rotation takes most of its variance (the message is then that warning);
    given: the pair's rotation is held at a given pose, not the parallel pair's.
    """
    said = f"the scale is uncertain by {100 * cause.sigma:.1f}% (1 sigma)"
    if cause.scene:
        warnings.append(said)
        return
    if cause.pp and not cause.pair:
        # What a guessed principal point costs is a caveat of every solve nobody gave K, not a fault
        # of this one: a note while the data alone fix the scale, a warning when they do not.
        (notes if cause.if_pp <= POOR_SCALE_REL else warnings).append(
            f"{said}, {100 * cause.if_pp:.2g}% were the principal points exactly at the image centres: "
            f"{GIVE_STEREO_K}")
        return
    if yaw_held and cause.sigma > HELD_YAW_SHARE * cause.if_pair:  # held_yaw_warning's, which says it
        if cause.pp:
            warnings.append(f"the scale's sigma rests on the guessed principal points as well: "
                            f"{100 * cause.if_pp:.2g}% were they exactly at the image centres: {GIVE_STEREO_K}")
        return
    todo = pair_rotation_todo(given)
    if cause.pp:
        warnings.append(f"{said}, {100 * cause.if_both:.2g}% were the principal points at the image centres and "
                        f"the stereo pair's held rotation exact: {GIVE_STEREO_K}, and {todo}")
    else:
        warnings.append(f"{said}, {100 * cause.if_pair:.2g}% were the stereo pair's held rotation exact: {todo}")


def _exact_columns(problem, cov: Covariance) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The covariance's columns of (the guessed principal points, the pair's held rotation axes, both), each
    None where absent: those the scale's sigma is taken given (`_scale_if_exact`).

    The covariance has more columns than the problem where guessed principal points entered as a
    prior (calibrate._uncertainty), and where the right stereo camera's held rotation axes entered at
    the pair's tolerance (uncertainty.held_at_tolerance).
    """
    cols = cov.columns
    pp = cols[:, 2:4][(cols[:, 2:4] >= 0) & ~problem.intr_free[:, 2:4]]
    pair = np.zeros(0, dtype=int)
    if problem.n_cameras >= 2:
        turns = cols[1, ROT]
        pair = turns[(turns >= 0) & ~problem.rot_free[1]]
    both = np.concatenate([pp, pair]) if len(pp) and len(pair) else None
    return (pp if len(pp) else None), (pair if len(pair) else None), both


def _scale_sigmas(cov: Covariance, points: np.ndarray, weights: np.ndarray, exact_columns) -> list[float]:
    """The scale's sigma, then its sigma given each of `exact_columns` (`_exact_columns`) present, in their
    order: all at once, as they share the scale's products with W (`uncertainty.scale_sigmas`)."""
    return scale_sigmas(cov, points, weights, [(), *[c for c in exact_columns if c is not None]])


def _scale_if_exact(columns, sigmas: list[float] | None, scale: float | None):
    """(sigma were the guessed principal points exact, were the pair's held rotation exact, were both): the
    scale's sigma with only that cause of its variance removed, each None where that cause is absent.

    columns: `_exact_columns`; sigmas: the scale's sigma, then its sigma given each of the columns
    present, in their order (`uncertainty.scale_sigmas`). The Gaussian conditional on a column is the
    sigma were it exactly as held (held_at_tolerance's update leaves that conditional as it was).
    """
    if scale is None:
        return None, None, None
    given = iter(sigmas[1:])
    return tuple(None if c is None else next(given) for c in columns)


def _distance_warnings(ids: list[str], problem, state, cov: Covariance, normal) -> list[str]:
    """Known distances that the scene (every other row) contradicts."""
    if not len(problem.distances):
        return []
    scene_m, sigma_m = distance_checks(problem, state, cov, normal=normal)
    known = problem.distances
    z = np.abs(scene_m - known.metres) / np.hypot(sigma_m, known.sigma_m)
    return [
        f"cameras {ids[a]} and {ids[b]}: the scene puts them {scene_m[k]:.4f} m apart (1 sigma "
        f"{1e3 * sigma_m[k]:.1f} mm), not the given {known.metres[k]:.4f} m ({z[k]:.0f} sigma): check that "
        "distance and the cameras it names"
        for k, (a, b) in enumerate(known.cams) if z[k] > DISTANCE_SIGMAS
    ]


def _geometry_warnings(obs, order, problem, state, parallax: np.ndarray, kept: np.ndarray) -> list[str]:
    """Little parallax, coplanar points, a scene too far for the baseline."""
    warnings = []
    if len(parallax) and np.median(parallax) < MIN_PARALLAX_DEG:
        warnings.append(
            f"little parallax: the median point is seen under {np.median(parallax):.2f} deg; "
            "depth and focal lengths are weakly determined"
        )
    body = state.X[kept]
    sv = np.linalg.svd(body - body.mean(axis=0), compute_uv=False) if len(body) >= 3 else np.ones(3)
    if sv[2] < COPLANAR_RATIO * sv[0]:
        warnings.append("the points are nearly coplanar; focal lengths and poses trade off")
    if len(body):
        warnings += far_scene_warning(float(np.median(np.linalg.norm(body - state.C[0], axis=1))),
                                      obs.stereo.baseline_m)
    return warnings


def far_scene_warning(median_depth_m: float, baseline_m: float) -> list[str]:
    """A warning when the scene's median point is more than MAX_DEPTH_BASELINES baselines away."""
    ratio = median_depth_m / baseline_m
    if ratio <= MAX_DEPTH_BASELINES:
        return []
    return [f"the median point is {ratio:.0f} baselines away ({median_depth_m:.3g} m for {baseline_m:.3g} m): "
            "at that ratio the scale is barely determined; check the baseline's unit (metres) and that the "
            "cameras see a common scene nearby"]


def solve_report(
    obs, order, problem, state, cov, inliers, info, *, method: Method, decisions: list[str],
    timings_s: dict[str, float], kept: np.ndarray, dropped: PointsLeftOut, residuals_px: np.ndarray,
    start: StartKind, pair_pose_given: bool = False, placed_tracks: np.ndarray | None = None,
) -> SolveReport:
    """The report of a solve.

    order: problem camera m is observations camera order[m]; inliers (n,):
    the observations kept; info: the final adjustment's bundle.SolveInfo;
    kept (N,): the points the calibration reports; residuals_px (n, 2): the
    problem's reprojection residuals at `state`, pixels; pair_pose_given:
    the pair's held rotation axes, if any, are held at a given pose;
    placed_tracks: the track rows the start placed (None: every track).
    """
    ids = [obs.cameras[i].id for i in order]
    counts = np.bincount(problem.cam, minlength=len(ids))
    squares = np.bincount(problem.cam, weights=rowwise.squared_lengths(residuals_px), minlength=len(ids))
    warnings = []
    cameras = {}
    for m, cam_id in enumerate(ids):
        n_in = int(counts[m])
        cameras[cam_id] = CameraStats(rms_px=float(np.sqrt(squares[m] / n_in)) if n_in else None, inliers=n_in)
        if n_in < MIN_CAMERA_OBSERVATIONS:
            warnings.append(f"camera {cam_id}: only {n_in} inlier observations; its calibration is weak")
    parallax = _parallax_deg(problem, state)[kept]
    warnings += _geometry_warnings(obs, order, problem, state, parallax, kept)
    if method != Method.PAPER:  # eq. 13 is no least-squares fit of every camera: its residuals differ by design
        # A track the start could not place (its rays part too little to fix a depth) is not one rejected.
        placed = np.ones(len(obs.uv), bool) if placed_tracks is None else np.isin(obs.track_index, placed_tracks)
        observed = np.bincount(obs.cam_index[placed], minlength=len(obs.cameras))[order]
        warnings += structure_warnings(ids, problem.cam, problem.uv, residuals_px, state.intr,
                                       problem.intr_free[:, 4], observed)
    notes: list[str] = []
    sizes = np.array([(obs.cameras[i].width, obs.cameras[i].height) for i in order], dtype=float)
    pp_guessed = np.array([obs.cameras[i].K is None for i in order])
    pp_given = np.array([sizes[k] / 2 if obs.cameras[i].K is None else obs.cameras[i].K[:2, 2]
                         for k, i in enumerate(order)])
    far_pp = {m: rel for m in range(len(ids)) if (rel := _far_pp_rel(problem, state, m, pp_given[m], sizes[m]))}
    uncertainty = None if cov is None else _uncertainty(ids, problem, state, cov, kept, warnings, notes, info.normal,
                                                        pair_pose_given, far_pp, pp_guessed)
    # The held column offset is priced into the scale's sigma when the principal points entered as
    # a guess with its prior: then a caveat (a note), else the sigma cannot show it (a warning).
    priced = uncertainty is not None and uncertainty.scale_rel_if_pp_exact.value is not None
    (notes if priced else warnings).extend(_held_disparity_warning(obs, order, problem, state))
    return SolveReport(
        method=method,
        converged=bool(info.converged),
        reason=info.reason,
        iterations=int(info.iterations),
        observations=int(len(inliers)),
        inliers=int(np.sum(inliers)),
        cameras=cameras,
        median_parallax_deg=float(np.median(parallax)) if len(parallax) else None,
        free=free_parameters(problem, ids),
        free_rule=tuple(decisions),
        warnings=tuple(warnings),
        points_left_out=dropped,
        start=start,
        timings_s=dict(timings_s),
        uncertainty=uncertainty,
        notes=tuple(notes),
        # Said where an axis is held only: where every one moved, nothing rests on a pose given.
        pair_pose_given=bool(pair_pose_given and problem.n_cameras >= 2 and not problem.rot_free[1].all()),
        far_principal_points={ids[m]: rel for m, rel in far_pp.items()},
    )


def refuse_undetermined(report: SolveReport) -> None:
    """Refuse a solution whose scale the observations do not determine: it is no calibration.

    Parameters the data leave free elsewhere are reported (sigma null, a
    warning naming them); without a scale nothing of the network is known. A
    scale beyond the linear range (stereo focal lengths known to tens of
    percent) is a calibration with its scale sigma null and a warning saying why.
    """
    u = report.uncertainty
    if u is not None and u.scale_rel.reason == UNDETERMINED_SCALE:
        cameras = [cam_id for cam_id, sigmas in u.cameras.items() if undetermined_names(sigmas)]
        also = f" (nor {in_words(cameras, noun='camera')})" if cameras else ""
        raise SolveError(f"the observations do not determine the scale{also}: too few points agree with one "
                         "solution; check the tracks and that the cameras see a common scene")


def refuse_wrong_start(report: SolveReport, rms_px: float, *, pair_K_given: bool = False) -> None:
    """Refuse a solution whose start left cameras out and which then rejects many of the rest's observations.

    rms_px: the calibration's reprojection RMS over its inliers, for the
    message. Either alone is no proof (a camera that sees nothing the others
    see is left out of a sound solve; false matches are rejected from one),
    both together are: the cameras placed disagree with the geometry the
    start gave them. pair_K_given: the observations give both stereo
    cameras' K, so the message does not ask for it.
    """
    if not report.cameras_left_out or not report.observations:
        return
    share = report.inliers / report.observations
    if share >= WRONG_START_INLIER_SHARE:
        return
    give_K = "" if pair_K_given else "give the stereo pair's K or "
    raise SolveError(
        f"start: {in_words(sorted(report.cameras_left_out), noun='camera')} could not be placed, and the solution of "
        f"the others keeps only {100 * share:.0f}% of their observations (RMS {rms_px:.2f} px): the start went wrong, "
        f"so this is no calibration; {give_K}choose a pair that sees more of the scene together, and check the matches"
    )
