"""Registration over the view graph: every camera placed through the cameras that share its tracks.

From the scale pair's start (camnet.geometry.cold_start) or a previous
calibration, the camera that sees the most placed points is resected next
(PnP RANSAC over a sweep of focal lengths, then the focal length and pose
refined by SciPy's robust least squares), the tracks it newly sees twice
are triangulated, and a short robust adjustment of every placed camera and
point keeps errors from adding up before the next one.
Cameras that share nothing with the pair are placed through their
neighbours; one that cannot be placed is left out with the reason.

Cameras are in problem order (the pair first), pixels centred, poses
``x_cam = R (X - C)``, metres, focal lengths in pixels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from camnet.geometry import bundle
from camnet.geometry.bundle import CentreMode, Problem, State
from camnet.geometry.model import Loss, Observations
from camnet.geometry.projection import N_INTRINSICS
from camnet.geometry.two_view import focal_grid

log = logging.getLogger(__name__)

MIN_RESECTION_POINTS = 6  # a pose and a focal length: 7 unknowns, and a margin for RANSAC
# A track's rays must part by this many pixels to place its point: less leaves its depth undetermined (an
# error of the order of the pixel noise moves it along its ray without bound; two views of 0.5 px noise each
# part by noise alone by more than 2 px in 2% of their tracks, by more than 1 px in 37%).
MIN_PARALLAX_PX = 2.0
MIN_INLIER_SHARE = 0.3  # fewer agreeing points than this share: the pose found is chance
LOCAL_ITERATIONS = 30  # a start for the next camera, not the solution
LOCAL_FTOL = 1e-4
LOCAL_LOSS_SCALE_PX = 2.0  # the robust loss bends here, as in the final adjustment's default


def threshold_px(obs: Observations, order: list[int]) -> float:
    """RANSAC inlier threshold: 1% of the left image's diagonal (a start, not a fit)."""
    left = obs.cameras[order[0]]
    return 0.01 * float(np.hypot(left.width, left.height))


@dataclass(frozen=True)
class Resection:
    """A camera placed on known points: focal length (px), pose, and the points that agree."""

    f_px: float
    R: np.ndarray
    C: np.ndarray
    inliers: np.ndarray  # (n,) bool over the points given
    msac_px2: float  # mean over every point given of its squared error, capped at the threshold's square


def _msac(X: np.ndarray, xy: np.ndarray, f: float, rvec, tvec, threshold_px: float) -> tuple[float, np.ndarray]:
    """(MSAC cost, per-point error px) of a pose at focal length f; points behind the camera count as misses."""
    import cv2

    R = cv2.Rodrigues(rvec)[0]
    xc = X @ R.T + tvec.ravel()
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(f * xc[:, :2] / xc[:, 2:3] - xy, axis=1)
    err = np.where((xc[:, 2] > 0) & np.isfinite(err), err, np.inf)
    return float(np.sum(np.minimum(err, threshold_px) ** 2)), err


def resect(X: np.ndarray, xy: np.ndarray, *, f_px: float | None, width_px: int, threshold_px: float) -> Resection | str:
    """Place a camera on known points X (n, 3) seen at centred pixels xy (n, 2); a reason when it cannot.

    f_px: the focal length when known; else every focal length of
    `focal_grid` is tried with PnP RANSAC (which, unlike a DLT, also works
    on nearly planar points), and the best by MSAC is refined with its pose
    on its inliers (`_refine`); a refined focal length outside the sweep's
    range places nothing.
    """
    import cv2

    n = len(X)
    if n < MIN_RESECTION_POINTS:
        return (f"it shares only {n} tracks with the cameras placed (need at least "
                f"{MIN_RESECTION_POINTS}): give it a view of what its neighbours see")
    X, xy = np.ascontiguousarray(X, np.float64), np.ascontiguousarray(xy, np.float64)
    best = (np.inf, None)
    for f in [f_px] if f_px is not None else focal_grid(width_px):
        ok, rvec, tvec, _ = cv2.solvePnPRansac(
            X, xy, np.diag([f, f, 1.0]), None, reprojectionError=threshold_px, iterationsCount=100,
            flags=cv2.SOLVEPNP_EPNP,
        )
        if ok:
            cost, err = _msac(X, xy, f, rvec, tvec, threshold_px)
            if cost < best[0]:
                best = (cost, (f, rvec.ravel(), tvec.ravel(), err < threshold_px))
    enough = max(MIN_RESECTION_POINTS, MIN_INLIER_SHARE * n)
    failed = (f"no consistent pose among the {n} tracks it shares with the cameras placed: "
              "check its matches, and that it did not move while they were taken")
    if best[1] is None or best[1][3].sum() < enough:
        return failed
    f, rvec, tvec = _refine(X[best[1][3]], xy[best[1][3]], *best[1][:3], f_free=f_px is None,
                            threshold_px=threshold_px)
    cost, err = _msac(X, xy, f, rvec, tvec, threshold_px)
    if np.sum(err < threshold_px) < enough:
        return failed
    grid = focal_grid(width_px)
    if f_px is None and not grid[0] <= f <= grid[-1]:  # nearly coplanar or distant points: f trades off with depth
        return (f"its {n} tracks shared with the cameras placed put its focal length at {f:.0f} px, outside "
                f"{grid[0]:.0f}-{grid[-1]:.0f} px: they do not determine its pose")
    R = cv2.Rodrigues(rvec)[0]
    return Resection(f, R, -R.T @ tvec, err < threshold_px, cost / n)


