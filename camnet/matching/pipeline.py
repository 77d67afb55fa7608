"""Images to observations: the matcher's chain, as one pure function.

Per synchronized frame set: features and pairwise matches
(`camnet.matching.features.match_frame_set`), multi-view tracks
(`camnet.matching.tracks.build_tracks`), pooled over frame sets
(`camnet.matching.pool.TrackPool`). The matcher node runs the same chain one
frame set at a time; offline runs, tests and benchmarks call this function.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from camnet.matching.features import MatcherConfig, match_frame_set
from camnet.matching.pool import PoolConfig, TrackPool
from camnet.matching.tracks import build_tracks
from camnet.model.camera import FIXABLE, Camera, CameraInfo
from camnet.model.observations import Observations, Stereo
from camnet.model.projection import full_dist

log = logging.getLogger(__name__)


def observations_from_frame_sets(
    frame_sets: Iterable[Mapping[str, np.ndarray]],
    *,
    cameras: Sequence[CameraInfo],
    stereo: Stereo,
    matcher: MatcherConfig | None = None,
    pool: PoolConfig | None = None,
) -> Observations:
    """Pool the tracks of every frame set into one observation set.

    `frame_sets`: in capture order, each maps camera id to the image (uint8
    grey (H, W) or BGR (H, W, 3)) taken at one trigger; a frame set may hold
    any subset of `cameras`. `cameras` lists every camera of the rig, with
    whatever is known of it (K, dist, fixed), which the observations carry.
    `matcher` and `pool` default to MatcherConfig() and PoolConfig().
    Logs one progress line per frame set, and a warning the first time a
    camera's image yields too few features, saying why (then only counts them).
    """
    matcher = MatcherConfig() if matcher is None else matcher
    track_pool = TrackPool(cameras, stereo, PoolConfig() if pool is None else pool)
    short: dict[str, int] = {}  # frame sets in which a camera had too few features
    for seq, images in enumerate(frame_sets):
        t0 = time.perf_counter()
        matches = match_frame_set(images, matcher, stereo=stereo)
        for camera_id, features in zip(matches.camera_ids, matches.features, strict=True):
            if features.shortage is not None:
                if camera_id not in short:
                    log.warning("camera %r: %s", camera_id, features.shortage)
                short[camera_id] = short.get(camera_id, 0) + 1
        tracks = build_tracks(matches)
        update = track_pool.add(tracks, frame_seq=seq)
        log.info(
            "frame set %d (cameras %s): %d tracks, %d new, %d re-observed, pool %d (%.1f s)",
            seq,
            ",".join(sorted(images)),
            update.offered,
            update.added,
            update.reobserved,
            len(track_pool),
            time.perf_counter() - t0,
        )
    for camera_id, count in short.items():
        if count > 1:
            log.warning("camera %r: too few features in %d frame sets", camera_id, count)
    return track_pool.observations()


def with_known_intrinsics(
    obs: Observations,
    known: Mapping[str, Camera],
    *,
    given: Sequence[str] = FIXABLE,
    fixed: Sequence[str] | None = None,
) -> Observations:
    """`obs` with the intrinsics named in `given` ("K", "dist") of the cameras in `known`.

    `fixed` (default: all of `given`) names what the solver must hold as
    given; what is given but not fixed is a starting point.
    """
    fixed = given if fixed is None else fixed
    unknown = set(known) - set(obs.camera_ids)
    if unknown:
        raise ValueError(f"known intrinsics for cameras not in the observations: {sorted(unknown)}")
    if not set(fixed) <= set(given) <= set(FIXABLE):
        raise ValueError(f"expected fixed {tuple(fixed)} within given {tuple(given)} within {FIXABLE}")
    cameras = []
    for c in obs.cameras:
        if c.id in known:
            cam = known[c.id]
            K = np.array(cam.K, dtype=float) if "K" in given else c.K
            dist = full_dist(cam.dist, cam.model.dist_size) if "dist" in given else c.dist
            c = replace(c, K=K, dist=dist, fixed=frozenset(fixed), model=cam.model)
        cameras.append(c)
    return replace(obs, cameras=tuple(cameras))
