"""Pool tracks from many frame sets into one bounded observation set.

The rig is static while the scene moves, so every frame set adds new scene
points seen by the same cameras; pooled over time they cover many depths
and image regions, which the calibration needs.

What counts as the same scene point:

- Within one frame set, two tracks that share a camera and lie within
  `duplicate_radius_px` there are the same point (one pixel sees one point
  at one instant). Typically SIFT returns two keypoints at one place with two
  orientations, matched through different pairs. If they agree in every
  camera they share, they are merged into one track (union of cameras);
  otherwise the one seen by fewer cameras is dropped.
- Across frame sets, a coinciding pixel in one camera is not enough: the
  scene moved, so the same pixel may see a different point at another depth
  along the same ray. Those are distinct points and both are kept. But when
  two tracks coincide in at least two shared cameras (and agree in every
  camera they share), their rays meet at the same place, and with a static
  rig that is the same 3-D point whether or not the object moved: typically
  static background re-detected in every frame set. Adding it again would
  bring no new geometry, only repeat the same measurement and overweight
  the static background, so it is merged into the pooled track, which is
  marked as seen again (`last_seen`).

With `PoolConfig.epipolar_px` set (the default), every pair of cameras
gets an F fitted to all that the pool holds of it (refitted in turn), and
a view off it is dropped, or the whole track where no one view is to blame
(`camnet.matching.pair_geometry`): false tracks that one frame set's
matching let through would otherwise accumulate.

When the pool is over `max_tracks`, tracks are evicted from the most
crowded grid cell first (each camera's image is split into a grid and a
track counts in the fullest cell it occupies), so the pool spreads over the
image area; among equally crowded tracks the one seen by fewer cameras goes
first, then the one least recently seen.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from camnet.matching.pair_geometry import PairGeometry
from camnet.matching.tracks import FrameTracks
from camnet.model.camera import CameraInfo
from camnet.model.observations import Observations, Stereo

log = logging.getLogger(__name__)

# Cameras' views lie this far apart in the third coordinate of `_close_pairs`'s tree: beyond any radius.
CAMERA_PLANE_PX = 1e6
# A camera blamed alone (the one view off its pairs' F in a track of three or more) in over this share of its
# views in a frame set's tracks, and in at least MOVED_MIN_VIEWS of them, moved: its old-pose views would judge
# its new ones against the old geometry, and the calibrator would never see the move (`_reject_off_epipolar`).
MOVED_SHARE = 0.5
MOVED_MIN_VIEWS = 10
# ... over this many frame sets running (each with MOVED_MIN_VIEWS of its views in such tracks): a person moving
# between the capture instants of free-running cameras puts one camera's views off in a frame set or two, a move
# in every one. A suspect's views are kept meanwhile: if it moved, they are its new pose's.
MOVED_FRAME_SETS = 3


@dataclass(frozen=True)
class PoolConfig:
    max_tracks: int = 5000
    duplicate_radius_px: float = 1.0
    grid_cols: int = 8  # cells across each image for spreading
    grid_rows: int = 8
    # A view off its pair's pooled F by more than this (Sampson, px; a pair with a wider residual spread gets a
    # wider limit) is dropped (`camnet.matching.pair_geometry`); 0: no check. 2 px, not the matcher's 1 px
    # RANSAC threshold: an F pooled over a few frame sets is still a pixel off in places (docs/benchmarks.md, "The
    # surround rig, live").
    epipolar_px: float = 2.0
    epipolar_min_tracks: int = 20  # a pair's F needs this many tracks on it (the matcher's min_matches)

    def __post_init__(self) -> None:
        if self.epipolar_px < 0 or self.epipolar_min_tracks < 8:
            raise ValueError(f"expected epipolar_px >= 0 and epipolar_min_tracks >= 8 (for F), got "
                             f"{self.epipolar_px} and {self.epipolar_min_tracks}")
        if self.max_tracks <= 0:
            raise ValueError(f"max_tracks must be positive, got {self.max_tracks}")
        if self.duplicate_radius_px < 0:
            raise ValueError(f"duplicate_radius_px must be >= 0, got {self.duplicate_radius_px}")
        if self.grid_cols <= 0 or self.grid_rows <= 0:
            raise ValueError(f"grid must be positive, got {self.grid_cols}x{self.grid_rows}")


@dataclass(frozen=True)
class PoolUpdate:
    """What one `TrackPool.add` did, for counters and logs."""

    offered: int
    merged_in_frame: int  # duplicates inside the frame set, merged or dropped
    reobserved: int  # matched a pooled track (same 3-D point), merged into it
    added: int
    evicted: int
    rejected: int = 0  # tracks the pooled F check left with under two views (`camnet.matching.pair_geometry`)


def _agree(uv_a: np.ndarray, uv_b: np.ndarray, radius_px: float) -> tuple[int, bool]:
    """(number of cameras both see, whether they lie within radius in all of them).

    `uv_a`, `uv_b`: (C, 2) pixels, NaN = unseen.
    """
    both = np.isfinite(uv_a[:, 0]) & np.isfinite(uv_b[:, 0])
    if not both.any():
        return 0, False
    d = np.hypot(*(uv_a[both] - uv_b[both]).T)
    return int(both.sum()), bool(np.all(d <= radius_px))


def _same_point(uv_a: np.ndarray, uv_b: np.ndarray, radius_px: float) -> np.ndarray:
    """(P,) pairs of tracks `uv_a[k]`, `uv_b[k]` (P, C, 2) seen by 2+ cameras in common, within `radius_px` in
    all of them (`_agree` of every pair at once)."""
    both = np.isfinite(uv_a[:, :, 0]) & np.isfinite(uv_b[:, :, 0])
    with np.errstate(invalid="ignore"):
        close = np.hypot(*np.moveaxis(uv_a - uv_b, 2, 0)) <= radius_px
    return (both.sum(axis=1) >= 2) & np.all(close | ~both, axis=1)


def _views(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(track of each view, points (u, v, camera) of the views) of `uv` (T, C, 2), NaN = unseen: in one tree
    the cameras lie on planes of their own, so a neighbour within a pixel is in the same camera."""
    track, camera = np.nonzero(np.isfinite(uv[:, :, 0]))
    return track, np.column_stack([uv[track, camera], CAMERA_PLANE_PX * camera])


