"""A camera placed on known points (resection), its focal length known or swept.

PnP RANSAC over a sweep of focal lengths, then the focal length and pose
refined by SciPy's robust least squares; and the other poses that nearly
flat points leave open (`twin_poses`), to be judged on the same points.

Pixels centred (relative to the principal point), poses
``x_cam = R (X - C)``, metres, focal lengths in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.two_view import focal_grid

MIN_RESECTION_POINTS = 6  # a pose and a focal length: 7 unknowns, and a margin for RANSAC
MIN_INLIER_SHARE = 0.3  # fewer agreeing points than this share: the pose found is chance
# Points whose least spread is under this share of their largest lie nearly on a plane: a pose on them has a
# twin (the plane seen mirrored about its normal) that fits nearly as well, and RANSAC may take either.
NEARLY_FLAT = 0.1


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


def refine_pose(X: np.ndarray, xy: np.ndarray, f_px: float, R: np.ndarray, C: np.ndarray, *, f_free: bool,
                threshold_px: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(f_px, R, C): a pose (and the focal length where f_free) refined on points X (n, 3) seen at centred
    pixels xy (n, 2) by robust least squares, the loss bending at a quarter of threshold_px."""
    import cv2

    tvec = -R @ C
    f, rvec, tvec = _refine(np.ascontiguousarray(X, np.float64), np.ascontiguousarray(xy, np.float64), f_px,
                            cv2.Rodrigues(R)[0].ravel(), tvec, f_free=f_free, threshold_px=threshold_px)
    R = cv2.Rodrigues(rvec)[0]
    return f, R, -R.T @ tvec


def pose_errors_px(X: np.ndarray, xy: np.ndarray, f_px: float, R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(n,) reprojection error (px) of points X (n, 3) seen at centred pixels xy (n, 2); inf behind the camera."""
    xc = (X - C) @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(f_px * xc[:, :2] / xc[:, 2:3] - xy, axis=1)
    return np.where((xc[:, 2] > 0) & np.isfinite(err), err, np.inf)


def twin_poses(X: np.ndarray, xy: np.ndarray, f_px: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(R, C)]: the two poses IPPE finds for points X (n, 3) seen at centred pixels xy (n, 2), where X is
    nearly flat (`NEARLY_FLAT`); [] where it is not, or where too few points are given.

    IPPE models the points as a plane: they are put in the plane of their
    two largest spreads first, and its poses brought back to X's frame.
    """
    import cv2

    if len(X) < MIN_RESECTION_POINTS:
        return []
    centre = X.mean(axis=0)
    _, spread, axes = np.linalg.svd(X - centre, full_matrices=False)
    if spread[2] > NEARLY_FLAT * spread[0]:
        return []
    if np.linalg.det(axes) < 0:
        axes[2] = -axes[2]
    planar = (X - centre) @ axes.T  # X = centre + planar @ axes
    planar[:, 2] = 0.0
    found, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        np.ascontiguousarray(planar), np.ascontiguousarray(xy, np.float64), np.diag([f_px, f_px, 1.0]), None,
        flags=cv2.SOLVEPNP_IPPE,
    )
    poses = []
    for rvec, tvec in zip(rvecs[:found], tvecs[:found], strict=True):
        R_plane = cv2.Rodrigues(rvec)[0]  # x_cam = R_plane planar + t = R_plane axes (X - centre) + t
        R = R_plane @ axes
        poses.append((R, centre - R.T @ tvec.ravel()))
    return poses
