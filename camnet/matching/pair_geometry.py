"""Each camera pair's epipolar geometry, fitted to the pool's own tracks, and the views that break it.

A frame set's matching fits a pair's F to that frame set's candidates
alone, and chaining pairs into tracks checks nothing between the cameras of
a track that were not matched directly (a track a-b-c is never checked
between a and c). False matches that fit one frame set's F get through: the
floor at grazing angles from cameras far apart, repeated texture, a pair
whose few inliers gave a false F. In a pool they accumulate: a true static
point re-detected in a later frame set is merged into its pooled track,
while a false match is a new track each time, and false tracks often lie
where true ones are sparse, in the grid cells that eviction spares: without
this check a long pool is many times falser than the frame sets it took in,
and falsest in its oldest tracks (docs/benchmarks.md, "The surround rig,
live"; "Evidence behind the nodes' choices").

The rig is static, so one F holds for a pair over every frame set. Fitted
robustly to everything the pool holds of a pair, over many frame sets, it is
the F of the true points, which agree across frame sets while false ones
scatter. A view off that F is false. Three things keep true views:

- An F fitted to the tracks of one frame set (the first the pool saw of a
  pair) holds where those tracks lie and can be pixels off elsewhere, where
  true tracks of later frame sets lie (docs/benchmarks.md, "The surround
  rig, live"). So where more than `SUSPECT_SHARE` of a pair's new tracks lie
  off its F, the F is refitted to the whole pool before any of them is
  judged.
- Pairs at grazing angles localize their points worse than most pairs
  (docs/benchmarks.md, "The surround rig, live"): each pair's limit is
  `SPREAD` times its own residual sigma, at least the configured one.
- Only the view to blame goes: the camera in every pair of the track that
  is off (a false view in a track a-b-c is off in a-c and b-c, not a-b);
  where no single camera is, the whole track goes.
"""

from __future__ import annotations

import cv2
import numpy as np

from camnet.matching.reuse import epipolar_inliers

# Of a pair's changed tracks checked against its F, the share (and least number) off it beyond which the F,
# not they, is suspect.
SUSPECT_SHARE = 0.25
SUSPECT_MIN = 5
# A pair's limit, in its residual sigmas (the median Sampson distance / 0.6745: Sampson's is a |normal| one).
SPREAD = 4.0
# A pair's F judges nothing until the pair's tracks come from this many frame sets.
MIN_FRAME_SETS = 3
# Pairs refitted in turn per call, at most: a fixed cost per frame set whatever the cameras, where a share of
# the pairs grows with their square (docs/benchmarks.md, "Evidence behind the nodes' choices").
MAX_REFITS_IN_TURN = 2


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


def _gram(seen: np.ndarray) -> np.ndarray:
    """(C, C) float: for each pair of columns of boolean `seen` (T, C), the rows true in both."""
    as_float = seen.astype(np.float32)
    return as_float.T @ as_float


