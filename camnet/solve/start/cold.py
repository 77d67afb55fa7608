"""A solve's start from nothing but the observations: the scale pair, then the view graph.

Any two cameras with a known distance can be the scale pair. Where their
matches lie on matching rows as closely as on any epipolar lines, the pair
is the paper's parallel pair and the paper's solver starts the solve as it
always did. Otherwise (or where that solver finds no plausible start) the
second camera is placed by the relative pose of the essential matrix
(camnet.model.two_view), its translation scaled to the known distance,
at the focal lengths (given, Bougnoux's or a sweep's) that a third camera
agrees with best. Every other camera is then placed through the cameras
that share its tracks (camnet.solve.start.register); one that cannot be is
left out, by name, with the reason, and the rest is solved.

Cameras are in problem order (the pair first), pixels centred, poses
``x_cam = R (X - C)`` in the left camera's frame, metres.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from camnet.errors import SolveError, in_words
from camnet.model.calibration import SolveReport
from camnet.model.observations import Observations, Stereo
from camnet.model.resection import MIN_RESECTION_POINTS, resect
from camnet.model.triangulation import triangulate_missing
from camnet.model.two_view import (
    MIN_PAIR_POINTS,
    RelativePose,
    focal_grid,
    homography_explains,
    pair_focals,
    relative_pose,
    row_and_epipolar_errors,
)
from camnet.solve.context import SolveContext, camera_order, threshold_px
from camnet.solve.start.paper_start import paper_start
from camnet.solve.start.register import register_over_graph, seed_adjustment
from camnet.solve.start.state import PairStart, Start

log = logging.getLogger(__name__)

MIN_CAMERAS = 3  # two views of unknown focal length need a third (eq. 15)
# The paper's pair, to start with: its matches on rows that match (eq. 4) within this many times their
# distance from a general pair's epipolar lines, plus a floor for exact data; most of its tracks in front of
# it by the paper's triangulation.
PARALLEL_ROWS_RATIO = 3.0
PARALLEL_ROWS_FLOOR_PX = 0.1
PARALLEL_IN_FRONT = 0.8
SEED_TRIALS = 4  # the pair's focal lengths a third view fits best, adjusted with it to choose one
WEAK_PAIR_RATIO = 3.0  # a failed solve names a pair that shares this many times the stereo pair's tracks


class NoStart(SolveError):
    """The start asked for cannot be made from these observations (nothing was solved from it)."""


def without_unobserved(obs: Observations) -> tuple[Observations, dict[str, str]]:
    """(observations, {camera id: why}): `obs` without the cameras that have no observation, each named
    with why it is left out; refused where fewer than MIN_CAMERAS cameras would be left.

    Such a camera cannot be placed, whatever is known of it. The stereo
    pair's cameras stay: `check_solvable` refuses a pair that shares nothing.
    """
    seen = np.zeros(len(obs.cameras), dtype=bool)
    seen[obs.cam_index] = True
    seen[[obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)]] = True
    if seen.all():
        return obs, {}
    unseen = [obs.cameras[i].id for i in np.flatnonzero(~seen)]
    if seen.sum() < MIN_CAMERAS:
        raise SolveError(
            f"cameras: {in_words(unseen)} {'has' if len(unseen) == 1 else 'have'} no observations, which leaves "
            f"{int(seen.sum())}; a metric solve needs at least {MIN_CAMERAS} (eq. 15): give every camera a view of "
            "what the others see"
        )
    why = "it has no observations (no track reaches it): give it a view of what the other cameras see"
    return obs.only_cameras(seen), dict.fromkeys(unseen, why)


def check_solvable(obs: Observations) -> None:
    """Refuse observations that cannot determine a metric network: too few cameras, or a pair that shares too little."""
    if len(obs.cameras) < MIN_CAMERAS:
        raise SolveError(f"cameras: {len(obs.cameras)} given; a metric solve needs at least {MIN_CAMERAS} (eq. 15)")
    order = camera_order(obs)
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), dtype=bool)
    seen[obs.track_index, obs.cam_index] = True
    shared = int(np.sum(seen[:, order[0]] & seen[:, order[1]]))
    if shared < MIN_PAIR_POINTS:
        raise SolveError(
            f"tracks: the stereo pair ({obs.stereo.left}, {obs.stereo.right}) shares only {shared} tracks; "
            f"need at least {MIN_PAIR_POINTS} (choose two cameras that see the same part of the scene)"
        )


def pair_advice(obs: Observations) -> str:
    """What to do when a solve from this stereo pair failed, if another pair shares many more tracks; else "".

    A pair that sees little of the scene together (two cameras far round a
    ring) gives the start few points and a weak relative pose; the pair that
    shares the most tracks starts better (its distance is then what to know).
    """
    found = stronger_pair(obs)
    if found is None:
        return ""
    a, b, shared_ab, shared_pair = found
    return (f"; the stereo pair ({obs.stereo.left}, {obs.stereo.right}) shares only {shared_pair} tracks, "
            f"{obs.cameras[a].id} and {obs.cameras[b].id} share {shared_ab}: name as the stereo pair two "
            "cameras that see more of the scene together, with their distance")


def stronger_pair(obs: Observations) -> tuple[int, int, int, int] | None:
    """`strongest_pair` where its two cameras share WEAK_PAIR_RATIO times the stereo pair's tracks; else None."""
    return _strongest(obs, WEAK_PAIR_RATIO)


