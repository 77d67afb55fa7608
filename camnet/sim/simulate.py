"""Seeded synthetic camera networks with known ground truth.

The default is the paper's rig (Sec. IV): a parallel stereo pair 0.125 m
apart and two monocular cameras, 1280x1024, looking at an object about
0.10 x 0.17 x 0.08 m at 0.65 m. Ring rigs add cameras on an arc around the
object. Observations get Gaussian pixel noise, optional gross outliers and
partial visibility. Everything is in the left camera's frame, in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.camera import Camera, CameraInfo
from camnet.model.observations import Baseline, Observations, Stereo
from camnet.model.projection import look_at, rotation_exp

WIDTH, HEIGHT = 1280, 1024
OBJECT_CENTRE = np.array([0.0625, 0.0, 0.65])
OBJECT_SIZE = np.array([0.10, 0.17, 0.08])
PAPER_BASELINE_M = 0.125


@dataclass(frozen=True)
class SimRig:
    cameras: list[Camera]  # cameras[0] is the left stereo camera, cameras[1] the right
    baseline_m: float
    points: np.ndarray  # (N, 3) metres
    baselines: tuple[Baseline, ...] = ()  # further known distances the observations carry
    stereo_sigma_m: float = 0.0  # 1 sigma of baseline_m (a taped distance); 0: exact

    @property
    def stereo(self) -> Stereo:
        return Stereo(self.cameras[0].id, self.cameras[1].id, self.baseline_m, sigma_m=self.stereo_sigma_m)


def _K(f: float, pp_offset: np.ndarray) -> np.ndarray:
    cx, cy = (WIDTH - 1) / 2 + pp_offset[0], (HEIGHT - 1) / 2 + pp_offset[1]
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def make_rig(
    *,
    n_cameras: int = 4,
    n_points: int = 57,
    seed: int = 0,
    pp_offset_px: float = 0.0,
    k1: float = 0.0,
    k2: float = 0.0,
    stereo_rotation_deg: float = 0.0,
    depth_range_m: tuple[float, float] | None = None,
) -> SimRig:
    """A network: the paper's four cameras, and for n_cameras > 4 more on an arc.

    pp_offset_px: principal points drawn uniformly within this many pixels of
    the image centre (per axis). stereo_rotation_deg: the right stereo
    camera's rotation angle about a random axis. depth_range_m: spread the
    points over this range of depths instead of the object's 0.08 m.
    """
    rng = np.random.default_rng(seed)
    half = OBJECT_SIZE / 2
    points = OBJECT_CENTRE + rng.uniform(-half, half, size=(n_points, 3))
    if depth_range_m is not None:
        z = rng.uniform(*depth_range_m, size=n_points)
        points = points * np.array([1.0, 1.0, 0.0]) * (z / OBJECT_CENTRE[2])[:, None]
        points[:, 2] = z

    def pp() -> np.ndarray:
        return rng.uniform(-pp_offset_px, pp_offset_px, size=2)

    dist = np.array([k1, k2, 0.0, 0.0, 0.0])
    axis = rng.normal(size=3)
    R_right = rotation_exp(np.deg2rad(stereo_rotation_deg) * axis / np.linalg.norm(axis))
    C_right = np.array([PAPER_BASELINE_M, 0.0, 0.0])
    cameras = [
        Camera("left", WIDTH, HEIGHT, _K(1500.0, pp()), dist),
        Camera("right", WIDTH, HEIGHT, _K(1500.0, pp()), dist, R_right, -R_right @ C_right),
    ]
    monos = [("mono_a", (-0.30, 0.0, 0.05), 1300.0), ("mono_b", (0.425, 0.0, 0.05), 1400.0)]
    extra = n_cameras - 4
    for i in range(extra):
        # An arc around the object from -75 to +75 degrees, alternating heights.
        angle = np.deg2rad(-75.0 + 150.0 * (i + 0.5) / extra)
        radius = rng.uniform(0.55, 0.75)
        height = (0.12 if i % 2 else -0.12) + rng.uniform(-0.03, 0.03)
        centre = OBJECT_CENTRE + radius * np.array([np.sin(angle), 0.0, -np.cos(angle)])
        centre[1] += height
        monos.append((f"mono_{i + 2:02d}", tuple(centre), float(rng.uniform(1100, 1700))))
    for name, centre, f in monos[: n_cameras - 2]:
        R, t = look_at(np.array(centre), OBJECT_CENTRE + rng.normal(scale=0.01, size=3))
        cameras.append(Camera(name, WIDTH, HEIGHT, _K(f, pp()), dist, R, t))
    return SimRig(cameras, PAPER_BASELINE_M, points)


@dataclass(frozen=True)
class TrueFloor:
    """The floor of a simulated rig in its left camera's frame: the points X with ``up_left . X = -left_height_m``."""

    up_left: np.ndarray  # (3,) unit, against gravity
    left_height_m: float  # the left camera centre's height above the floor