def _close_pairs(uv_a: np.ndarray, uv_b: np.ndarray | None, radius_px: float) -> np.ndarray:
    """(k, 2) pairs (i, j) of tracks within `radius_px` in at least one camera, unique, in increasing order.

    With `uv_b` None, pairs i < j within `uv_a` itself. Arrays are (T, C, 2). One tree of every camera's
    views, not a tree per camera whose pairs Python gathers: that cost grew with the cameras.
    """
    track_a, points_a = _views(uv_a)
    none = np.empty((0, 2), dtype=np.int64)
    if len(track_a) == 0:
        return none
    tree_a = cKDTree(points_a)
    if uv_b is None:
        views = tree_a.query_pairs(radius_px, output_type="ndarray")
        i, j = track_a[views[:, 0]], track_a[views[:, 1]]
        i, j = np.minimum(i, j), np.maximum(i, j)
        n = len(uv_a)
    else:
        track_b, points_b = _views(uv_b)
        if len(track_b) == 0:
            return none
        near = tree_a.sparse_distance_matrix(cKDTree(points_b), radius_px, output_type="ndarray")
        i, j = track_a[near["i"]], track_b[near["j"]]
        n = len(uv_b)
    keys = np.unique(i.astype(np.int64) * n + j)
    return np.column_stack([keys // n, keys % n])


def dedupe_frame_tracks(uv: np.ndarray, radius_px: float) -> tuple[np.ndarray, int]:
    """Merge or drop same-frame duplicates (see the module docstring).

    `uv`: (T, C, 2) pixels, NaN = unseen. Returns the deduplicated (T', C, 2)
    array and the number of tracks merged or dropped.
    """
    pairs = _close_pairs(uv, None, radius_px).tolist()
    if not pairs:
        return uv, 0
    uv = uv.copy()
    views = np.isfinite(uv[:, :, 0]).sum(axis=1)
    neighbours: dict[int, list[int]] = {}
    for i, j in pairs:
        neighbours.setdefault(i, []).append(j)
        neighbours.setdefault(j, []).append(i)
    alive = np.ones(len(uv), dtype=bool)
    # Strongest first, so a weak track folds into a strong one, not the reverse.
    for i in sorted(neighbours, key=lambda k: (-views[k], k)):
        if not alive[i]:
            continue
        for j in neighbours[i]:
            if not alive[j]:
                continue
            _, agree = _agree(uv[i], uv[j], radius_px)
            if agree:
                fill = ~np.isfinite(uv[i, :, 0]) & np.isfinite(uv[j, :, 0])
                uv[i, fill] = uv[j, fill]
            alive[j] = False
    return uv[alive], int((~alive).sum())


def _view_cells(uv: np.ndarray, sizes_px: np.ndarray, grid_cols: int,
                grid_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """(track, cell) of every view of `uv` (T, C, 2), in track order: cell numbers run over (camera, row, col)."""
    track, cam = np.nonzero(np.isfinite(uv[:, :, 0]))
    w, h = sizes_px[cam, 0], sizes_px[cam, 1]
    # +0.5: pixel centres run from 0 to w - 1, the image area from -0.5 to w - 0.5.
    col = np.clip(((uv[track, cam, 0] + 0.5) / w * grid_cols).astype(int), 0, grid_cols - 1)
    row = np.clip(((uv[track, cam, 1] + 0.5) / h * grid_rows).astype(int), 0, grid_rows - 1)
    return track, cam * (grid_cols * grid_rows) + row * grid_cols + col


def _fullest(track: np.ndarray, cell: np.ndarray, n_tracks: int, n_cells: int) -> np.ndarray:
    """(n_tracks,) the count of views in the fullest cell each track occupies (0: none)."""
    count = np.bincount(cell, minlength=n_cells)
    out = np.zeros(n_tracks, dtype=np.int64)
    np.maximum.at(out, track, count[cell])
    return out


def crowding(uv: np.ndarray, sizes_px: np.ndarray, grid_cols: int, grid_rows: int) -> np.ndarray:
    """(T,) for each track, the count of tracks in the fullest grid cell it occupies.

    `uv`: (T, C, 2) pixels, NaN = unseen; `sizes_px`: (C, 2) image width, height.
    """
    track, cell = _view_cells(uv, sizes_px, grid_cols, grid_rows)
    return _fullest(track, cell, uv.shape[0], uv.shape[1] * grid_cols * grid_rows)


class TrackPool:
    """A bounded pool of tracks over many frame sets of one static rig.

    Not thread-safe: the matcher node owns one and feeds it in order.
    """

    def __init__(self, cameras: Sequence[CameraInfo], stereo: Stereo, config: PoolConfig = PoolConfig()) -> None:
        ids = [c.id for c in cameras]
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate camera ids: {ids}")
        for side in (stereo.left, stereo.right):
            if side not in ids:
                raise ValueError(f"stereo camera {side!r} is not among the cameras {ids}")
        self.cameras = tuple(cameras)
        self.stereo = stereo
        self.config = config
        self._column = {cam_id: i for i, cam_id in enumerate(ids)}
        self._sizes_px = np.array([[c.width, c.height] for c in cameras], dtype=float)
        self._uv = np.empty((0, len(ids), 2))
        self._ids = np.empty(0, dtype=np.int64)
        self._last_seen = np.empty(0, dtype=np.int64)
        self._next_id = 0
        # Per camera whose views were forgotten (it moved), the first track id pooled since: its views of older
        # tracks were judged against its old geometry, a biased few (told to the calibrator, `camnet.bus.moved`).
        self.forgotten: dict[str, int] = {}
        # Per column suspected of a move (`_reject_off_epipolar`): the first track id of its first frame set off
        # its pairs' F, how many frame sets running have been, and the ids of the tracks its views were kept in.
        self._suspects: dict[int, tuple[int, int, set[int]]] = {}
        self._geometry = PairGeometry(len(ids), threshold_px=config.epipolar_px,
                                      min_inliers=config.epipolar_min_tracks)

    def __len__(self) -> int:
        return len(self._ids)

    def _to_pool_columns(self, tracks: FrameTracks) -> np.ndarray:
        uv = np.full((len(tracks), len(self.cameras), 2), np.nan)
        for c, cam_id in enumerate(tracks.camera_ids):
            if cam_id not in self._column:
                raise ValueError(f"frame set camera {cam_id!r} is not in the pool's cameras")
            uv[:, self._column[cam_id]] = tracks.uv[:, c]
        return uv

    def add(self, tracks: FrameTracks, *, frame_seq: int) -> PoolUpdate:
        """Pool the tracks of one frame set; `frame_seq` increases with time."""
        radius = self.config.duplicate_radius_px
        new_uv, merged_in_frame = dedupe_frame_tracks(self._to_pool_columns(tracks), radius)
        is_new = np.ones(len(new_uv), dtype=bool)
        grown = np.zeros(len(self._uv), dtype=bool)
        reobserved = 0
        pairs = _close_pairs(new_uv, self._uv, radius)
        same = _same_point(new_uv[pairs[:, 0]], self._uv[pairs[:, 1]], radius)
        # A pooled track grown by a merge is judged again; one no other pair names cannot have been.
        named = np.bincount(pairs[:, 1], minlength=len(self._uv))[pairs[:, 1]]
        grown_now: set[int] = set()
        for k in np.flatnonzero(same | (named > 1)).tolist():
            i, j = int(pairs[k, 0]), int(pairs[k, 1])
            if not is_new[i]:
                continue
            if j in grown_now:
                shared, agree = _agree(new_uv[i], self._uv[j], radius)
                same[k] = shared >= 2 and agree
            if same[k]:
                grown_now.add(j)
                fill = ~np.isfinite(self._uv[j, :, 0]) & np.isfinite(new_uv[i, :, 0])
                self._uv[j, fill] = new_uv[i, fill]
                grown[j] = fill.any()
                self._last_seen[j] = frame_seq
                is_new[i] = False
                reobserved += 1
        added = int(is_new.sum())
        first_new_id = self._next_id
        self._uv = np.concatenate([self._uv, new_uv[is_new]])
        self._ids = np.concatenate([self._ids, self._next_id + np.arange(added)])
        self._last_seen = np.concatenate([self._last_seen, np.full(added, frame_seq)])
        self._next_id += added
        rejected = self._reject_off_epipolar(np.concatenate([grown, np.ones(added, dtype=bool)]), first_new_id)
        evicted = self._evict()
        update = PoolUpdate(len(tracks), merged_in_frame, reobserved, added, evicted, rejected)
        log.debug("frame %d: %s, pool %d", frame_seq, update, len(self))
        return update

    def forget_camera(self, camera_id: str) -> int:
        """Drop every view of `camera_id` (it moved: its old-pose views would judge its new ones against
        the old geometry), and the tracks left with fewer than two views; the number of tracks dropped.

        Its pairs' F are fitted afresh from its new views (`PairGeometry.forget`). Track ids stay; those pooled
        from now on are `forgotten[camera_id]` on.
        """
        if camera_id not in self._column:
            raise ValueError(f"camera {camera_id!r} is not in the pool's cameras")
        self.forgotten[camera_id] = self._next_id
        column = self._column[camera_id]
        self._suspects.pop(column, None)
        self._uv[:, column] = np.nan
        self._geometry.forget(column)
        keep = np.isfinite(self._uv[:, :, 0]).sum(axis=1) >= 2
        self._uv, self._ids, self._last_seen = self._uv[keep], self._ids[keep], self._last_seen[keep]
        return int((~keep).sum())

    def _reject_off_epipolar(self, changed: np.ndarray, first_new_id: int) -> int:
        if self.config.epipolar_px <= 0:
            return 0
        off = self._geometry.off_views(self._uv, changed)
        blamed, judged = moved_columns(off, np.isfinite(self._uv[:, :, 0]), changed)
        for column in set(judged) - set(blamed):  # on its pairs' F in a frame set that shows it: not moved
            self._suspects.pop(column, None)
        for column in blamed:
            first, sets, kept = self._suspects.get(column, (first_new_id, 0, set()))
            kept |= set(self._ids[changed & off[:, column]].tolist())
            off[:, column] = False
            if sets + 1 < MOVED_FRAME_SETS:
                self._suspects[column] = (first, sets + 1, kept)
                log.info("camera %r: its views break its pairs' epipolar geometry alone in %d frame set(s) running: "
                         "kept, and a move once they do in %d", self.cameras[column].id, sets + 1, MOVED_FRAME_SETS)
                continue
            del self._suspects[column]
            # Its views from before its first frame set off go, not those since; its pairs are fitted to those afresh.
            log.warning("camera %r: its views break its pairs' epipolar geometry alone in %d frame sets running: "
                        "taken for moved, its earlier views forgotten", self.cameras[column].id, MOVED_FRAME_SETS)
            since = changed | np.isin(self._ids, list(kept))
            self._uv[~since, column] = np.nan
            self._geometry.forget(column)
            self.forgotten[self.cameras[column].id] = first
        self._uv[off] = np.nan
        keep = ~off.any(axis=1) | (np.isfinite(self._uv[:, :, 0]).sum(axis=1) >= 2)
        self._uv, self._ids, self._last_seen = self._uv[keep], self._ids[keep], self._last_seen[keep]
        return int((~keep).sum())

    def _evict(self) -> int:
        cfg = self.config
        if len(self._ids) <= cfg.max_tracks:
            return 0
        # The views' cells once; each round recounts only the views of the tracks still kept.
        track, cell = _view_cells(self._uv, self._sizes_px, cfg.grid_cols, cfg.grid_rows)
        n_cells = self._uv.shape[1] * cfg.grid_cols * cfg.grid_rows
        views = np.isfinite(self._uv[:, :, 0]).sum(axis=1)
        keep = np.ones(len(self._ids), dtype=bool)
        while (kept := int(keep.sum())) > cfg.max_tracks:
            live = keep[track]
            crowd = _fullest(track[live], cell[live], len(keep), n_cells)
            index = np.flatnonzero(keep)
            # lexsort: last key is primary. Most crowded, then fewest views, then oldest.
            order = np.lexsort((self._ids[index], self._last_seen[index], views[index], -crowd[index]))
            # Evict in halves so that crowding is recounted as cells empty.
            keep[index[order[: max(1, (kept - cfg.max_tracks + 1) // 2)]]] = False
        self._uv, self._ids, self._last_seen = self._uv[keep], self._ids[keep], self._last_seen[keep]
        return int((~keep).sum())

    def observations(self) -> Observations:
        """The pool as `Observations`; track ids are stable while a track stays pooled."""
        seen = np.isfinite(self._uv[:, :, 0])
        track_index, cam_index = np.nonzero(seen)
        return Observations(
            cameras=self.cameras,
            stereo=self.stereo,
            track_ids=self._ids.copy(),
            cam_index=cam_index.astype(np.int64),
            track_index=track_index.astype(np.int64),
            uv=self._uv[track_index, cam_index].reshape(-1, 2),
        )


def moved_columns(off: np.ndarray, seen: np.ndarray, changed: np.ndarray) -> tuple[list[int], list[int]]:
    """(blamed, judged): columns of the cameras off their pairs' F in this frame set, by `off` (T, C) the views
    off their pairs' F (`PairGeometry.off_views`), `seen` (T, C) and `changed` (T,) the tracks of this frame
    set: blamed alone, in tracks of three or more views, in over MOVED_SHARE of their views in those tracks and
    in at least MOVED_MIN_VIEWS; and the columns with at least MOVED_MIN_VIEWS views in those tracks."""
    wide = changed & (seen.sum(axis=1) >= 3)
    alone = off[wide] & (off[wide].sum(axis=1) == 1)[:, None]
    blamed, views = alone.sum(axis=0), seen[wide].sum(axis=0)
    return ([int(c) for c in np.flatnonzero((blamed >= MOVED_MIN_VIEWS) & (blamed > MOVED_SHARE * views))],
            [int(c) for c in np.flatnonzero(views >= MOVED_MIN_VIEWS)])


def regrow_pool(pool: TrackPool | None, cameras: list[CameraInfo], stereo: Stereo, config: PoolConfig,
                *, frame_seq: int) -> TrackPool:
    """A pool over `cameras` holding the tracks of `pool` (None: an empty pool).

    For a camera whose size became known, or changed, after pooling began.
    Track ids are renumbered.
    """
    grown = TrackPool(cameras, stereo, config)
    if pool is None or len(pool) == 0:
        return grown
    obs = pool.observations()
    column = {c.id: i for i, c in enumerate(cameras)}
    uv = np.full((len(obs.track_ids), len(cameras), 2), np.nan)
    uv[obs.track_index, [column[obs.cameras[c].id] for c in obs.cam_index]] = obs.uv
    grown.add(FrameTracks(tuple(column), uv), frame_seq=frame_seq)
    return grown