def strongest_pair(obs: Observations) -> tuple[int, int, int, int] | None:
    """(a, b, tracks a and b share, tracks the stereo pair shares) for the two observations cameras a, b that
    share the most tracks; None where they are the stereo pair.

    Two cameras at one viewpoint (a homography explains their matches,
    `two_view.homography_explains`) share the most tracks of all, and fix
    no relative pose: they are passed over, for the next pair.
    """
    return _strongest(obs, 0.0)


def _strongest(obs: Observations, ratio: float) -> tuple[int, int, int, int] | None:
    """`strongest_pair`, None where it shares fewer than `ratio` times the stereo pair's tracks."""
    seen = np.zeros((len(obs.track_ids), len(obs.cameras)), dtype=bool)
    seen[obs.track_index, obs.cam_index] = True
    shared = seen.T.astype(int) @ seen  # (cameras, cameras) tracks each two share
    left, right = obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)
    enough = ratio * shared[left, right]
    rows = np.full(seen.shape, -1)
    rows[obs.track_index, obs.cam_index] = np.arange(len(obs.uv))
    a_of, b_of = np.triu_indices(len(obs.cameras), k=1)
    for k in np.argsort(-shared[a_of, b_of], kind="stable"):
        a, b = int(a_of[k]), int(b_of[k])
        if shared[a, b] < enough or {a, b} == {left, right}:
            return None
        both = seen[:, a] & seen[:, b]
        uv_a, uv_b = obs.uv[rows[both, a]], obs.uv[rows[both, b]]
        if homography_explains(uv_a, uv_b, threshold_px=threshold_px(obs, camera_order(obs))):
            log.info("%s and %s share %d tracks, but one homography maps them: no baseline, no start",
                     obs.cameras[a].id, obs.cameras[b].id, shared[a, b])
            continue
        return a, b, int(shared[a, b]), int(shared[left, right])
    return None


def is_parallel(rows_px: float, epipolar_px: float) -> bool:
    """Whether a pair is the paper's parallel pair, from `two_view.row_and_epipolar_errors`.

    The essential matrix cannot tell: with a short baseline, or a small
    object, its rotation and translation trade off. Matches that fix no
    rows (infinite rows_px) make no parallel pair.
    """
    return bool(np.isfinite(rows_px) and rows_px <= PARALLEL_ROWS_RATIO * epipolar_px + PARALLEL_ROWS_FLOOR_PX)


def pair_looks_parallel(obs: Observations) -> bool:
    """Whether `cold_start` takes the stereo pair for the paper's parallel pair (`is_parallel`)."""
    ctx = SolveContext.of(obs)
    left, right = _pair_rows(ctx)
    return is_parallel(*row_and_epipolar_errors(ctx.xy[left], ctx.xy[right], threshold_px=ctx.threshold_px))