def with_floor(rig: SimRig, *, n_points: int = 250, height_m: float = 0.45, pitch_deg: float = 0.0,
               roll_deg: float = 0.0, seed: int = 0) -> tuple[SimRig, TrueFloor]:
    """The rig with `n_points` points on a floor `height_m` below its left camera, the camera pitched down by
    pitch_deg and rolled by roll_deg against gravity, and that floor.

    The points cover 0.6 to 2 m ahead of the left camera along the floor and 0.7 m to either side (what its
    image shows of a floor at that height and pitch), drawn from a generator of their own.
    """
    # Gravity's up in the left camera's frame: a camera pitched down sees up tilted towards its own -z.
    turn = rotation_exp(np.radians([pitch_deg, 0.0, roll_deg]))
    up = turn @ np.array([0.0, -1.0, 0.0])
    ahead = turn @ np.array([0.0, 0.0, 1.0])
    side = np.cross(up, ahead)
    rng = np.random.default_rng(seed + 104729)
    points = (-height_m * up + np.outer(rng.uniform(0.6, 2.0, n_points), ahead)
              + np.outer(rng.uniform(-0.7, 0.7, n_points), side))
    return replace(rig, points=np.concatenate([rig.points, points])), TrueFloor(up, height_m)


def rolled(rig: SimRig, max_deg: float, *, seed: int = 0) -> SimRig:
    """The rig with every camera but the stereo pair turned about its own optical axis, in place, by a seeded
    angle within max_deg either way (cameras on a rig are upright only roughly)."""
    rng = np.random.default_rng(seed)
    cameras = list(rig.cameras[:2])
    for cam in rig.cameras[2:]:
        R = rotation_exp(np.array([0.0, 0.0, np.radians(rng.uniform(-max_deg, max_deg))])) @ cam.R
        cameras.append(replace(cam, R=R, t=-R @ cam.centre))
    return replace(rig, cameras=cameras)


def with_head(rig: SimRig, camera_id: str, *, baseline_m: float = PAPER_BASELINE_M, sigma_m: float = 0.0) -> SimRig:
    """The rig with a second parallel head: camera `camera_id` its left camera, a new one
    (``<camera_id>_right``, the same K and orientation) `baseline_m` to its right, and their
    distance among the rig's known ones (sigma_m: its 1 sigma, 0: exact)."""
    left = next(c for c in rig.cameras if c.id == camera_id)
    centre = left.centre + baseline_m * left.R[0]  # the left camera's x axis, in the world
    right = replace(left, id=f"{camera_id}_right", t=-left.R @ centre)
    known = Baseline(left.id, right.id, baseline_m, sigma_m)
    return replace(rig, cameras=[*rig.cameras, right], baselines=(*rig.baselines, known))


