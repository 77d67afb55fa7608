"""The matching engine: frame sets in, pooled multi-view tracks out.

The matcher node (`camnet matcher`) and `camnet match`
(`camnet.matching.pipeline.observations_from_frame_sets`) run this one engine,
so what the offline command finds is what the live rig finds. Per frame set,
in order:

- each camera's features: detected here, each camera on its own
  `camnet.matching.edge.FeatureExtractor` (only where the image changed since
  its keyframe), or as the camera's own feature stage sent them
  (`camnet.matching.edge.CameraFeatures`);
- `camnet.matching.reuse.IncrementalMatcher` matches only what is new since a
  pair's last whole match, on every pair until the rig has a calibration
  (`take_calibration`), then on the view graph's pairs
  (`camnet.matching.viewgraph`);
- `camnet.matching.tracks.build_tracks` chains the matches into tracks and
  `camnet.matching.pool.TrackPool` pools them.

A camera whose size is not known at the start (width and height 0) joins the
pool when its first image shows it: the pool then starts afresh over the
cameras of known size, holding the tracks so far (`pool_id` changes, track ids
start over). Once the pool is full, images may be detected smaller
(`EngineConfig.full_pool_image_side_px`).

Detection and matching run on an `executor` when one is given (a thread pool:
OpenCV releases the GIL), one camera or one pair a task. Each pair task seeds
OpenCV's RNG, which is per thread, so a frame set gives the same matches
whichever thread takes a pair. The engine itself is not thread-safe: one
caller feeds it frame sets in order.
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace

import numpy as np

from camnet.matching.edge import CameraFeatures, EdgeConfig, FeatureExtractor
from camnet.matching.features import FrameSetMatches, MatcherConfig
from camnet.matching.images import to_grey
from camnet.matching.pool import PoolConfig, PoolUpdate, TrackPool, regrow_pool
from camnet.matching.reuse import IncrementalMatcher
from camnet.matching.tracks import build_tracks
from camnet.matching.viewgraph import ViewGraph, ViewGraphConfig
from camnet.model.calibration import Calibration
from camnet.model.camera import CameraInfo
from camnet.model.observations import Observations, Stereo

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EngineConfig:
    """How the engine detects, matches, chooses its pairs and pools."""

    matcher: MatcherConfig = MatcherConfig()
    # Once the pool holds pool.max_tracks, a frame set's new tracks only replace others: then detect on a copy
    # downscaled to this size (if smaller than matcher.max_image_side_px; None: never).
    full_pool_image_side_px: int | None = None
    edge: EdgeConfig = EdgeConfig()
    view_graph: ViewGraphConfig = ViewGraphConfig()
    pool: PoolConfig = PoolConfig()

    def __post_init__(self) -> None:
        if self.full_pool_image_side_px is not None and self.full_pool_image_side_px < 16:
            raise ValueError(f"full_pool_image_side_px must be at least 16, got {self.full_pool_image_side_px}")

    def full_pool_matcher(self) -> MatcherConfig:
        """How images are detected once the pool is full."""
        side, limit = self.full_pool_image_side_px, self.matcher.max_image_side_px
        if side is None or (limit is not None and limit <= side):
            return self.matcher
        return replace(self.matcher, max_image_side_px=side)


@dataclass(frozen=True)
class CameraImage:
    """One camera's image of a frame set, for the engine to detect.

    `image`: (H, W) grey or Bayer mosaic, or (H, W, 3) colour, 8 or 16 bits; `encoding`: what its pixels
    are, as a frame encoding name (mono8, bgr8, rgb8, bayer_rggb8, ...), or None: grey, or BGR as OpenCV
    reads it. `seq` increases frame by frame of the camera (its keyframes are named by it).
    """

    camera_id: str
    image: np.ndarray
    seq: int
    timestamp_ns: int = 0
    encoding: str | None = None

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])


@dataclass(frozen=True)
class FrameSetResult:
    """What the engine made of one frame set."""

    update: PoolUpdate
    tracks: int  # tracks of the frame set
    tracks_3plus: int  # of them, seen by three cameras or more
    pairs: tuple[int, int]  # pairs matched, pairs of its cameras
    # Camera id: why its image gave fewer than MatcherConfig.few_features keypoints, and what to do.
    few_features: Mapping[str, str] = field(default_factory=dict)
    # When its features were ready, its pairs matched and its tracks pooled: wall clock, Unix epoch ns.
    detected_ns: int = 0
    matched_ns: int = 0
    pooled_ns: int = 0
    elapsed_s: float = 0.0  # detecting, matching and pooling it


@dataclass(frozen=True)
class EngineStats:
    """The engine's counters since it started, and its pool's size."""

    frame_sets_matched: int = 0
    frame_sets_pooled: int = 0  # of them, those whose tracks added to the pool or re-observed its tracks
    pairs: tuple[int, int] = (0, 0)  # in the last frame set: pairs matched, pairs of its cameras
    last_match_s: float = 0.0  # the last frame set's detecting, matching and pooling
    tracks_pooled: int = 0


def detection_size(config: MatcherConfig) -> str:
    """How large images are detected, in words."""
    side = config.max_image_side_px
    return "at full size" if side is None else f"of at most {side} px a side"


class MatchingEngine:
    """Frame sets of one static rig in, in capture order; its pooled tracks out.

    `cameras`: every camera of the rig, in order, with what is known of it (K, dist, fixed), which the
    observations carry; a camera of unknown size has width and height 0. `stereo`: the pair with the known
    distance (its cameras must be among `cameras`). `executor`: where detection and the pairs' matching run
    (None: in the calling thread).
    """

    def __init__(self, cameras: Sequence[CameraInfo], stereo: Stereo, config: EngineConfig = EngineConfig(), *,
                 executor: Executor | None = None) -> None:
        self.cameras = tuple(cameras)
        self.stereo = stereo
        self.config = config
        self._map = map if executor is None else executor.map
        self._sizes = {c.id: (c.width, c.height) for c in self.cameras if c.width and c.height}
        self._extractors = {c.id: FeatureExtractor(c.id, config.matcher, config.edge) for c in self.cameras}
        self._full_pool_detection = False  # the extractors detect as config.full_pool_matcher()
        self.matcher = IncrementalMatcher(config.matcher, stereo=stereo)
        self.view_graph = ViewGraph(config.view_graph, always={frozenset((stereo.left, stereo.right))})
        self._pool: TrackPool | None = None
        self.pool_id = ""  # new whenever the pool starts afresh, when track ids start over
        self._stats = EngineStats()

    @property
    def stats(self) -> EngineStats:
        return replace(self._stats, tracks_pooled=0 if self._pool is None else len(self._pool))

    @property
    def pool(self) -> TrackPool:
        """The pool over the cameras of known size (started afresh, holding its tracks, when one became known)."""
        return self._ensure_pool()

    def observations(self) -> Observations:
        """The pool's tracks now."""
        return self.pool.observations()

    def _ensure_pool(self) -> TrackPool:
        cameras = [replace(c, width=self._sizes[c.id][0], height=self._sizes[c.id][1])
                   for c in self.cameras if c.id in self._sizes]
        sizes = [(c.id, c.width, c.height) for c in cameras]
        if self._pool is None or [(c.id, c.width, c.height) for c in self._pool.cameras] != sizes:
            if self._pool is not None:
                log.info("cameras now %s: re-pooling %d tracks", ", ".join(f"{c.id} {c.width}x{c.height}"
                                                                       for c in cameras), len(self._pool))
            self._pool = regrow_pool(self._pool, cameras, self.stereo, self.config.pool,
                                     frame_seq=self._stats.frame_sets_matched)
            self.pool_id = uuid.uuid4().hex
        return self._pool

    def take_calibration(self, calibration: Calibration) -> None:
        """Choose the pairs to match with `calibration` from now on (`camnet.matching.viewgraph`)."""
        self.view_graph.update(calibration)
        log.info("calibration of %d cameras: %d overlapping pairs", len(calibration.cameras),
                 len(self.view_graph.overlapping))

    def forget_moved(self, camera_ids: Iterable[str]) -> None:
        """Forget what the pool and the matcher hold of each camera in `camera_ids`, which moved: its old-pose
        views would judge its new ones against the old geometry (`TrackPool.forget_camera`); its pairs are
        matched whole next."""
        pool = self._pool  # none yet: nothing pooled
        pooled = set() if pool is None else {c.id for c in pool.cameras}
        for camera_id in camera_ids:
            dropped = pool.forget_camera(camera_id) if camera_id in pooled else 0
            self.matcher.forget(camera_id)
            log.info("camera %r moved: forgot its views, %d tracks left with under two dropped; pool %d",
                     camera_id, dropped, 0 if pool is None else len(pool))

    def process(self, frame_set: Sequence[CameraImage | CameraFeatures]) -> FrameSetResult:
        """Detect, match and pool one frame set: per camera of the rig (any subset of them), its image or
        the features its own stage detected."""
        start_s = time.perf_counter()
        unknown = sorted({item.camera_id for item in frame_set} - self._extractors.keys())
        if unknown:
            raise ValueError(f"frame set cameras {unknown} are not among the rig's cameras "
                             f"{[c.id for c in self.cameras]}")
        for item in frame_set:
            self._sizes[item.camera_id] = (item.width, item.height)
        pool = self.pool
        self._detect_smaller_once_full(pool)
        cameras = self.matcher.prepare(list(self._map(self._features, frame_set)))
        detected_ns = time.time_ns()
        ids = [c.camera_id for c in cameras]
        pairs = self.view_graph.pairs(ids, matched_well=self.matcher.matched_well(
            self.view_graph.config.good_matches))
        matches = self._match_pairs(cameras, pairs)
        matched_ns = time.time_ns()
        possible = len(ids) * (len(ids) - 1) // 2
        few = {camera_id: features.shortage for camera_id, features in zip(matches.camera_ids, matches.features,
                                                                           strict=True) if features.shortage}
        tracks = build_tracks(matches)
        update = pool.add(tracks, frame_seq=self._stats.frame_sets_matched)
        elapsed_s = time.perf_counter() - start_s
        result = FrameSetResult(update, len(tracks), int(np.sum(tracks.views >= 3)),
                                (possible if pairs is None else len(pairs), possible), few, detected_ns, matched_ns,
                                time.time_ns(), elapsed_s)
        stats = self._stats
        self._stats = EngineStats(stats.frame_sets_matched + 1,
                                  stats.frame_sets_pooled + bool(update.added or update.reobserved),
                                  result.pairs, elapsed_s)
        return result

    def _detect_smaller_once_full(self, pool: TrackPool) -> None:
        """Once the pool is full, detect as `EngineConfig.full_pool_matcher` says."""
        if self._full_pool_detection or len(pool) < self.config.pool.max_tracks:
            return
        self._full_pool_detection = True
        smaller = self.config.full_pool_matcher()
        for extractor in self._extractors.values():
            extractor.config = smaller
        log.info("pool full (%d tracks): new tracks replace pooled ones from now on; detecting on images %s%s",
                 len(pool), detection_size(smaller), " as before" if smaller == self.config.matcher else "")

    def _features(self, item: CameraImage | CameraFeatures) -> CameraFeatures:
        """The features of one camera's part of a frame set: as its stage sent them, or detected here."""
        if isinstance(item, CameraFeatures):
            return item
        image = to_grey(item.image, encoding=item.encoding)
        return self._extractors[item.camera_id].extract(image, seq=item.seq, timestamp_ns=item.timestamp_ns)

    def _match_pairs(self, cameras: list[CameraFeatures], pairs: set[frozenset[str]] | None) -> FrameSetMatches:
        """`pairs` of `cameras` (None: all), one pair a task, in the order of one `IncrementalMatcher.match`
        call. Each task seeds OpenCV's RNG (`IncrementalMatcher.match`), so a frame set gives the same matches
        whichever thread takes a pair; tasks touch only their own pair's state."""
        ids = [c.camera_id for c in cameras]
        every = [frozenset((a, b)) for i, a in enumerate(ids) for b in ids[i + 1:]]
        chosen = every if pairs is None else [pair for pair in every if pair in pairs]
        parts = self._map(lambda pair: self.matcher.match(cameras, pairs={pair}), chosen)
        return FrameSetMatches(tuple(ids), tuple(c.features for c in cameras),
                               tuple(matched for part in parts for matched in part.pairs))


def match_frame_set(images: Mapping[str, np.ndarray] | Sequence[tuple[str, np.ndarray]],
                    config: MatcherConfig | None = None, *, stereo: Stereo | None = None,
                    seed: int = 0) -> FrameSetMatches:
    """Every pair of one frame set matched whole, as the engine matches a frame set it has not seen before,
    without probing a pair first: what matching alone finds, pair by pair (pooled tracks: `MatchingEngine`).

    `images` maps camera id to its image (uint8 or uint16, grey or BGR) of one trigger. If `stereo` is a
    parallel head (`stereo.parallel`) of two of those cameras and `config.use_stereo_prior` is set, its pair
    is matched under the near-epipolar prior (`camnet.matching.reuse.IncrementalMatcher.match`). OpenCV's RNG
    of the calling thread is seeded with `seed` first, so the matches are a function of the images alone.
    """
    config = MatcherConfig() if config is None else config
    items = list(images.items()) if isinstance(images, Mapping) else list(images)
    cameras = [FeatureExtractor(camera_id, config).extract(image, seq=0, timestamp_ns=0) for camera_id, image in items]
    return IncrementalMatcher(config, stereo=stereo, probe_every=1).match(cameras, seed=seed)
