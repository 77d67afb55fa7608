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


def sampson_px(F: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray) -> np.ndarray:
    """(n,) Sampson distance, px, of pixels (n, 2) `uv_a` and `uv_b` from their own F (n, 3, 3)."""
    xa = np.column_stack([uv_a, np.ones(len(uv_a))])
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    Fxa, Ftxb = np.einsum("nij,nj->ni", F, xa), np.einsum("nji,nj->ni", F, xb)
    num = np.einsum("ij,ij->i", xb, Fxa) ** 2
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


class PairGeometry:
    """Each camera pair's F, fitted to a pool's tracks, and the tracks off it. Not thread-safe.

    Fitting every pair after every frame set costs about 1 ms a pair (36 ms
    for a ring of nine): too much beside the matcher's 0.24 s a frame set of
    sixteen cameras. A pair's F does not change while the rig is static, so
    each call refits `1 / refit_every` of the pairs in turn, and a pair
    without an F when its tracks have grown by half since it was last tried;
    tracks that changed are checked against every F, and all of a refitted
    pair's tracks against its new F.
    """

    def __init__(self, n_cameras: int, *, threshold_px: float, min_inliers: int, refit_every: int = 8) -> None:
        self.threshold_px = threshold_px
        self.min_inliers = min_inliers
        self.refit_every = refit_every
        self._F = np.zeros((n_cameras, n_cameras, 3, 3))
        self._has = np.zeros((n_cameras, n_cameras), dtype=bool)
        self._tried_at = np.zeros((n_cameras, n_cameras), dtype=np.int64)  # tracks when last fitted
        self._cursor = 0

    def _due(self, counts: np.ndarray) -> list[tuple[int, int]]:
        a, b = np.nonzero(np.triu(counts >= self.min_inliers, k=1))
        turn = max(1, -(-len(a) // self.refit_every))
        in_turn = (np.arange(len(a)) - self._cursor) % len(a) < turn if len(a) else np.zeros(0, bool)
        self._cursor += turn
        grown = ~self._has[a, b] & (counts[a, b] >= 1.5 * self._tried_at[a, b])
        return [(int(i), int(j)) for i, j in zip(a[in_turn | grown], b[in_turn | grown], strict=True)]

    def outliers(self, uv: np.ndarray, changed: np.ndarray) -> np.ndarray:
        """(T,) tracks whose views lie more than `threshold_px` (Sampson) off their pair's F in some pair.

        `uv`: (T, C, 2) the pool's pixels, NaN = unseen; `changed`: (T,) the
        tracks new or grown since the last call, checked against every F.
        Pairs seen together by fewer than `min_inliers` tracks, or without an
        F that many agree with (`pooled_fundamental`), check nothing.
        """
        seen = np.isfinite(uv[:, :, 0])
        bad = np.zeros(len(uv), dtype=bool)
        counts = seen.T.astype(np.int64) @ seen.astype(np.int64)  # (C, C) tracks seen by both cameras
        for a, b in self._due(counts):
            both = np.flatnonzero(seen[:, a] & seen[:, b])
            F = pooled_fundamental(uv[both, a], uv[both, b], threshold_px=self.threshold_px,
                                   min_inliers=self.min_inliers)
            self._tried_at[a, b] = len(both)
            self._has[a, b] = F is not None
            if F is not None:
                self._F[a, b] = F
                bad[both[~epipolar_inliers(F, uv[both, a], uv[both, b], self.threshold_px)]] = True
        pa, pb = np.nonzero(self._has)
        rows = np.flatnonzero(changed)
        track, pair = np.nonzero(seen[rows][:, pa] & seen[rows][:, pb])
        track, a, b = rows[track], pa[pair], pb[pair]
        off = sampson_px(self._F[a, b], uv[track, a], uv[track, b]) > self.threshold_px
        bad[track[off]] = True
        return bad
