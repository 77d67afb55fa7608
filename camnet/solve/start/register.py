"""Registration over the view graph: every camera placed through the cameras that share its tracks.

From the scale pair's start (camnet.solve.start.cold) or a previous
calibration, the camera that sees the most placed points is resected next
(camnet.model.resection), the tracks it newly sees twice are
triangulated (camnet.model.triangulation), and a short robust
adjustment of every placed camera and point keeps errors from adding up
before the next one; points whose rays it leaves parting too little to fix
a depth are forgotten. Cameras that share nothing with the pair are placed
through their neighbours; one that cannot be placed is left out with the
reason. Once all are placed, each one placed here is checked against the
others, and placed again or left out (camnet.solve.start.recheck).

Cameras are in problem order (the pair first), pixels centred, poses
``x_cam = R (X - C)``, metres, focal lengths in pixels.
"""

from __future__ import annotations

import logging

import numpy as np

from camnet.model.methods import Loss
from camnet.model.projection import N_INTRINSICS
from camnet.model.resection import resect
from camnet.model.triangulation import triangulate_missing
from camnet.solve import bundle
from camnet.solve.bundle import CentreMode, Problem, State
from camnet.solve.context import SolveContext
from camnet.solve.start.recheck import Network, recheck_placed
from camnet.solve.start.state import Start

log = logging.getLogger(__name__)

LOCAL_ITERATIONS = 30  # a start for the next camera, not the solution
LOCAL_FTOL = 1e-4
LOCAL_LOSS_SCALE_PX = 2.0  # the robust loss bends here, as in the final adjustment's default


def local_adjustment(
    f: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray, *, aspect: np.ndarray, xy_rows: np.ndarray,
    xy: np.ndarray, placed: np.ndarray, held_K: np.ndarray, hold_pair: bool, baseline_m: float,
) -> float:
    """A short robust adjustment, in place, of the placed cameras and the points they see twice; its final
    robust cost per observation (px^2).

    f, aspect (M,), R, C (M, ...), X (T, 3): problem-order arrays; xy_rows
    (T, M): each track's observation row per camera (-1 none); xy: centred
    pixels. The gauge is the final adjustment's first pass: the left camera
    fixed, the right one held where it is when `hold_pair` (the paper's
    ideal pair, or a previous calibration's), else turning and on the
    baseline's sphere.
    """
    cams = np.flatnonzero(placed)
    seen = xy_rows[:, cams] >= 0
    tracks = np.flatnonzero(np.all(np.isfinite(X), axis=1) & (seen.sum(axis=1) >= 2))
    local_pt, local_cam = np.nonzero(seen[tracks])
    obs_rows = xy_rows[tracks[local_pt], cams[local_cam]]
    M = len(cams)
    intr = np.zeros((M, N_INTRINSICS))  # centred pixels: principal points at the origin, no distortion
    intr[:, 0], intr[:, 1] = f[cams], aspect[cams]
    intr_free = np.zeros_like(intr, dtype=bool)
    intr_free[:, 0] = ~held_K[cams]
    rot_free = np.ones((M, 3), dtype=bool)
    rot_free[0] = False
    rot_free[1] = not hold_pair
    centre_mode = np.full(M, CentreMode.FREE)
    centre_mode[0] = CentreMode.FIXED
    centre_mode[1] = CentreMode.FIXED if hold_pair else CentreMode.ON_BASELINE
    problem = Problem(local_cam, local_pt, xy[obs_rows], intr_free, rot_free, centre_mode, baseline_m, len(tracks))
    state, info = bundle.solve(
        problem, State(intr, R[cams], C[cams], X[tracks]), loss=Loss.CAUCHY, scale_px=LOCAL_LOSS_SCALE_PX,
        max_iterations=LOCAL_ITERATIONS, ftol=LOCAL_FTOL,
    )
    log.debug("local adjustment of %d cameras, %d points: %s", M, len(tracks), info.reason)
    f[cams] = state.intr[:, 0]
    R[cams], C[cams], X[tracks] = state.R, state.C, state.X
    return info.final_cost / max(len(local_cam), 1)