def move_camera(rig: SimRig, camera_id: str, *, shift_m: float, angle_deg: float, seed: int = 0) -> SimRig:
    """The rig with one camera bumped: its centre shifted by shift_m and its
    orientation turned by angle_deg, both in seeded random directions."""
    rng = np.random.default_rng(seed)
    cameras = []
    for cam in rig.cameras:
        if cam.id == camera_id:
            d, w = rng.normal(size=3), rng.normal(size=3)
            R = rotation_exp(np.deg2rad(angle_deg) * w / np.linalg.norm(w)) @ cam.R
            C = cam.centre + shift_m * d / np.linalg.norm(d)
            cam = replace(cam, R=R, t=-R @ C)
        cameras.append(cam)
    return replace(rig, cameras=cameras)


@dataclass(frozen=True)
class SimObservations:
    observations: Observations
    outlier_obs: np.ndarray  # (n,) bool: observation replaced by a random pixel
    noise_px: float


def observe(
    rig: SimRig,
    *,
    noise_px: float = 0.5,
    seed: int = 0,
    outlier_fraction: float = 0.0,
    visibility: float = 1.0,
    with_intrinsics: bool = False,
    normals: np.ndarray | None = None,
) -> SimObservations:
    """Project the rig's points with Gaussian noise (sigma px per coordinate).

    visibility: the share of tracks each non-stereo camera sees (the stereo
    cameras see every point). outlier_fraction: the share of tracks one of
    whose observations is replaced by a uniformly random pixel.
    with_intrinsics: include each camera's true K and distortion (not fixed);
    each camera's lens model is always given.
    normals (N, 3): outward surface normals of the points (NaN rows: seen
    from everywhere); a camera sees a point only from the side it faces.
    """
    rng = np.random.default_rng(seed + 7919)
    n_points = len(rig.points)
    cam_index, track_index, uv = [], [], []
    for m, cam in enumerate(rig.cameras):
        pix = cam.project(rig.points)
        seen = np.all(np.isfinite(pix), axis=1)
        seen &= (pix[:, 0] >= 0) & (pix[:, 0] <= cam.width - 1)
        seen &= (pix[:, 1] >= 0) & (pix[:, 1] <= cam.height - 1)
        if m >= 2:
            seen &= rng.random(n_points) < visibility
        if normals is not None:
            facing = np.einsum("ij,ij->i", normals, cam.centre - rig.points)
            seen &= ~(facing <= 0)  # NaN normals: seen from everywhere
        idx = np.flatnonzero(seen)
        cam_index.append(np.full(idx.size, m))
        track_index.append(idx)
        uv.append(pix[idx] + rng.normal(scale=noise_px, size=(idx.size, 2)))
    cam_index = np.concatenate(cam_index)
    track_index = np.concatenate(track_index)
    uv = np.concatenate(uv)
    order = np.lexsort((cam_index, track_index))
    cam_index, track_index, uv = cam_index[order], track_index[order], uv[order]

    outlier = np.zeros(len(uv), dtype=bool)
    seen_tracks = np.unique(track_index)  # a point no camera sees has no observation to spoil
    n_bad = min(int(round(outlier_fraction * n_points)), len(seen_tracks))
    bad_tracks = rng.choice(seen_tracks, size=n_bad, replace=False)
    for trk in bad_tracks:
        k = rng.choice(np.flatnonzero(track_index == trk))
        cam = rig.cameras[cam_index[k]]
        uv[k] = rng.uniform([0, 0], [cam.width - 1, cam.height - 1])
        outlier[k] = True

    cameras = tuple(
        CameraInfo(c.id, c.width, c.height, c.K.copy(), c.dist.copy(), model=c.model)
        if with_intrinsics
        else CameraInfo(c.id, c.width, c.height, model=c.model)
        for c in rig.cameras
    )
    obs = Observations(
        cameras=cameras,
        stereo=rig.stereo,
        track_ids=np.arange(n_points, dtype=np.int64),
        cam_index=cam_index,
        track_index=track_index,
        uv=uv,
        baselines=rig.baselines,
    )
    return SimObservations(obs, outlier, noise_px)
