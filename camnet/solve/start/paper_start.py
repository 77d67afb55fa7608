"""The paper's start: the scale pair as a parallel pair, every camera that shares six stereo tracks by DLT and
eq. 13, then the rest by alternate registration and triangulation.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (camnet.solve.context.centred). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

import logging

import numpy as np

from camnet.errors import SolveError
from camnet.model import paper
from camnet.model.resection import MIN_INLIER_SHARE
from camnet.model.triangulation import triangulate_missing
from camnet.solve.context import SolveContext
from camnet.solve.start.state import MIN_REGISTRATION_POINTS, Start

log = logging.getLogger(__name__)

EQ13_START_FTOL = 1e-4  # eq. 13 as a start for the adjustment: its last digits do not matter
# The paper's method itself: solved to its minimum, so that its digits do not depend on where SciPy stops.
EQ13_FTOL = 1e-12


def paper_start(ctx: SolveContext, seed: int, max_tracks: int | None = None, register_rest: bool = True) -> Start:
    """The paper's unknowns from nothing but the observations, then every camera and track.

    max_tracks: use at most this many tracks per camera in eq. 13, which is
    plenty for a starting point; None uses all (the paper's method itself).
    register_rest: place the other cameras and every track, else the caller does.
    """
    obs, order, intr, xy, rows = ctx.obs, ctx.order, ctx.intr, ctx.xy, ctx.rows
    M, T = len(order), len(obs.track_ids)
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
    stretched = _stretched_cameras(ctx, P0, seed)
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
            f_left, f[others], R[others], C[others], P0, cams, ftol=EQ13_FTOL if max_tracks is None else EQ13_START_FTOL
        )
        f[0], f[1] = f_left, k * f_left
        X = P0 * np.array([1.0, 1.0, f_left])
        registered[others] = True
    if register_rest:
        register_and_triangulate(ctx, f, R, C, X, registered, seed=seed)
    return Start(f, R, C, X, registered, P0, k)


def _stretched_cameras(ctx: SolveContext, P0, seed) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{problem index: (DLT matrix on the stretched stereo cloud P0, its inlier tracks)} of the other cameras."""
    obs, order, xy, rows = ctx.obs, ctx.order, ctx.xy, ctx.rows
    has_P0 = np.all(np.isfinite(P0), axis=1)
    threshold = ctx.threshold_px
    stretched = {}
    for m in range(2, len(order)):
        trk = np.flatnonzero(has_P0 & (rows[:, order[m]] >= 0))
        if len(trk) < MIN_REGISTRATION_POINTS:
            continue
        got = _stretched_dlt(P0[trk], xy[rows[trk, order[m]]], threshold, seed)
        if isinstance(got, str):
            log.info("the paper's start leaves %s to the view graph: %s", obs.cameras[order[m]].id, got)
            continue
        stretched[m] = (got[0], trk[got[1]])
    return stretched


def _stretched_dlt(P0: np.ndarray, x: np.ndarray, threshold: float, seed: int) -> tuple[np.ndarray, np.ndarray] | str:
    """(P, inliers) of a camera on the stretched stereo cloud, or why the camera cannot join eq. 13.

    A camera that shares a few false tracks with the pair, or sees only the
    floor among them (coplanar points leave a DLT undetermined), would pull
    every focal length of the paper's start: it is placed later, through the view graph.
    """
    try:
        P, inl = paper.dlt_ransac(P0, x, threshold_px=threshold, seed=seed)
    except SolveError as exc:
        return f"{len(P0)} stereo tracks, {exc}"
    if inl.mean() < MIN_INLIER_SHARE:
        return f"{int(inl.sum())} of its {len(P0)} stereo tracks agree on a camera (fewer than {MIN_INLIER_SHARE:.0%})"
    if not np.all(np.isfinite(paper.focals_from_stretched_dlt(P))):
        return f"its {int(inl.sum())} agreeing stereo tracks do not fix a camera (nearly on one plane, or too few)"
    return P, inl


def register_and_triangulate(ctx: SolveContext, f, R, C, X, registered, *, seed: int) -> None:
    """Alternately register cameras (DLT on known points) and triangulate tracks, in the arrays given.

    f, R, C, registered (M, ...) and X (T, 3): the start's arrays in the making.
    """
    obs, order, xy, rows = ctx.obs, ctx.order, ctx.xy, ctx.rows
    M = len(order)
    threshold = ctx.threshold_px
    while True:
        progress = False
        for m in np.flatnonzero(~registered):
            has_X = np.all(np.isfinite(X), axis=1) & (rows[:, order[m]] >= 0)
            trk = np.flatnonzero(has_X)
            if len(trk) < MIN_REGISTRATION_POINTS:
                continue
            P, _ = paper.dlt_ransac(X[trk], xy[rows[trk, order[m]]], threshold_px=threshold, seed=seed)
            f[m], R[m], C[m] = paper.pose_from_dlt(P)
            registered[m] = True
            progress = True
        progress |= triangulate_missing(order, xy, rows, f, R, C, X, registered) > 0
        if not progress or registered.all():
            break
    if not registered.all():
        missing = [obs.cameras[order[m]].id for m in range(M) if not registered[m]]
        raise SolveError(
            f"cameras {missing}: too few tracks shared with the solved cameras to place them "
            f"(need at least {MIN_REGISTRATION_POINTS})"
        )
    triangulate_missing(order, xy, rows, f, R, C, X, registered)