def seed_adjustment(ctx: SolveContext, start: Start) -> tuple[float, Start]:
    """(cost per observation px^2, start): the local adjustment of a start's placed cameras after triangulating
    what they see."""
    f, R, C, X, placed = start.working()
    triangulate_missing(ctx.order, ctx.xy, ctx.rows, f, R, C, X, placed)
    cost = local_adjustment(
        f, R, C, X, aspect=np.where(np.isfinite(ctx.intr[:, 1]), ctx.intr[:, 1], 1.0), xy_rows=ctx.problem_rows,
        xy=ctx.xy, placed=placed, held_K=ctx.held_K, hold_pair=start.parallel, baseline_m=ctx.obs.stereo.baseline_m,
    )
    return cost, start.placed(f, R, C, X, placed)


def register_over_graph(ctx: SolveContext, start: Start, *, hold_pair: bool) -> tuple[Start, dict[int, str]]:
    """(start, {problem index: reason}): `start` with every camera the view graph reaches placed, and why
    each other one is not.

    A held K's focal length is kept. hold_pair: hold the stereo pair where
    it is in the local adjustments.
    """
    f, R, C, X, placed = start.working()
    obs, order, xy, rows, intr = ctx.obs, ctx.order, ctx.xy, ctx.rows, ctx.intr
    xy_rows, held_K = ctx.problem_rows, ctx.held_K
    aspect = np.where(np.isfinite(intr[:, 1]), intr[:, 1], 1.0)
    threshold = ctx.threshold_px
    reasons: dict[int, str] = {}
    given = placed.copy()
    triangulate_missing(order, xy, rows, f, R, C, X, placed)
    while not placed.all():
        known = np.all(np.isfinite(X), axis=1)
        shared = {int(m): np.flatnonzero(known & (xy_rows[:, m] >= 0)) for m in np.flatnonzero(~placed)}
        for m in sorted(shared, key=lambda m: -len(shared[m])):
            trk = shared[m]
            got = resect(X[trk], xy[xy_rows[trk, m]], f_px=intr[m, 0] if held_K[m] else None,
                         width_px=ctx.camera(m).width, threshold_px=threshold)
            if isinstance(got, str):
                reasons[m] = got
                continue
            f[m], R[m], C[m], placed[m] = got.f_px, got.R, got.C, True
            log.debug("%s placed on %d of %d tracks", ctx.camera(m).id, got.inliers.sum(), len(trk))
            reasons.pop(m, None)
            triangulate_missing(order, xy, rows, f, R, C, X, placed)
            local_adjustment(f, R, C, X, aspect=aspect, xy_rows=xy_rows, xy=xy, placed=placed, held_K=held_K,
                             hold_pair=hold_pair, baseline_m=obs.stereo.baseline_m)
            break
        else:
            break  # no camera left that the placed ones reach
    # The views placed here, checked against all the others (the scale pair frames the network: not them).
    net = Network(order, xy, rows, f, R, C, X, placed)
    left_out, moved = recheck_placed(net, ~given & (np.arange(len(order)) >= 2), f_free=~held_K,
                                     width_px=np.array([obs.cameras[i].width for i in order]), threshold_px=threshold)
    for m in moved:
        log.info("%s placed again: its first pose disagreed with the other cameras", ctx.camera(m).id)
    reasons.update(left_out)
    if left_out or moved:
        local_adjustment(f, R, C, X, aspect=aspect, xy_rows=xy_rows, xy=xy, placed=placed, held_K=held_K,
                         hold_pair=hold_pair, baseline_m=obs.stereo.baseline_m)
    triangulate_missing(order, xy, rows, f, R, C, X, placed)
    return start.placed(f, R, C, X, placed), reasons
