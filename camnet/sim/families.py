"""Seeded simulated rigs unlike the paper's: what telepresence rigs really look like.

Every family returns a `SimRig` in the scale pair's left camera's frame
(metres; ``x_cam = R X + t``; camera axes x right, y down, z forward), the
first two cameras being the pair with the known distance, and the outward
surface normal of every scene point, so that a camera sees only the side of
the scene that faces it (`observe(..., normals=)`).

- ``ring``: 8 cameras on a full ring of radius 2 m around a person-sized
  elliptic cylinder (0.5 x 1.7 x 0.34 m), a parallel head (0.12 m) taking the
  place of one of them, so the cameras opposite see none of the pair's points.
- ``ring_K``: the ring with its head factory-calibrated: the observations
  give both head cameras' K and distortion (the truth) and fix them.
- ``two_heads``: the ring with a second parallel head opposite the first, its
  baseline a further known distance.
- ``tape_pair``: the ring with no head: two single cameras 45 degrees apart
  (1.53 m) are the pair, their distance measured with a tape (sigma 2 mm).
- ``wide``: the paper's four cameras with 100 degree lenses (k1 -0.28,
  k2 0.09) looking at a scene that fills their images.
- ``fisheye``: the paper's four cameras with fisheye lenses (OpenCV's
  fisheye model, 160 degrees across the image diagonal, 127 across its
  width) in a room whose points surround them to 85 degrees off the axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.camera import Camera, LensModel
from camnet.model.observations import Baseline, Observations
from camnet.model.projection import distort_fisheye, look_at, rotation_exp
from camnet.sim.simulate import HEIGHT, WIDTH, SimRig, make_rig, observe

FAMILIES = ("ring", "ring_K", "two_heads", "tape_pair", "wide", "fisheye")
RING_RADIUS_M = 2.0
HEAD_BASELINE_M = 0.12
TAPE_SIGMA_M = 0.002  # a tape measure's 1 sigma over 1.5 m
PERSON_SEMI_AXES_M = (0.25, 0.17)  # x, z of the elliptic cylinder
PERSON_HEIGHT_M = 1.7
RING_FOCAL_PX = 950.0  # a 1.7 m person fills 1024 rows at 2 m
WIDE_FOCAL_PX = (WIDTH / 2) / np.tan(np.radians(50.0))  # 100 degrees across the image
WIDE_DIST = (-0.28, 0.09)
FISHEYE_DIST = (0.05, -0.01, 0.002, -0.0005)  # k1..k4, as a real fisheye's
# Within OpenCV's fisheye inverse (cv2.fisheye.undistortPoints), which ends at a distorted angle of 90 degrees.
FISHEYE_DIAGONAL_DEG = 160.0
# The focal length that puts a ray FISHEYE_DIAGONAL_DEG / 2 off the axis at the image's corner.
FISHEYE_FOCAL_PX = float(
    np.hypot(WIDTH, HEIGHT) / 2 / distort_fisheye(np.array([[np.tan(np.radians(FISHEYE_DIAGONAL_DEG / 2)), 0.0]]),
                                                  np.array(FISHEYE_DIST))[0, 0]
)
FISHEYE_MAX_ANGLE_DEG = 85.0  # the room's points lie within this of the left camera's axis (beyond the corners)


@dataclass(frozen=True)
class FamilyRig:
    rig: SimRig
    normals: np.ndarray  # (N, 3) outward unit normals of rig.points, left frame; NaN: seen from everywhere
    given: tuple[str, ...] = ()  # cameras whose K and distortion the observations give, fixed (factory-calibrated)


def _K(f: float, rng: np.random.Generator) -> np.ndarray:
    f = f * rng.uniform(0.95, 1.05)
    return np.array([[f, 0.0, (WIDTH - 1) / 2], [0.0, f, (HEIGHT - 1) / 2], [0.0, 0.0, 1.0]])


def _person(n_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) on an upright elliptic cylinder about the origin, y down, and their normals."""
    a, c = PERSON_SEMI_AXES_M
    phi = rng.uniform(0.0, 2.0 * np.pi, n_points)
    y = rng.uniform(-PERSON_HEIGHT_M / 2, PERSON_HEIGHT_M / 2, n_points)
    points = np.stack([a * np.cos(phi), y, c * np.sin(phi)], axis=1)
    normals = np.stack([np.cos(phi) / a, np.zeros(n_points), np.sin(phi) / c], axis=1)
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _ring_camera(name: str, angle: float, rng: np.random.Generator) -> Camera:
    """A camera on the ring at `angle` (rad), about chest height, looking at the person's middle."""
    centre = RING_RADIUS_M * np.array([np.sin(angle), 0.0, -np.cos(angle)])
    centre[1] = -0.25 + rng.uniform(-0.1, 0.1)  # y down: above the middle
    R, t = look_at(centre, rng.normal(scale=0.05, size=3))
    return Camera(name, WIDTH, HEIGHT, _K(RING_FOCAL_PX, rng), np.zeros(5), R, t)


