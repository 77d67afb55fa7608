"""Starting values for the adjustment: the paper's solver, a previous calibration, registration.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (``centred``). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

import logging
from collections.abc import Collection
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from camnet.errors import SolveError
from camnet.geometry import paper
from camnet.geometry.model import Calibration, LensModel, Observations
from camnet.geometry.projection import K_from_intrinsics, full_dist, intrinsics_from_K, normalised
from camnet.geometry.register import register_over_graph, threshold_px
from camnet.geometry.resection import MIN_INLIER_SHARE
from camnet.geometry.triangulation import triangulate_missing

log = logging.getLogger(__name__)

MIN_REGISTRATION_POINTS = 6  # a DLT has 11 degrees of freedom
EQ13_START_FTOL = 1e-4  # eq. 13 as a start for the adjustment: its last digits do not matter


class PairStart(Enum):
    """How a cold start places the scale pair (camnet.geometry.cold_start)."""

    AUTO = "auto"  # the paper's where the pair's matches lie on matching rows, else the essential matrix
    PAPER = "paper"  # the paper's solver
    ESSENTIAL = "essential"  # the pair's essential matrix, its focal lengths from a third view
    # The two cameras that share the most tracks, placed by their essential matrix; every camera through the
    # view graph from them; then the scale pair's frame and distance (a scale pair that sees little together).
    STRONGEST = "strongest pair"


@dataclass
class Start:
    f: np.ndarray  # (M,) focal lengths, px
    R: np.ndarray  # (M, 3, 3)
    C: np.ndarray  # (M, 3) centres, m
    X: np.ndarray  # (T, 3) points, m; NaN where unknown
    registered: np.ndarray  # (M,) bool
    P0: np.ndarray  # (T, 3) the paper's stereo cloud (f_left = 1, unit baseline); NaN where unknown
    k: float  # f_right / f_left
    parallel: bool = True  # the pair is the paper's ideal parallel pair, to start with
    left_out: dict[str, str] = field(default_factory=dict)  # camera id -> why it could not be placed
    pair: PairStart | None = None  # how a cold start placed the scale pair (never AUTO); None: a warm start


def camera_order(obs: Observations) -> list[int]:
    """Problem camera m is observations camera order[m]: the stereo pair first."""
    left, right = obs.index_of(obs.stereo.left), obs.index_of(obs.stereo.right)
    return [left, right] + [i for i in range(len(obs.cameras)) if i not in (left, right)]


def observation_rows(obs: Observations) -> np.ndarray:
    """(T, cameras) row of the observation of each track by each camera; -1 where none."""
    rows = np.full((len(obs.track_ids), len(obs.cameras)), -1)
    rows[obs.track_index, obs.cam_index] = np.arange(len(obs.uv))
    return rows


def initial_intrinsics(obs: Observations, order: list[int]) -> np.ndarray:
    """(M, 9) intrinsics given by the observations; f NaN and the image centre where not given."""
    intr = np.zeros((len(order), 9))
    for m, i in enumerate(order):
        cam = obs.cameras[i]
        dist = full_dist(cam.dist)  # a fisheye's four padded with a zero
        if cam.K is not None:
            intr[m] = intrinsics_from_K(cam.K, dist)
        else:
            intr[m] = [np.nan, 1.0, (cam.width - 1) / 2, (cam.height - 1) / 2, *dist]
    return intr


def centred(obs: Observations, order: list[int], intr: np.ndarray) -> np.ndarray:
    """Observed pixels relative to each camera's principal point, undistorted where known.

    A fisheye camera's pixels are made pinhole ones (of the same K), with a
    guessed focal length where none is known (`with_guessed_fisheye_focal`).
    """
    intr = with_guessed_fisheye_focal(obs, order, intr)
    m_of = np.empty(len(obs.cameras), dtype=int)
    m_of[order] = np.arange(len(order))
    m = m_of[obs.cam_index]
    xy = obs.uv - intr[m, 2:4]
    fisheye = np.array([obs.cameras[i].model == LensModel.FISHEYE for i in order])
    for mm in np.flatnonzero((np.any(intr[:, 4:] != 0, axis=1) | fisheye) & np.isfinite(intr[:, 0])):
        rows = m == mm
        K = K_from_intrinsics(intr[mm])
        dist = intr[mm, 4 : 4 + obs.cameras[order[mm]].model.dist_size]
        xy[rows] = normalised(obs.uv[rows], K=K, dist=dist, fisheye=fisheye[mm]) * np.diag(K)[:2]
    return xy


# A fisheye's guessed focal length puts its image's corner this far off the axis (rad): a pinhole
# image of the pixels then stays finite (tan 1.2 = 2.6) whatever the lens's true field of view.
FISHEYE_START_CORNER_RAD = 1.2


def with_guessed_fisheye_focal(obs: Observations, order: list[int], intr: np.ndarray) -> np.ndarray:
    """`intr` (M, 9) with a focal length guessed for each fisheye camera that has none, for `centred`.

    Raw fisheye pixels are no pinhole image: the paper's start on them lands the
    adjustment in a wrong valley (a live fisheye rig's focal lengths 12% off with
    as good a fit). Made pinhole by an equidistant lens of the guessed focal
    length (half the image diagonal over FISHEYE_START_CORNER_RAD), they start it
    in the right one, even with the guess 25% off. The start estimates the focal
    lengths itself: the guess only undistorts (`centred` uses it).
    """
    guessed = intr.copy()
    for m, i in enumerate(order):
        cam = obs.cameras[i]
        if cam.model == LensModel.FISHEYE and not np.isfinite(intr[m, 0]):
            guessed[m, 0] = np.hypot(cam.width, cam.height) / 2 / FISHEYE_START_CORNER_RAD
    return guessed


def paper_start(
    obs: Observations,
    order: list[int],
    intr: np.ndarray,
    xy: np.ndarray,
    rows: np.ndarray,
    seed: int,
    max_tracks: int | None = None,
    register_rest: bool = True,
) -> Start:
    """The paper's unknowns from nothing but the observations, then every camera and track.

    max_tracks: use at most this many tracks per camera in eq. 13, which is
    plenty for a starting point; None uses all (the paper's method itself).
    register_rest: place the other cameras and every track, else the caller does.
    """
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
    stretched = _stretched_cameras(obs, order, xy, rows, P0, seed)
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
            f_left, f[others], R[others], C[others], P0, cams, ftol=1e-8 if max_tracks is None else EQ13_START_FTOL
        )
        f[0], f[1] = f_left, k * f_left
        X = P0 * np.array([1.0, 1.0, f_left])
        registered[others] = True
    if register_rest:
        register_and_triangulate(obs, order, xy, rows, f, R, C, X, registered, seed=seed)
    return Start(f, R, C, X, registered, P0, k)


def _stretched_cameras(obs, order, xy, rows, P0, seed) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{problem index: (DLT matrix on the stretched stereo cloud P0, its inlier tracks)} of the other cameras."""
    has_P0 = np.all(np.isfinite(P0), axis=1)
    threshold = threshold_px(obs, order)
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


def warm_start(
    obs: Observations,
    order: list[int],
    intr: np.ndarray,
    xy: np.ndarray,
    rows: np.ndarray,
    initial: Calibration,
    *,
    reset: Collection[int] = (),
) -> Start:
    """Start from a previous calibration: its cameras, its points, new tracks triangulated.

    `intr` and `xy` are updated in place with the previous intrinsics.
    reset: problem indices of non-stereo cameras whose previous pose is not
    trusted; they keep their intrinsics and are registered again, by PnP
    RANSAC, on the points the other cameras determine. Cameras new to
    `initial` are placed through the view graph; `Start.left_out` names
    those it cannot place.
    """
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
        intr[m, 4:] = full_dist(cam.dist)
        f[m] = cam.K[0, 0]
        if m not in reset:
            R[m], C[m] = cam.R, cam.centre
            registered[m] = True
    if not registered[:2].all():
        raise SolveError("initial calibration: it does not hold both stereo cameras")
    xy[:] = centred(obs, order, intr)
    X = _previous_points(obs.track_ids, initial.point_ids, initial.points)
    # A moved camera's observations of the old points are dropped (they saw its old pose): it is placed on the
    # points of its new tracks, which the cameras still in place triangulate here first.
    triangulate_missing(order, xy, rows, f, R, C, X, registered)
    for m in reset:
        if not np.isfinite(f[m]):
            continue  # not in `initial` either: registered below like any new camera
        # Points the moved camera helped to place are still fine: the other cameras hold them.
        R[m], C[m] = register_pnp(X, xy, rows[:, order[m]], f[m], obs.cameras[order[m]].id, threshold_px(obs, order))
        registered[m] = True
    reasons = register_over_graph(obs, order, xy, rows, intr, f, R, C, X, registered, hold_pair=True)
    left_out = {obs.cameras[order[m]].id: reasons[m] for m in np.flatnonzero(~registered)}
    return Start(f, R, C, X, registered, np.full_like(X, np.nan), f[1] / f[0], left_out=left_out)


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


def register_and_triangulate(obs, order, xy, rows, f, R, C, X, registered, *, seed: int) -> None:
    """Alternately register cameras (DLT on known points) and triangulate tracks, in place."""
    M = len(order)
    threshold = threshold_px(obs, order)
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