def _pair_rows(ctx: SolveContext) -> tuple[np.ndarray, np.ndarray]:
    """The pair's observation rows (left, right) of the tracks both see."""
    left, right = ctx.camera_rows(0), ctx.camera_rows(1)
    both = (left >= 0) & (right >= 0)
    return left[both], right[both]


def _essential_start(ctx: SolveContext, f_pair, pose: RelativePose) -> Start:
    """The pair placed by its relative pose, the translation scaled to the known distance, its tracks triangulated."""
    obs, order, xy, rows = ctx.obs, ctx.order, ctx.xy, ctx.rows
    M, T = len(order), len(obs.track_ids)
    f = np.full(M, np.nan)
    f[:2] = f_pair
    R = np.tile(np.eye(3), (M, 1, 1))
    C = np.zeros((M, 3))
    R[1], C[1] = pose.R, obs.stereo.baseline_m * pose.centre_direction
    X = np.full((T, 3), np.nan)
    registered = np.arange(M) < 2
    triangulate_missing(order, xy, rows, f, R, C, X, registered)
    return Start(f, R, C, X, registered, np.full((T, 3), np.nan), f[1] / f[0], parallel=False,
                 pair=PairStart.ESSENTIAL)


def _focal_candidates(ctx: SolveContext) -> list[tuple[float, float]]:
    """The pair's focal lengths to try: as given, else a sweep and Bougnoux's from the fundamental matrix."""
    given = ctx.intr[:2, 0]
    if np.all(np.isfinite(given)):
        return [(given[0], given[1])]
    grid = focal_grid(ctx.camera(0).width)
    candidates = [tuple(np.where(np.isfinite(given), given, f)) for f in grid]
    left, right = _pair_rows(ctx)
    from_F = pair_focals(ctx.xy[left], ctx.xy[right], threshold_px=ctx.threshold_px)
    bougnoux = np.where(np.isfinite(given), given, from_F)
    if np.all((grid[0] <= bougnoux) & (bougnoux <= grid[-1])):
        candidates.append(tuple(bougnoux))
    return candidates


def _essential_by_third_view(ctx: SolveContext) -> Start:
    """The essential-matrix start at the pair's focal lengths that the camera sharing most of its tracks fits best.

    Two cameras that look at one object hardly fix their focal lengths
    (their optical axes nearly meet); a third view of the pair's
    triangulated points does.
    """
    obs, order, intr, xy, rows = ctx.obs, ctx.order, ctx.intr, ctx.xy, ctx.rows
    left, right = _pair_rows(ctx)
    both = np.flatnonzero((rows[:, order[0]] >= 0) & (rows[:, order[1]] >= 0))
    shared = [len(np.flatnonzero(rows[both, order[m]] >= 0)) for m in range(2, len(order))]
    third = 2 + int(np.argmax(shared))
    candidates = _focal_candidates(ctx)
    if len(candidates) > 1 and max(shared) < MIN_RESECTION_POINTS:
        raise SolveError(
            f"tracks: no camera shares more than {max(shared)} tracks with the stereo pair ({obs.stereo.left}, "
            f"{obs.stereo.right}); need at least {MIN_RESECTION_POINTS} seen by the pair and another camera "
            "(or give the pair's K)"
        )
    threshold = ctx.threshold_px
    placed = []  # (MSAC of the third camera, start with it placed)
    for f_pair in candidates:
        pose = relative_pose(xy[left], xy[right], *f_pair, threshold_px=threshold)
        if pose is None or pose.inliers.sum() < MIN_PAIR_POINTS:
            continue
        start = _essential_start(ctx, f_pair, pose)
        if len(candidates) == 1:
            return start
        trk = np.flatnonzero(np.all(np.isfinite(start.X), axis=1) & (rows[:, order[third]] >= 0))
        got = resect(start.X[trk], xy[rows[trk, order[third]]], f_px=intr[third, 0] if np.isfinite(intr[third, 0])
                     else None, width_px=obs.cameras[order[third]].width, threshold_px=threshold)
        if not isinstance(got, str):
            f, R, C, X, registered = start.working()
            f[third], R[third], C[third], registered[third] = got.f_px, got.R, got.C, True
            placed.append((got.msac_px2, start.placed(f, R, C, X, registered)))
    disagrees = SolveError(
        f"cameras: {obs.cameras[order[third]].id} does not agree with the stereo pair ({obs.stereo.left}, "
        f"{obs.stereo.right}) at any focal length, so the pair's are not determined; check the pair's matches"
    )
    if not placed:
        raise disagrees
    # Few shared tracks fit a wrong focal length nearly as well: the three views, adjusted, decide.
    best = (np.inf, None)
    for _, start in sorted(placed, key=lambda p: p[0])[:SEED_TRIALS]:
        cost, start = seed_adjustment(ctx, start)
        if cost < best[0]:  # a NaN cost (an adjustment that failed) is none
            best = (cost, start)
    if best[1] is None:
        raise disagrees
    log.info("the pair's focal lengths from a third view: %.0f, %.0f px (%.2f px^2)", *best[1].f[:2], best[0])
    return best[1]