def _in_left_frame(cameras: list[Camera], points: np.ndarray, normals: np.ndarray) -> tuple:
    """Cameras, points and normals re-expressed in cameras[0]'s frame."""
    R0, t0 = cameras[0].R, cameras[0].t
    moved = [replace(c, R=c.R @ R0.T, t=c.t - c.R @ R0.T @ t0) for c in cameras]
    return moved, points @ R0.T + t0, normals @ R0.T


def ring(*, seed: int = 0, n_points: int = 600, heads: int = 1, head_yaw_deg: float = 0.0) -> FamilyRig:
    """8 ring positions; `heads` of them (1 or 2, opposite) hold a parallel head, the rest one camera.

    head_yaw_deg: every head's right camera turned by this about its own y axis (a head toed in, not
    parallel: positive turns it towards the left camera's side).
    """
    rng = np.random.default_rng(seed)
    angles = np.radians(np.arange(8) * 45.0 + rng.uniform(-5, 5, 8))
    cameras: list[Camera] = []
    head_slots = (0,) if heads == 1 else (0, 4)
    for k, slot in enumerate(head_slots):
        left = _ring_camera(f"head{k}_left", angles[slot], rng)
        right_centre = left.centre + HEAD_BASELINE_M * left.R[0]
        R_right = rotation_exp(np.array([0.0, np.radians(head_yaw_deg), 0.0])) @ left.R
        right = Camera(f"head{k}_right", WIDTH, HEIGHT, _K(RING_FOCAL_PX, rng), np.zeros(5), R_right,
                       -R_right @ right_centre)
        cameras += [left, right]
    # Every head after the first is a further known distance.
    known = tuple(Baseline(f"head{k}_left", f"head{k}_right", HEAD_BASELINE_M) for k in range(1, len(head_slots)))
    for slot in range(8):
        if slot not in head_slots:
            cameras.append(_ring_camera(f"ring{slot}", angles[slot], rng))
    points, normals = _person(n_points, rng)
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    return FamilyRig(SimRig(cameras, HEAD_BASELINE_M, points, baselines=known), normals)


def tape_pair(*, seed: int = 0, n_points: int = 600) -> FamilyRig:
    """8 single cameras on the ring; the pair is two neighbours 45 degrees apart, their distance taped."""
    rng = np.random.default_rng(seed)
    angles = np.radians(np.arange(8) * 45.0 + rng.uniform(-5, 5, 8))
    cameras = [_ring_camera(f"ring{slot}", angles[slot], rng) for slot in range(8)]
    points, normals = _person(n_points, rng)
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    distance_m = float(np.linalg.norm(cameras[1].centre - cameras[0].centre))
    # The tape's reading: off by a draw of its sigma (a generator of its own keeps the rig's draws as they were).
    taped_m = distance_m + np.random.default_rng(seed + 1).normal(scale=TAPE_SIGMA_M)
    return FamilyRig(SimRig(cameras, taped_m, points, stereo_sigma_m=TAPE_SIGMA_M), normals)


