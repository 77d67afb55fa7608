"""Two views alone: focal lengths from the fundamental matrix, the relative pose from the essential matrix,
and how well the paper's parallel pair (matching rows) explains their matches.

Pixels are *centred* (relative to each camera's principal point, as in
camnet.solve.context), so the principal points are the origins.
Poses follow camnet's convention: the second camera sees ``x_2 = R x_1 + t``
in the first camera's frame; t comes back as a unit vector (two views fix
no scale). Focal lengths in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.projection import skew

RANSAC_CONFIDENCE = 0.999
MIN_PAIR_POINTS = 8  # the eight-point fundamental matrix, and a margin over E's five
# Focal lengths a sweep tries, as multiples of the image width: 170 to 10 degrees across.
FOCAL_RANGE_REL = (0.15, 6.0)
FOCAL_STEPS = 16  # 27% apart: a refinement finishes from the nearest
# Two views from one viewpoint: a homography explains their matches within this many times their distance from
# the epipolar lines (both refitted on their RANSAC inliers; pixel noise alone gives about 2, views of a scene with
# depth 25-30 where the depth spans a tenth of the distance), plus a floor for exact data.
ROTATION_RATIO = 5.0
ROTATION_FLOOR_PX = 0.1
# Rows closer together than this share of their distance from the principal point are one row to a line's fit.
ROW_SPAN_REL = 1e-9


@dataclass(frozen=True)
class RelativePose:
    """The second camera's pose in the first's frame (t unit), and the matches that agree with it."""

    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,) unit
    inliers: np.ndarray  # (n,) bool

    @property
    def centre_direction(self) -> np.ndarray:
        """The unit direction of the second camera's centre in the first's frame."""
        return -self.R.T @ self.t


def focal_grid(width_px: int) -> np.ndarray:
    """The focal lengths (px) a sweep tries for an image `width_px` wide."""
    lo, hi = FOCAL_RANGE_REL
    return np.geomspace(lo * width_px, hi * width_px, FOCAL_STEPS)


def fundamental(xy1: np.ndarray, xy2: np.ndarray, *, threshold_px: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(F (3, 3), inliers (n,)) with ``x2^T F x1 = 0`` on centred pixels, by RANSAC; None if none is found."""
    import cv2

    if len(xy1) < MIN_PAIR_POINTS:
        return None
    F, mask = cv2.findFundamentalMat(xy1, xy2, cv2.FM_RANSAC, threshold_px, RANSAC_CONFIDENCE)
    if F is None or F.shape != (3, 3):
        return None
    return F, mask.ravel().astype(bool)


def bougnoux_focals(F: np.ndarray) -> tuple[float, float]:
    """(f1, f2) of the two views from F on centred pixels (Bougnoux's formula); NaN where not real.

    The formula divides by a term that vanishes when the two optical axes
    meet (then F says nothing of the focal lengths): callers must not trust
    it without another check.
    """
    origin, flat = np.array([0.0, 0.0, 1.0]), np.diag([1.0, 1.0, 0.0])

    def squared(F: np.ndarray) -> float:
        e2 = np.linalg.svd(F.T)[2][-1]  # the epipole in the second image: F^T e2 = 0
        lhs = origin @ skew(e2) @ flat @ F
        return -float(lhs @ origin * (origin @ F.T @ origin)) / float(lhs @ flat @ F.T @ origin)

    with np.errstate(divide="ignore", invalid="ignore"):
        f1_sq, f2_sq = squared(F), squared(F.T)
    return (float(np.sqrt(f1_sq)) if f1_sq > 0 else np.nan, float(np.sqrt(f2_sq)) if f2_sq > 0 else np.nan)


def relative_pose(
    xy1: np.ndarray, xy2: np.ndarray, f1: float, f2: float, *, threshold_px: float
) -> RelativePose | None:
    """The second view's pose from the essential matrix at focal lengths f1, f2; None if none is found.

    The matches of RANSAC that also put their point in front of both cameras
    (recoverPose's cheirality test) are the inliers. Few inliers with many
    matches mean a baseline too short for the translation's direction
    (the rotation is still fair): callers that need t must check.
    """
    import cv2

    if len(xy1) < MIN_PAIR_POINTS or not (f1 > 0 and f2 > 0):  # no pinhole has a focal length of 0 or less
        return None
    n1, n2 = xy1 / f1, xy2 / f2
    threshold = threshold_px / np.sqrt(f1 * f2)
    E, mask = cv2.findEssentialMat(n1, n2, np.eye(3), cv2.RANSAC, RANSAC_CONFIDENCE, threshold)
    if E is None or E.shape[0] % 3:
        return None
    # Nearly degenerate matches (a short baseline) can leave several solutions stacked: the one
    # that puts the most points in front of both cameras wins.
    best = (-1, None, None, None)
    for k in range(0, E.shape[0], 3):
        _, R, t, in_front = cv2.recoverPose(E[k : k + 3], n1, n2, np.eye(3), mask=mask.copy())
        inliers = in_front.ravel() > 0
        if inliers.sum() > best[0]:
            best = (int(inliers.sum()), R, t, inliers)
    _, R, t, inliers = best
    return RelativePose(R, t.ravel() / np.linalg.norm(t), inliers)