def _refine(X, xy, f, rvec, tvec, *, f_free: bool, threshold_px: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(f, rvec, tvec) refined by robust least squares on the reprojection error."""
    import cv2
    from scipy.optimize import least_squares

    def residuals(p: np.ndarray) -> np.ndarray:
        focal = np.exp(p[0]) if f_free else f
        uv = cv2.projectPoints(X, p[1:4], p[4:7], np.diag([focal, focal, 1.0]), None)[0]
        return (uv.reshape(-1, 2) - xy).ravel()

    x0 = np.concatenate([[np.log(f)], rvec, tvec])
    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=threshold_px / 4, x_scale="jac")
    return (float(np.exp(fit.x[0])) if f_free else f), fit.x[1:4], fit.x[4:7]


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


def seed_adjustment(obs: Observations, order: list[int], xy, rows, intr, start) -> float:
    """The local adjustment of a start's placed cameras, in place, after triangulating what they see; its cost
    per observation (px^2)."""
    triangulate_missing(order, xy, rows, start.f, start.R, start.C, start.X, start.registered)
    held_K = np.array([obs.cameras[i].K is not None and "K" in obs.cameras[i].fixed for i in order])
    return local_adjustment(
        start.f, start.R, start.C, start.X, aspect=np.where(np.isfinite(intr[:, 1]), intr[:, 1], 1.0),
        xy_rows=rows[:, order], xy=xy, placed=start.registered, held_K=held_K, hold_pair=start.parallel,
        baseline_m=obs.stereo.baseline_m,
    )


def register_over_graph(
    obs: Observations, order: list[int], xy: np.ndarray, rows: np.ndarray, intr: np.ndarray, f: np.ndarray,
    R: np.ndarray, C: np.ndarray, X: np.ndarray, placed: np.ndarray, *, hold_pair: bool,
) -> dict[int, str]:
    """Place, in place, every camera the view graph reaches; {problem index: reason} for the others.

    rows (T, cameras): observation row of each track per observations
    camera; intr (M, 9): the given intrinsics (a held K's focal length is
    kept); f, R, C, placed (M, ...) and X (T, 3) as in initialise.Start.
    hold_pair: hold the stereo pair where it is in the local adjustments.
    """
    xy_rows = rows[:, order]
    held_K = np.array([obs.cameras[i].K is not None and "K" in obs.cameras[i].fixed for i in order])
    aspect = np.where(np.isfinite(intr[:, 1]), intr[:, 1], 1.0)
    threshold = threshold_px(obs, order)
    reasons: dict[int, str] = {}
    triangulate_missing(order, xy, rows, f, R, C, X, placed)
    while not placed.all():
        known = np.all(np.isfinite(X), axis=1)
        shared = {int(m): np.flatnonzero(known & (xy_rows[:, m] >= 0)) for m in np.flatnonzero(~placed)}
        for m in sorted(shared, key=lambda m: -len(shared[m])):
            trk = shared[m]
            got = resect(X[trk], xy[xy_rows[trk, m]], f_px=intr[m, 0] if held_K[m] else None,
                         width_px=obs.cameras[order[m]].width, threshold_px=threshold)
            if isinstance(got, str):
                reasons[m] = got
                continue
            f[m], R[m], C[m], placed[m] = got.f_px, got.R, got.C, True
            reasons.pop(m, None)
            triangulate_missing(order, xy, rows, f, R, C, X, placed)
            local_adjustment(f, R, C, X, aspect=aspect, xy_rows=xy_rows, xy=xy, placed=placed, held_K=held_K,
                             hold_pair=hold_pair, baseline_m=obs.stereo.baseline_m)
            break
        else:
            break  # no camera left that the placed ones reach
    triangulate_missing(order, xy, rows, f, R, C, X, placed)
    return reasons


def triangulate_missing(order, xy, rows, f, R, C, X, registered) -> int:
    """Midpoint triangulation, in place, of tracks without a point seen by >= 2 placed cameras.

    A track whose rays part by less than MIN_PARALLAX_PX (as pixels of its
    cameras' mean focal length) is left unknown: its depth is not
    determined (two views from one viewpoint, a pure rotation between them,
    triangulate nothing), and a point free along its ray stalls the adjustment.
    """
    todo = ~np.all(np.isfinite(X), axis=1)
    A = np.zeros((len(X), 3, 3))
    b = np.zeros((len(X), 3))
    count = np.zeros(len(X), dtype=int)
    f_sum = np.zeros(len(X))
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
        f_sum[trk] += f[m]
    ok = np.flatnonzero(todo & (count >= 2))
    if not len(ok):
        return 0
    # Two rays an angle a apart leave A's least eigenvalue at 1 - cos a, about a^2 / 2; more rays, more.
    least = np.linalg.eigvalsh(A[ok])[:, 0]
    parallax_rad = MIN_PARALLAX_PX * count[ok] / f_sum[ok]
    good = ok[least >= 0.5 * parallax_rad**2]
    X[good] = np.linalg.solve(A[good], b[good][:, :, None])[:, :, 0]
    return len(good)
