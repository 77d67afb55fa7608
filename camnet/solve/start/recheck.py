"""Placed views checked against the network once registration is done: re-placed, or left out.

A view resected early rests on the few points placed then, and a wrong
pose there (points of undetermined depth, or the mirrored twin of a pose
on nearly flat points) is never looked at again: the adjustments that
follow pull its points to it, and it ends with a small sigma at a wrong
pose. Once every view is placed, a view whose median reprojection error
stands far above the network's is resected again on the points the
*other* views place (RANSAC PnP, and the IPPE twins where those points are
nearly flat), keeping the pose that agrees with most of them; a view on
whose points no consistent pose is found is left out, with the reason.

Cameras in problem order, pixels centred, poses ``x_cam = R (X - C)``,
metres, focal lengths in pixels; points one per track row, NaN where not
known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.resection import MIN_RESECTION_POINTS, pose_errors_px, refine_pose, resect, twin_poses
from camnet.model.triangulation import ray_points, triangulate_missing

# A view stands out when its median reprojection error is above RECHECK_RATIO times the network's typical one
# (the median over views of theirs), and RECHECK_EXCESS_PX above it: above where the outer views of a wide or
# fisheye rig stand before the final adjustment models distortion, below where a view placed far off on points
# of undetermined depth stands (docs/benchmarks.md, "Real images: the temple ring").
RECHECK_RATIO = 4.0
RECHECK_EXCESS_PX = 0.5


@dataclass(frozen=True)
class Network:
    """The registration's arrays, shared with it and changed in place (see `recheck_placed`)."""

    order: list[int]  # problem camera m is observations camera order[m]
    xy: np.ndarray  # (n, 2) centred pixels of every observation
    rows: np.ndarray  # (T, cameras) observation row of each track per observations camera, -1 none
    f: np.ndarray  # (M,) focal lengths, px
    R: np.ndarray  # (M, 3, 3)
    C: np.ndarray  # (M, 3)
    X: np.ndarray  # (T, 3)
    placed: np.ndarray  # (M,) bool

    def errors_px(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(tracks, errors px): the tracks camera m sees that have a point, and its reprojection errors."""
        cam_rows = self.rows[:, self.order[m]]
        trk = np.flatnonzero(np.all(np.isfinite(self.X), axis=1) & (cam_rows >= 0))
        return trk, pose_errors_px(self.X[trk], self.xy[cam_rows[trk]], self.f[m], self.R[m], self.C[m])


def typical_error_px(net: Network) -> tuple[np.ndarray, float]:
    """((M,) each placed view's median reprojection error px, NaN for the others; the median of those)."""
    medians = np.full(len(net.f), np.nan)
    for m in np.flatnonzero(net.placed):
        _, err = net.errors_px(m)
        if len(err) >= MIN_RESECTION_POINTS:
            medians[m] = np.median(err)
    return medians, float(np.nanmedian(medians)) if np.isfinite(medians).any() else np.nan


def recheck_placed(net: Network, which: np.ndarray, *, f_free: np.ndarray, width_px: np.ndarray,
                   threshold_px: float) -> tuple[dict[int, str], list[int]]:
    """({view: reason} for the views among `which` (M,) bool left out, [views re-placed]); in place.

    f_free (M,): whether a view's focal length is solved (else held);
    width_px (M,): image widths, for the focal sweep; threshold_px: the
    registration's RANSAC threshold. A view re-placed or left out has its
    tracks' points triangulated again without its old pose.
    """
    medians, typical = typical_error_px(net)
    if not np.isfinite(typical):
        return {}, []
    bound_px = max(RECHECK_RATIO * typical, typical + RECHECK_EXCESS_PX)
    reasons, moved = {}, []
    for m in sorted(np.flatnonzero(which & net.placed & (medians > bound_px)), key=lambda m: -medians[m]):
        m = int(m)
        _, err = net.errors_px(m)
        if np.median(err) <= bound_px:  # its points were pulled by a view placed again before it
            continue
        pose = _replace(net, m, bound_px, f_free=bool(f_free[m]), width_px=int(width_px[m]),
                        threshold_px=threshold_px)
        if pose is None:  # its present pose agrees best, or the others place too few of its points to tell
            continue
        trk = np.flatnonzero(net.rows[:, net.order[m]] >= 0)
        net.X[trk] = np.nan
        if isinstance(pose, str):
            net.placed[m] = False
            reasons[m] = (f"its observations stand out (median reprojection error {np.median(err):.1f} px, against "
                          f"{typical:.2f} px for the others') and, on the points the others place, {pose}")
        else:
            net.f[m], net.R[m], net.C[m] = pose
            moved.append(m)
        triangulate_missing(net.order, net.xy, net.rows, net.f, net.R, net.C, net.X, net.placed)
    return reasons, moved


def _replace(net: Network, m: int, bound_px: float, *, f_free: bool, width_px: int,
             threshold_px: float) -> tuple[float, np.ndarray, np.ndarray] | str | None:
    """(f, R, C) of view m that agrees with most points the other views place (errors truncated at bound_px),
    among a fresh resection and the IPPE twins, where one agrees better than its present pose; None where none
    does, or those points are too few; why not, where they find it no consistent pose (`resect`)."""
    others = net.placed & (np.arange(len(net.f)) != m)
    cam_rows = net.rows[:, net.order[m]]
    X_others = ray_points(np.flatnonzero(cam_rows >= 0), net.order, net.xy, net.rows, net.f, net.R, net.C, others)
    known = np.all(np.isfinite(X_others), axis=1)
    if known.sum() < MIN_RESECTION_POINTS:
        return None
    X, xy = X_others[known], net.xy[cam_rows[cam_rows >= 0][known]]
    candidates = [(net.f[m], net.R[m], net.C[m])]
    got = resect(X, xy, f_px=None if f_free else net.f[m], width_px=width_px, threshold_px=threshold_px)
    if isinstance(got, str):
        return got
    candidates.append((got.f_px, got.R, got.C))
    for f, R, C in list(candidates):
        agree = pose_errors_px(X, xy, f, R, C) < bound_px
        for R_twin, C_twin in twin_poses(X[agree], xy[agree], f):
            candidates.append(refine_pose(X, xy, f, R_twin, C_twin, f_free=f_free, threshold_px=threshold_px))
    costs = [np.sum(np.minimum(pose_errors_px(X, xy, *pose), bound_px) ** 2) for pose in candidates]
    best = int(np.argmin(costs))
    return candidates[best] if best > 0 else None
