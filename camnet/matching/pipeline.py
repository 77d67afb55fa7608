"""Images to observations: the matching engine over frame sets given at once, and what a user knows of K.

`observations_from_frame_sets` runs `camnet.matching.engine.MatchingEngine`,
the engine behind the matcher node, over frame sets in capture order: offline
runs (`camnet match`), datasets, tests and benchmarks find what a live rig
finds in the same frames.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from camnet.matching.engine import CameraImage, EngineConfig, MatchingEngine
from camnet.model.camera import FIXABLE, Camera, CameraInfo
from camnet.model.observations import Observations, Stereo
from camnet.model.projection import full_dist

log = logging.getLogger(__name__)


def observations_from_frame_sets(
    frame_sets: Iterable[Mapping[str, np.ndarray]],
    *,
    cameras: Sequence[CameraInfo],
    stereo: Stereo,
    config: EngineConfig | None = None,
) -> Observations:
    """Pool the tracks of every frame set into one observation set, as the matcher node pools a live rig's.

    `frame_sets`: in capture order, each maps camera id to the image (uint8
    or uint16, grey (H, W) or BGR (H, W, 3)) taken at one trigger; a frame set
    may hold any subset of `cameras`. `cameras` lists every camera of the rig,
    with whatever is known of it (K, dist, fixed), which the observations
    carry. `config` defaults to EngineConfig(), the matcher node's defaults.
    Logs one progress line per frame set, and a warning the first time a
    camera's image yields too few features, saying why (then only counts them).
    """
    short: dict[str, int] = {}  # frame sets in which a camera had too few features
    with ThreadPoolExecutor(max_workers=max(1, min(len(cameras), os.cpu_count() or 1)),
                            thread_name_prefix="match") as workers:
        engine = MatchingEngine(cameras, stereo, EngineConfig() if config is None else config, executor=workers)
        for seq, images in enumerate(frame_sets):
            result = engine.process([CameraImage(camera_id, image, seq=seq) for camera_id, image in images.items()])
            for camera_id, reason in result.few_features.items():
                if camera_id not in short:
                    log.warning("camera %r: %s", camera_id, reason)
                short[camera_id] = short.get(camera_id, 0) + 1
            update = result.update
            log.info("frame set %d (cameras %s): %d of %d pairs, %d tracks, %d new, %d re-observed, pool %d (%.1f s)",
                     seq, ",".join(sorted(images)), *result.pairs, update.offered, update.added, update.reobserved,
                     len(engine.pool), result.elapsed_s)
    for camera_id, count in short.items():
        if count > 1:
            log.warning("camera %r: too few features in %d frame sets", camera_id, count)
    return engine.observations()


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