def _paper_pair(ctx: SolveContext, seed, max_tracks) -> Start | str:
    """The paper's start (pair, and every camera it places when it places all); why not where it finds none."""
    try:
        start = paper_start(ctx, seed, max_tracks=max_tracks, register_rest=False)
    except SolveError as exc:
        return f"the paper's solver gives no start ({exc})"
    grid = focal_grid(ctx.camera(0).width)
    in_front = np.mean(np.isfinite(start.P0[(ctx.camera_rows(0) >= 0) & (ctx.camera_rows(1) >= 0), 0]))
    if not (grid[0] <= start.f[0] <= grid[-1] and in_front >= PARALLEL_IN_FRONT):
        return (f"the paper's solver puts the left focal length at {start.f[0]:.0f} px and {100 * in_front:.0f}% "
                "of the pair's tracks in front")
    if not start.registered.all():
        # Cameras that share few stereo tracks see them from the side, where the stereo cloud's
        # depth error shows most: they are placed again through the graph, on better points.
        f, R, C, X, registered = start.working()
        registered[2:] = False
        f[2:] = np.nan
        start = start.placed(f, R, C, X, registered)
    return replace(start, pair=PairStart.PAPER)


def _from_stronger_pair(ctx: SolveContext) -> Start:
    """The start from the two cameras that share the most tracks (`strongest_pair`), every camera placed through
    the graph from them, then put in the scale pair's frame and scaled to its distance.

    A scale pair far apart sees few tracks together: their essential matrix,
    and the third view that fixes their focal lengths, rest on those few,
    where a pair that sees much together fixes its own well.
    """
    obs, order = ctx.obs, ctx.order
    found = strongest_pair(obs)
    if found is None:
        raise NoStart("the stereo pair is the pair of cameras that shares the most tracks: its own starts are the "
                      "strongest pair's")
    a, b = obs.cameras[found[0]].id, obs.cameras[found[1]].id
    log.info("starting from %s and %s, which share %d tracks (the stereo pair %d)", a, b, found[2], found[3])
    seed_obs = replace(obs, stereo=Stereo(a, b, 1.0))  # a unit distance until the scale pair's is known
    seed_order = camera_order(seed_obs)
    m_of = [order.index(i) for i in seed_order]  # seed camera k is problem camera m_of[k]
    seed = SolveContext(seed_obs, tuple(seed_order), ctx.intr[m_of], ctx.xy, ctx.rows)
    start, _ = register_over_graph(seed, _essential_by_third_view(seed), hold_pair=False)
    k_of = np.argsort(m_of)  # problem camera m is seed camera k_of[m]
    f, R, C, placed = start.f[k_of], start.R[k_of], start.C[k_of], start.registered[k_of]
    if not placed[:2].all():
        raise NoStart(f"the view graph from {a} and {b} does not reach the stereo pair ({obs.stereo.left}, "
                      f"{obs.stereo.right})")
    # x_cam = R (X - C) is kept under X' = s R0 (X - C0): R' = R R0^T, C' = s R0 (C - C0).
    R0, C0 = R[0].copy(), C[0].copy()
    s = obs.stereo.baseline_m / np.linalg.norm(C[1] - C0)
    R, C, X = R @ R0.T, s * (C - C0) @ R0.T, s * (start.X - C0) @ R0.T
    return Start(f, R, C, X, placed, np.full_like(X, np.nan), f[1] / f[0], parallel=False, pair=PairStart.STRONGEST)