def pair_focals(xy1: np.ndarray, xy2: np.ndarray, *, threshold_px: float) -> tuple[float, float]:
    """Bougnoux's focal lengths (px) of two views from their RANSAC fundamental matrix; NaN where not real.

    Where the optical axes nearly meet (cameras that look at one object),
    two views hardly fix the focal lengths at all, and these values are
    noise: a candidate to check with a third view, not an answer.
    """
    found = fundamental(xy1, xy2, threshold_px=threshold_px)
    return (np.nan, np.nan) if found is None else bougnoux_focals(found[0])


def row_and_epipolar_errors(xy1: np.ndarray, xy2: np.ndarray, *, threshold_px: float) -> tuple[float, float]:
    """(rows_px, epipolar_px): how well the paper's parallel pair, and any pair, explain two views' matches.

    rows_px: the median distance of the second view's pixels from the rows
    ``y2 = k y1 + c`` (eq. 4, with an offset for principal points that
    differ), fitted robustly; epipolar_px: the median distance from their
    epipolar lines under the RANSAC fundamental matrix, over its inliers.
    Matches with a non-finite pixel are ignored; both are infinite where
    fewer than two rows remain to fit, and epipolar_px where no fundamental
    matrix is found.
    """
    import cv2

    finite = np.all(np.isfinite(xy1), axis=1) & np.all(np.isfinite(xy2), axis=1)
    xy1, xy2 = xy1[finite], xy2[finite]
    y1, y2 = xy1[:, 1], xy2[:, 1]
    if not _spans_rows(y1):  # no line through one row: nothing says the rows match
        return np.inf, np.inf
    keep = np.ones(len(y1), dtype=bool)
    for _ in range(3):  # refit on the rows that agree: mismatches would drag a plain fit
        if _spans_rows(y1[keep]):  # else the last line stands
            k, c = np.polyfit(y1[keep], y2[keep], 1)
        off = np.abs(y2 - (k * y1 + c))
        keep = off <= max(3.0 * np.median(off), 1.0)
    found = fundamental(xy1, xy2, threshold_px=threshold_px)
    if found is None:
        return float(np.median(off)), np.inf
    F, inliers = found
    lines = cv2.computeCorrespondEpilines(xy1[inliers].reshape(-1, 1, 2), 1, F).reshape(-1, 3)
    epipolar = np.abs(np.sum(lines[:, :2] * xy2[inliers], axis=1) + lines[:, 2])
    return float(np.median(off)), float(np.median(epipolar))


def _spans_rows(y: np.ndarray) -> bool:
    """Whether pixel rows `y` span enough to fit a line through them (a fit on one row is singular)."""
    return len(y) >= 2 and float(np.ptp(y)) > ROW_SPAN_REL * (1.0 + float(np.max(np.abs(y))))


def homography_explains(xy1: np.ndarray, xy2: np.ndarray, *, threshold_px: float) -> bool:
    """Whether one homography maps the first view's matches onto the second's as closely as any epipolar geometry.

    So it is between two views from one viewpoint (a pure rotation: no
    baseline, so no relative pose and no depth) or of one plane. Both
    models are fitted by RANSAC, then by least squares on their inliers;
    the medians over the fundamental matrix's inliers are compared
    (`ROTATION_RATIO`). Pixels in either convention, both views alike.
    """
    import cv2

    found = fundamental(xy1, xy2, threshold_px=threshold_px)
    if found is None:
        return False
    inliers = found[1]
    H, mask = cv2.findHomography(xy1, xy2, cv2.RANSAC, threshold_px)
    if H is None or inliers.sum() < MIN_PAIR_POINTS or mask.sum() < MIN_PAIR_POINTS:
        return False
    H = cv2.findHomography(xy1[mask.ravel() > 0], xy2[mask.ravel() > 0], 0)[0]
    F = cv2.findFundamentalMat(xy1[inliers], xy2[inliers], cv2.FM_8POINT)[0]
    if H is None or F is None or F.shape != (3, 3):
        return False
    lines = cv2.computeCorrespondEpilines(xy1[inliers].reshape(-1, 1, 2), 1, F).reshape(-1, 3)
    epipolar_px = np.median(np.abs(np.sum(lines[:, :2] * xy2[inliers], axis=1) + lines[:, 2]))
    mapped = cv2.perspectiveTransform(xy1[inliers].reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    transfer_px = np.median(np.linalg.norm(mapped - xy2[inliers], axis=1))
    return bool(transfer_px <= ROTATION_RATIO * epipolar_px + ROTATION_FLOOR_PX)
