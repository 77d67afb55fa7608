"""A warm start: a previous calibration's cameras and points, new tracks triangulated, moved cameras placed again.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (camnet.solve.context.centred). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import replace

import numpy as np

from camnet.errors import SolveError
from camnet.model.calibration import Calibration
from camnet.model.projection import full_dist
from camnet.model.triangulation import triangulate_missing
from camnet.solve.context import SolveContext
from camnet.solve.start.register import register_over_graph
from camnet.solve.start.state import MIN_REGISTRATION_POINTS, Start


def warm_start(ctx: SolveContext, initial: Calibration, *, reset: Collection[int] = ()) -> tuple[SolveContext, Start]:
    """(context, start) from a previous calibration: its cameras, its points, new tracks triangulated; the
    context with the previous intrinsics (its pixels centred by them).

    reset: problem indices of non-stereo cameras whose previous pose is not
    trusted; they keep their intrinsics and are registered again, by PnP
    RANSAC, on the points the other cameras determine. Cameras new to
    `initial` are placed through the view graph; `Start.left_out` names
    those it cannot place.
    """
    obs, order = ctx.obs, ctx.order
    by_id = {c.id: c for c in initial.cameras}
    M = len(order)
    intr = ctx.intr.copy()
    f = np.full(M, np.nan)
    R = np.tile(np.eye(3), (M, 1, 1))
    C = np.zeros((M, 3))
    registered = np.zeros(M, dtype=bool)
    for m, i in enumerate(order):
        cam = by_id.get(obs.cameras[i].id)
        if cam is None:
            continue
        intr[m, :4] = cam.K[0, 0], cam.K[1, 1] / cam.K[0, 0], cam.K[0, 2], cam.K[1, 2]
        intr[m, 4:] = full_dist(cam.dist)
        f[m] = cam.K[0, 0]
        if m not in reset:
            R[m], C[m] = cam.R, cam.centre
            registered[m] = True
    if not registered[:2].all():
        raise SolveError("initial calibration: it does not hold both stereo cameras")
    ctx = ctx.with_intrinsics(intr)
    X = _previous_points(obs.track_ids, initial.point_ids, initial.points)
    # A moved camera's observations of the old points are dropped (they saw its old pose): it is placed on the
    # points of its new tracks, which the cameras still in place triangulate here first.
    triangulate_missing(order, ctx.xy, ctx.rows, f, R, C, X, registered)
    for m in reset:
        if not np.isfinite(f[m]):
            continue  # not in `initial` either: registered below like any new camera
        # Points the moved camera helped to place are still fine: the other cameras hold them.
        R[m], C[m] = register_pnp(X, ctx.xy, ctx.camera_rows(m), f[m], ctx.camera(m).id, ctx.threshold_px)
        registered[m] = True
    start = Start(f, R, C, X, registered, np.full_like(X, np.nan), f[1] / f[0])
    start, reasons = register_over_graph(ctx, start, hold_pair=True)
    left_out = {ctx.camera(m).id: reasons[m] for m in np.flatnonzero(~start.registered)}
    return ctx, replace(start, k=start.f[1] / start.f[0], left_out=left_out)


def _previous_points(track_ids: np.ndarray, point_ids: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, 3) each track's point in a previous calibration (ids `point_ids`, metres), NaN where it has none.

    As a loop over the points would place them (1 us each): of tracks with one id, the last; of points with
    one id, the last."""
    X = np.full((len(track_ids), 3), np.nan)
    if not len(track_ids) or not len(point_ids):
        return X
    ids = np.asarray(track_ids, dtype=np.int64)
    pids = np.asarray(point_ids, dtype=np.int64)
    by_id = np.argsort(ids, kind="stable")
    at = np.searchsorted(ids[by_id], pids, side="right") - 1  # the last track of the id
    found = (at >= 0) & (ids[by_id[np.maximum(at, 0)]] == pids)
    last = len(pids) - 1 - np.unique(pids[::-1], return_index=True)[1]  # the last point of each id
    last = last[found[last]]
    X[by_id[at[last]]] = np.asarray(points)[last]
    return X


def register_pnp(
    X: np.ndarray, xy: np.ndarray, cam_rows: np.ndarray, f_px: float, camera_id: str, threshold_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """(R, C) of a camera of known focal length from the known points it sees, by PnP RANSAC.

    X: (T, 3) points, NaN where unknown; xy: centred pixels of all
    observations; cam_rows: (T,) the camera's observation row per track, -1
    where it does not see it.
    """
    import cv2

    trk = np.flatnonzero(np.all(np.isfinite(X), axis=1) & (cam_rows >= 0))
    if len(trk) < MIN_REGISTRATION_POINTS:
        raise SolveError(
            f"cameras[{camera_id}]: sees only {len(trk)} points placed by the other cameras; "
            f"need at least {MIN_REGISTRATION_POINTS} to place it again"
        )
    K = np.diag([f_px, f_px, 1.0])
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        X[trk].astype(np.float64),
        xy[cam_rows[trk]].astype(np.float64),
        K,
        None,
        reprojectionError=threshold_px,
        iterationsCount=200,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inliers is None or len(inliers) < MIN_REGISTRATION_POINTS:
        raise SolveError(f"cameras[{camera_id}]: no consistent pose found among its tracks (too many outliers)")
    inl = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(X[trk][inl], xy[cam_rows[trk]][inl], K, None, rvec, tvec)
    R = cv2.Rodrigues(rvec)[0]
    return R, -R.T @ tvec.ravel()
