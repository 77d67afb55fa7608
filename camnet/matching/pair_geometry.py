"""Each camera pair's epipolar geometry, fitted to the pool's own tracks, and the tracks that break it.

A frame set's matching fits a pair's F to that frame set's candidates
alone, and chaining pairs into tracks checks nothing between the cameras of
a track that were not matched directly (a track a-b-c is never checked
between a and c). False matches that fit one frame set's F get through: the
floor at grazing angles from cameras far apart, repeated texture, a pair
whose few inliers gave a false F. In a pool they accumulate: a true static
point re-detected in a later frame set is merged into its pooled track,
while a false match is a new track each time, and false tracks often lie
where true ones are sparse, in the grid cells that eviction spares. On the
surround rig (config/surround.yaml) 3% of a frame set's tracks are false
(off the truth by more than 1 px) and, without this check, 20% of the pool's
after 36 frame sets (of its tracks seen by 3+ cameras, 62% in its older half).

The rig is static, so one F holds for a pair over every frame set. Fitted
robustly to everything the pool holds of a pair, over many frame sets, it is
the F of the true points, which agree across frame sets while false ones
scatter. A track whose views in some pair lie off that pair's pooled F is
false: with it, the pool's false share stays near a frame set's.
"""

from __future__ import annotations

import cv2
import numpy as np

from camnet.matching.reuse import epipolar_inliers


def pooled_fundamental(uv_a: np.ndarray, uv_b: np.ndarray, *, threshold_px: float,
                       min_inliers: int) -> np.ndarray | None:
    """F (x_b^T F x_a = 0, pixels) of (n, 2) corresponding pixels by USAC MAGSAC, or None.

    None when there are fewer than `min_inliers` correspondences, or fewer
    of them within `threshold_px` (Sampson) of the F found: too little to
    tell true from false.
    """
    if len(uv_a) < min_inliers:
        return None
    try:
        F, _ = cv2.findFundamentalMat(uv_a.astype(np.float64), uv_b.astype(np.float64), cv2.USAC_MAGSAC,
                                      threshold_px, 0.999, 10_000)
    except cv2.error:  # USAC asserts on some degenerate samples instead of returning no model
        return None
    if F is None or F.shape != (3, 3):
        return None
    if epipolar_inliers(F, uv_a, uv_b, threshold_px).sum() < min_inliers:
        return None
    return F


def epipolar_outliers(uv: np.ndarray, *, threshold_px: float, min_inliers: int) -> np.ndarray:
    """(T,) tracks whose views lie off their pair's pooled F in some pair of cameras.

    `uv`: (T, C, 2) pixels, NaN = unseen. Each pair of cameras seen together
    by at least `min_inliers` tracks gets an F fitted to all of them
    (`pooled_fundamental`); a track is an outlier when, in some pair with an
    F, its two views lie more than `threshold_px` (Sampson distance) off it.
    Pairs without an F check nothing.
    """
    seen = np.isfinite(uv[:, :, 0])
    bad = np.zeros(len(uv), dtype=bool)
    counts = seen.T.astype(np.int64) @ seen.astype(np.int64)  # (C, C) tracks seen by both cameras
    for a, b in zip(*np.nonzero(np.triu(counts >= min_inliers, k=1)), strict=True):
        both = np.flatnonzero(seen[:, a] & seen[:, b])
        F = pooled_fundamental(uv[both, a], uv[both, b], threshold_px=threshold_px, min_inliers=min_inliers)
        if F is not None:
            bad[both[~epipolar_inliers(F, uv[both, a], uv[both, b], threshold_px)]] = True
    return bad
