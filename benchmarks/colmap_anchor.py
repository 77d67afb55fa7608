"""What a user does today, as the anchor beside camnet: COLMAP's bundle adjustment (pycolmap,
Ceres) on the same tracks from the same start, the scale fixed afterwards from the known distance.

Benchmark-only (pycolmap is in the test extra). COLMAP's pixel origin is the
corner of the top-left pixel, camnet's its centre: +0.5 px on the way in.
Every camera is COLMAP's OPENCV model (fx, fy, cx, cy, k1, k2, p1, p2) with
the focal length and the distortion refined and the principal point held at
the image centre, COLMAP's defaults; a camera whose K the observations give
and fix (a factory-calibrated head) starts at its K and distortion, held.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from camnet.geometry.cold_start import cold_start
from camnet.geometry.initialise import camera_order, centred, initial_intrinsics, observation_rows
from camnet.geometry.model import Observations

COLMAP_PIXEL_SHIFT = 0.5


@dataclass(frozen=True)
class AnchorResult:
    track_ids: np.ndarray  # (N,) the tracks COLMAP kept a point for
    points: np.ndarray  # (N, 3) metres, scaled by the known distance
    focal_px: dict[str, float]
    seconds: float  # the bundle adjustment alone


def _given(cam) -> bool:
    """Whether the observations give this camera's K and distortion and fix them."""
    return cam.K is not None and cam.dist is not None and {"K", "dist"} <= cam.fixed


def _params(cam, f_start: float) -> list[float]:
    """COLMAP OPENCV parameters (fx, fy, cx, cy, k1, k2, p1, p2): the given ones, else the start's focal length."""
    if not _given(cam):
        return [f_start, f_start, cam.width / 2, cam.height / 2, 0.0, 0.0, 0.0, 0.0]
    K, dist = cam.K, np.zeros(4) if not len(cam.dist) else np.asarray(cam.dist, dtype=float)[:4]
    return [K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_SHIFT, K[1, 2] + COLMAP_PIXEL_SHIFT, *dist]


def camnet_start(obs: Observations, seed: int = 0):
    """(order, start): camnet's cold start of `obs`, as `camnet.geometry.calibrate` computes it."""
    order = camera_order(obs)
    intr = initial_intrinsics(obs, order)
    xy = centred(obs, order, intr)
    start = cold_start(obs, order, intr, xy, observation_rows(obs), seed=seed, max_tracks=150)
    return order, start


def colmap_adjust(obs: Observations, seed: int = 0) -> AnchorResult:
    """COLMAP's bundle adjustment of `obs` from camnet's cold start, then the stereo pair's distance as the scale."""
    import pycolmap

    pycolmap.logging.minloglevel = pycolmap.logging.WARNING  # one INFO banner per adjustment otherwise
    order, start = camnet_start(obs, seed)
    rec = pycolmap.Reconstruction()
    image_of = {}
    for m, i in enumerate(order):
        if not start.registered[m]:
            continue
        cam = obs.cameras[i]
        camera = pycolmap.Camera(model="OPENCV", width=cam.width, height=cam.height, camera_id=m + 1,
                                 params=_params(cam, float(start.f[m])))
        rec.add_camera_with_trivial_rig(camera)
        mine = np.flatnonzero(obs.cam_index == i)
        image = pycolmap.Image(name=cam.id, keypoints=obs.uv[mine] + COLMAP_PIXEL_SHIFT, camera_id=m + 1,
                               image_id=m + 1)
        R = start.R[m]
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.column_stack([R, -R @ start.C[m]])))
        image_of[m + 1] = mine
    rows_of = {int(r): (image_id, k) for image_id, mine in image_of.items() for k, r in enumerate(mine)}
    kept = []
    for j in np.flatnonzero(np.all(np.isfinite(start.X), axis=1)):
        elements = [rows_of[int(r)] for r in np.flatnonzero(obs.track_index == j) if int(r) in rows_of]
        if len(elements) < 2:
            continue
        track = pycolmap.Track()
        for image_id, k in elements:
            track.add_element(image_id, k)
        rec.add_point3D(start.X[j], track)
        kept.append(j)
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    t0 = time.perf_counter()
    held = [m + 1 for m, i in enumerate(order) if m + 1 in image_of and _given(obs.cameras[i])]
    if held:  # the default adjustment, with the given cameras' intrinsics held
        config = pycolmap.BundleAdjustmentConfig()
        for image_id in image_of:
            config.add_image(image_id)
        for camera_id in held:
            config.set_constant_cam_intrinsics(camera_id)
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
        pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    else:
        pycolmap.bundle_adjustment(rec, options)
    seconds = time.perf_counter() - t0
    centre = {m: rec.image(m + 1).projection_center() for m in range(2)}
    scale = obs.stereo.baseline_m / np.linalg.norm(centre[1] - centre[0])
    points = np.array([rec.points3D[pid].xyz for pid in sorted(rec.points3D)]) * scale
    focal = {obs.cameras[order[cid - 1]].id: float(rec.cameras[cid].params[0]) for cid in rec.cameras}
    return AnchorResult(obs.track_ids[np.array(kept)], points, focal, seconds)
