"""What a user does today, as the anchor beside camnet: COLMAP's bundle adjustment (pycolmap,
Ceres) on the same tracks from the same start, the scale fixed afterwards from the known distance.

Benchmark-only (pycolmap is in the test extra). COLMAP's pixel origin is the
corner of the top-left pixel, camnet's its centre: +0.5 px on the way in.
By default every camera is COLMAP's OPENCV model (fx, fy, cx, cy, k1, k2, p1,
p2) with the focal length and the distortion refined and the principal point
held at the image centre, COLMAP's defaults; `AnchorSolver` chooses another
model (SIMPLE_PINHOLE: the focal length alone, as camnet's ``free={"f"}``), can
hold the stereo pair's poses as camnet holds them, and sets Ceres's stopping
rule. Otherwise the gauge is COLMAP's TWO_CAMS_FROM_WORLD. A camera whose K
the observations give and fix (a factory-calibrated head) starts at its K and
distortion, held.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from camnet.model.observations import Observations
from camnet.solve.context import SolveContext
from camnet.solve.start.cold import cold_start

COLMAP_PIXEL_SHIFT = 0.5


@dataclass(frozen=True)
class AnchorSolver:
    """What COLMAP refines, and when its solver (Ceres, Levenberg-Marquardt) stops."""

    camera_model: str = "OPENCV"  # OPENCV: f and k1, k2, p1, p2 refined; SIMPLE_PINHOLE: f alone
    hold_stereo_pair: bool = False  # both stereo cameras' poses held (camnet's ideal pair), else the gauge's
    # COLMAP's defaults for its bundle adjustment: no test on the cost's change, a gradient test instead.
    function_tolerance: float = 0.0
    gradient_tolerance: float = 1e-4
    max_num_iterations: int = 100


@dataclass(frozen=True)
class AnchorResult:
    track_ids: np.ndarray  # (N,) the tracks COLMAP kept a point for
    points: np.ndarray  # (N, 3) metres, scaled by the known distance
    focal_px: dict[str, float]
    seconds: float  # the bundle adjustment alone: setting up Ceres's problem and solving it
    cpu_seconds: float  # the same, in CPU time of this thread (Ceres solves on it at these sizes)
    iterations: int
    termination: str


def _given(cam) -> bool:
    """Whether the observations give this camera's K and distortion and fix them."""
    return cam.K is not None and cam.dist is not None and {"K", "dist"} <= cam.fixed


def _params(cam, f_start: float, camera_model: str) -> list[float]:
    """COLMAP parameters of `camera_model`: the given ones (OPENCV), else the start's focal length."""
    cx, cy = cam.width / 2, cam.height / 2
    if camera_model == "SIMPLE_PINHOLE":
        return [f_start, cx, cy]
    if not _given(cam):
        return [f_start, f_start, cx, cy, 0.0, 0.0, 0.0, 0.0]
    K, dist = cam.K, np.zeros(4) if not len(cam.dist) else np.asarray(cam.dist, dtype=float)[:4]
    return [K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_SHIFT, K[1, 2] + COLMAP_PIXEL_SHIFT, *dist]


def camnet_start(obs: Observations, seed: int = 0):
    """(order, start): camnet's cold start of `obs`, as `camnet.solve.pipeline` computes it."""
    ctx = SolveContext.of(obs)
    return list(ctx.order), cold_start(ctx, seed=seed, max_tracks=150)


def colmap_adjust(obs: Observations, seed: int = 0, solver: AnchorSolver = AnchorSolver()) -> AnchorResult:
    """COLMAP's bundle adjustment of `obs` from camnet's cold start, then the stereo pair's distance as the scale."""
    import pycolmap

    pycolmap.logging.minloglevel = pycolmap.logging.WARNING  # one INFO banner per adjustment otherwise
    order, start = camnet_start(obs, seed)
    rec, kept = _reconstruction(obs, order, start, solver.camera_model)
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    ceres = options.ceres.solver_options
    ceres.function_tolerance = solver.function_tolerance
    ceres.gradient_tolerance = solver.gradient_tolerance
    ceres.max_num_iterations = solver.max_num_iterations
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    if solver.hold_stereo_pair:
        for image_id in (1, 2):
            config.set_constant_rig_from_world_pose(rec.image(image_id).frame_id)
    else:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    for m, i in enumerate(order):
        if rec.exists_camera(m + 1) and _given(obs.cameras[i]):
            config.set_constant_cam_intrinsics(m + 1)
    t0, cpu0 = time.perf_counter(), time.thread_time()
    summary = pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    seconds, cpu_seconds = time.perf_counter() - t0, time.thread_time() - cpu0
    ceres_summary = summary.ceres_summary
    centre = {m: rec.image(m + 1).projection_center() for m in range(2)}
    scale = obs.stereo.baseline_m / np.linalg.norm(centre[1] - centre[0])
    points = np.array([rec.points3D[pid].xyz for pid in sorted(rec.points3D)]) * scale
    focal = {obs.cameras[order[cid - 1]].id: float(rec.cameras[cid].params[0]) for cid in rec.cameras}
    iterations = ceres_summary.num_successful_steps + ceres_summary.num_unsuccessful_steps
    return AnchorResult(obs.track_ids[np.array(kept)], points, focal, seconds, cpu_seconds, iterations,
                        str(ceres_summary.termination_type).split(".")[-1])


def _reconstruction(obs: Observations, order, start, camera_model: str):
    """(COLMAP reconstruction of camnet's start, the track rows it holds a point for)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    image_of = {}
    for m, i in enumerate(order):
        if not start.registered[m]:
            continue
        cam = obs.cameras[i]
        camera = pycolmap.Camera(model=camera_model, width=cam.width, height=cam.height, camera_id=m + 1,
                                 params=_params(cam, float(start.f[m]), camera_model))
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
    return rec, kept