def _scale_pair_start(ctx: SolveContext, *, seed, max_tracks, paper_only, pair: PairStart) -> Start:
    """The scale pair placed as the paper's parallel pair or by its essential matrix (see `cold_start`)."""
    left, right = _pair_rows(ctx)
    rows_px, epipolar_px = row_and_epipolar_errors(ctx.xy[left], ctx.xy[right], threshold_px=ctx.threshold_px)
    parallel = is_parallel(rows_px, epipolar_px) if pair == PairStart.AUTO else pair == PairStart.PAPER
    log.info("the stereo pair's matches lie %.2f px off matching rows, %.2f px off epipolar lines: %s (%s)",
             rows_px, epipolar_px, "parallel" if parallel else "not parallel", pair.value)
    if paper_only:
        if not parallel:
            raise SolveError(
                f"method paper: the stereo pair's matches lie {rows_px:.1f} px off matching rows, so it is not "
                "parallel as the paper's method needs; use the refined method"
            )
        return replace(paper_start(ctx, seed, max_tracks=max_tracks), pair=PairStart.PAPER)
    start = _paper_pair(ctx, seed, max_tracks) if parallel else None
    if isinstance(start, str):
        if pair == PairStart.PAPER:  # asked for, so not made another way: the caller tries the others itself
            raise NoStart(start)
        log.info("%s: starting from the essential matrix", start)
        start = None
    return _essential_by_third_view(ctx) if start is None else start


def cold_start(
    ctx: SolveContext, *, seed: int, max_tracks: int | None, paper_only: bool = False,
    pair: PairStart = PairStart.AUTO,
) -> Start:
    """The start of a solve with no previous calibration; `Start.left_out` names the cameras it could not place,
    `Start.pair` how the scale pair was placed.

    paper_only:
    the paper's method, which needs a parallel pair and every camera
    sharing six stereo tracks (raises if not). pair: how the pair is
    placed (`PairStart`): AUTO decides from its matches, and starts from the
    essential matrix where the paper's solver finds no plausible start; any
    other raises `NoStart` where it cannot be made.
    """
    if pair == PairStart.STRONGEST and not paper_only:
        start = _from_stronger_pair(ctx)
    else:
        start = _scale_pair_start(ctx, seed=seed, max_tracks=max_tracks, paper_only=paper_only, pair=pair)
        if paper_only:
            return start
    start, reasons = register_over_graph(ctx, start, hold_pair=start.parallel)
    start = replace(start, left_out={ctx.camera(m).id: reasons[m] for m in np.flatnonzero(~start.registered)})
    if start.registered.sum() < MIN_CAMERAS:
        raise SolveError(
            f"cameras: only {int(start.registered.sum())} could be placed; a metric solve needs at least "
            f"{MIN_CAMERAS} (" + "; ".join(f"{c}: {r}" for c, r in start.left_out.items()) + ")"
        )
    return start


def only_placed(ctx: SolveContext, start: Start) -> tuple[SolveContext, Start]:
    """(context, start) with only the cameras the start placed; the same tracks, the problem order kept, the
    intrinsics the context had."""
    obs, order = ctx.obs, ctx.order
    keep = np.flatnonzero(start.registered)
    obs = obs.only_cameras(np.isin(np.arange(len(obs.cameras)), [order[m] for m in keep]))
    start = start.placed(start.f[keep], start.R[keep], start.C[keep], start.X, start.registered[keep])
    return SolveContext.of(obs, ctx.intr[keep]), start


def with_cameras_left_out(report: SolveReport, left_out: dict[str, str]) -> SolveReport:
    """`report` naming the cameras left out (besides those it names), each also in a warning: the user must
    see them."""
    if not left_out:
        return report
    warned = tuple(f"camera {cam_id} left out: {why}" for cam_id, why in left_out.items())
    return replace(report, cameras_left_out={**report.cameras_left_out, **left_out},
                   warnings=report.warnings + warned)