def wide(*, seed: int = 0, n_points: int = 400) -> FamilyRig:
    """The paper's rig with 100 degree lenses, the scene spread over their whole images."""
    rig = make_rig(seed=seed, n_points=n_points, k1=WIDE_DIST[0], k2=WIDE_DIST[1])
    rng = np.random.default_rng(seed + 1)
    cameras = [Camera(c.id, c.width, c.height, _K(WIDE_FOCAL_PX, rng), c.dist, c.R, c.t) for c in rig.cameras]
    # A room-sized scene at the object's distance: 1.8 x 1.5 m across at 0.65 m, 0.5 to 1.2 m deep.
    z = rng.uniform(0.5, 1.2, n_points)
    xy = rng.uniform(-0.5, 0.5, (n_points, 2)) * np.array([1.8, 1.5]) * (z / 0.65)[:, None]
    points = np.column_stack([xy[:, 0] + 0.0625, xy[:, 1], z])
    return FamilyRig(SimRig(cameras, rig.baseline_m, points), np.full((n_points, 3), np.nan))


def fisheye(*, seed: int = 0, n_points: int = 600) -> FamilyRig:
    """The paper's rig with fisheye lenses in a room: points 0.8 to 3 m away, up to 85 degrees off the axis."""
    rig = make_rig(seed=seed)
    rng = np.random.default_rng(seed + 1)
    cameras = [
        replace(c, K=_K(FISHEYE_FOCAL_PX, rng), dist=np.array(FISHEYE_DIST), model=LensModel.FISHEYE)
        for c in rig.cameras
    ]
    # Directions uniform on the cap within FISHEYE_MAX_ANGLE_DEG of the optical axis.
    cos_theta = rng.uniform(np.cos(np.radians(FISHEYE_MAX_ANGLE_DEG)), 1.0, n_points)
    phi = rng.uniform(0.0, 2.0 * np.pi, n_points)
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    rays = np.column_stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta])
    points = rays * rng.uniform(0.8, 3.0, n_points)[:, None]
    return FamilyRig(SimRig(cameras, rig.baseline_m, points), np.full((n_points, 3), np.nan))


def family(name: str, *, seed: int = 0, head_yaw_deg: float = 0.0) -> FamilyRig:
    """The family `name` (one of FAMILIES) drawn with `seed`; head_yaw_deg: as `ring`'s, for the ring families."""
    if head_yaw_deg and name not in ("ring", "ring_K", "two_heads"):
        raise ValueError(f"head_yaw_deg: family {name!r} has no parallel head; the ring families have")
    if name == "ring":
        return ring(seed=seed, head_yaw_deg=head_yaw_deg)
    if name == "ring_K":
        drawn = ring(seed=seed, head_yaw_deg=head_yaw_deg)
        return replace(drawn, given=tuple(c.id for c in drawn.rig.cameras[:2]))
    if name == "two_heads":
        return ring(seed=seed, heads=2, head_yaw_deg=head_yaw_deg)
    if name == "tape_pair":
        return tape_pair(seed=seed)
    if name == "wide":
        return wide(seed=seed)
    if name == "fisheye":
        return fisheye(seed=seed)
    raise ValueError(f"unknown family {name!r}; expected one of {FAMILIES}")


def observe_family(drawn: FamilyRig, *, noise_px: float = 0.5, seed: int = 0) -> Observations:
    """The observations of a drawn family (`observe` with its normals), the given cameras' K and dist fixed."""
    obs = observe(drawn.rig, noise_px=noise_px, seed=seed, normals=drawn.normals).observations
    truth = {c.id: c for c in drawn.rig.cameras}
    cameras = tuple(
        replace(c, K=truth[c.id].K.copy(), dist=truth[c.id].dist.copy(), fixed=frozenset({"K", "dist"}))
        if c.id in drawn.given else c
        for c in obs.cameras
    )
    return replace(obs, cameras=cameras)