def views_to_blame(track: np.ndarray, a: np.ndarray, b: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(T, C) the views to drop, given the pairs (a, b) of tracks `track` found off their F (all (k,)).

    A camera in every off pair of its track is blamed alone; a track with no
    such camera (its off pairs share none) loses every view.
    """
    drop = np.zeros(shape, dtype=bool)
    if len(track) == 0:
        return drop
    off_pairs = np.bincount(track, minlength=shape[0])
    per_camera = np.zeros(shape, dtype=np.int64)
    np.add.at(per_camera, (track, a), 1)
    np.add.at(per_camera, (track, b), 1)
    drop[:] = (per_camera == off_pairs[:, None]) & (off_pairs[:, None] > 0)
    unblamed = (off_pairs > 0) & ~drop.any(axis=1)
    drop[unblamed] = True
    return drop


class PairGeometry:
    """Each camera pair's F, fitted to a pool's tracks, and the views off it. Not thread-safe.

    Fitting every pair after every frame set costs too much beside the rest
    of the matcher's work on the set (docs/benchmarks.md, "Evidence behind
    the nodes' choices"). A pair's F does not change while the rig is static, so
    each call refits `1 / refit_every` of the pairs in turn (at most
    `MAX_REFITS_IN_TURN`), a pair without
    an F when its tracks have grown by half since it was last tried, and a
    pair whose F over `SUSPECT_SHARE` of its new tracks disagree with; tracks that changed are
    checked against every F, and all of a refitted pair's tracks against
    its new F.
    """

    def __init__(self, n_cameras: int, *, threshold_px: float, min_inliers: int, refit_every: int = 8) -> None:
        self.threshold_px = threshold_px
        self.min_inliers = min_inliers
        self.refit_every = refit_every
        self._F = np.zeros((n_cameras, n_cameras, 3, 3))
        self._limit_px = np.zeros((n_cameras, n_cameras))
        self._has = np.zeros((n_cameras, n_cameras), dtype=bool)
        self._tried_at = np.zeros((n_cameras, n_cameras), dtype=np.int64)  # tracks when last fitted
        self._frame_sets = np.zeros((n_cameras, n_cameras), dtype=np.int64)  # calls that brought the pair tracks
        self._cursor = 0

    def forget(self, camera: int) -> None:
        """Forget the F of every pair of column `camera` (it moved): they are fitted afresh, as a new
        pair's, once its tracks come from `MIN_FRAME_SETS` frame sets, and judge nothing meanwhile."""
        for table in (self._F, self._limit_px, self._has, self._tried_at, self._frame_sets):
            table[camera, :] = 0
            table[:, camera] = 0

    def _due(self, counts: np.ndarray) -> set[tuple[int, int]]:
        a, b = np.nonzero(np.triu((counts >= self.min_inliers) & (self._frame_sets >= MIN_FRAME_SETS), k=1))
        turn = min(max(1, -(-len(a) // self.refit_every)), MAX_REFITS_IN_TURN)
        in_turn = (np.arange(len(a)) - self._cursor) % len(a) < turn if len(a) else np.zeros(0, bool)
        self._cursor += turn
        grown = ~self._has[a, b] & (counts[a, b] >= 1.5 * self._tried_at[a, b])
        return {(int(i), int(j)) for i, j in zip(a[in_turn | grown], b[in_turn | grown], strict=True)}

    def _fit(self, a: int, b: int, uv_a: np.ndarray, uv_b: np.ndarray) -> np.ndarray | None:
        """Fit the pair's F to these views; their Sampson distances to it (px), or None where none fits."""
        F = pooled_fundamental(uv_a, uv_b, threshold_px=self.threshold_px, min_inliers=self.min_inliers)
        self._tried_at[a, b] = len(uv_a)
        self._has[a, b] = F is not None
        if F is None:
            return None
        self._F[a, b] = F
        d = sampson_px(np.broadcast_to(F, (len(uv_a), 3, 3)), uv_a, uv_b)
        self._limit_px[a, b] = max(self.threshold_px, SPREAD * np.median(d) / 0.6745)
        return d

    def _off(self, uv: np.ndarray, seen: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, ...]:
        """(track, a, b, off) for every pair with an F that tracks `rows` are seen in."""
        pa, pb = np.nonzero(self._has)
        track, pair = np.nonzero(seen[rows][:, pa] & seen[rows][:, pb])
        track, a, b = rows[track], pa[pair], pb[pair]
        return track, a, b, sampson_px(self._F[a, b], uv[track, a], uv[track, b]) > self._limit_px[a, b]

    def off_views(self, uv: np.ndarray, changed: np.ndarray) -> np.ndarray:
        """(T, C) the views to drop: off their pair's F (see the module docstring).

        `uv`: (T, C, 2) the pool's pixels, NaN = unseen; `changed`: (T,) the
        tracks new or grown since the last call, checked against every F.
        Pairs seen together by fewer than `min_inliers` tracks, or without an
        F that many agree with (`pooled_fundamental`), check nothing.
        """
        seen = np.isfinite(uv[:, :, 0])
        # (C, C) tracks seen by both cameras; a float product (BLAS) is exact below 2**24 and a tenth of the
        # integer one's time on 5000 tracks of 16 cameras.
        counts = np.rint(_gram(seen)).astype(np.int64)
        self._frame_sets += _gram(seen[changed]) > 0
        track, a, b, off = self._off(uv, seen, np.flatnonzero(changed))
        pair = a * len(counts) + b
        checked = np.bincount(pair, minlength=counts.size)
        off_count = np.bincount(pair[off], minlength=counts.size)
        suspect = (off_count > SUSPECT_SHARE * checked) & (off_count >= SUSPECT_MIN)
        due = self._due(counts) | {divmod(int(p), len(counts)) for p in np.flatnonzero(suspect)}
        keep = off & ~np.isin(pair, [i * len(counts) + j for i, j in due])
        found = [(track[keep], a[keep], b[keep])]
        for i, j in sorted(due):
            both = np.flatnonzero(seen[:, i] & seen[:, j])
            d = self._fit(i, j, uv[both, i], uv[both, j])
            if d is not None:
                bad = both[d > self._limit_px[i, j]]
                found.append((bad, np.full(len(bad), i), np.full(len(bad), j)))
        # A refitted pair's verdicts replace what its old F said of the changed tracks: each pair counts once.
        track, a, b = (np.concatenate(parts).astype(np.int64) for parts in zip(*found, strict=True))
        return views_to_blame(track, a, b, seen.shape)
