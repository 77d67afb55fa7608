"""Random multi-view tracks, as a matcher hands them to the pool: for exercising the pool and its codecs.

Pixels are uniform over a `WIDTH` x `HEIGHT` image (origin at the top-left
pixel's centre); no geometry lies behind them.
"""

from __future__ import annotations

import numpy as np

from camnet.matching.pool import TrackPool
from camnet.matching.tracks import FrameTracks

WIDTH, HEIGHT = 640, 512


def random_tracks(rng: np.random.Generator, camera_ids: tuple[str, ...], n: int) -> FrameTracks:
    """`n` tracks each seen by 2 to 4 of the cameras at random pixels."""
    uv = np.full((n, len(camera_ids), 2), np.nan)
    for t in range(n):
        seen = rng.choice(len(camera_ids), rng.integers(2, 5), replace=False)
        uv[t, seen] = rng.random((len(seen), 2)) * [WIDTH - 1, HEIGHT - 1]
    return FrameTracks(camera_ids, uv)


def reseen(rng: np.random.Generator, pool: TrackPool, n: int) -> FrameTracks:
    """`n` pooled tracks seen again, each by one more camera: the pool fills that camera in."""
    obs = pool.observations()
    ids = tuple(c.id for c in obs.cameras)
    uv = np.full((len(obs.track_ids), len(ids), 2), np.nan)
    uv[obs.track_index, obs.cam_index] = obs.uv
    chosen = [t for t in rng.permutation(len(uv)) if np.isnan(uv[t, :, 0]).any()][:n]
    for t in chosen:
        uv[t, rng.choice(np.flatnonzero(np.isnan(uv[t, :, 0])))] = rng.random(2) * [WIDTH - 1, HEIGHT - 1]
    return FrameTracks(ids, uv[chosen])
