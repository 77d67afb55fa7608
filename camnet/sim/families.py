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
- The families round a person (``FLOOR_FAMILIES``) may stand it on a floor:
  ``floor_points`` points on a disc about its feet, the true floor in the
  drawn rig's ``floor``.
- ``wide``: the paper's four cameras with 100 degree lenses (k1 -0.28,
  k2 0.09) looking at a scene that fills their images.
- ``fisheye``: the paper's four cameras with fisheye lenses (OpenCV's
  fisheye model, 160 degrees across the image diagonal, 127 across its
  width) in a room whose points surround them to 85 degrees off the axis.

Two families model real scenes camnet has been wrong on (`HARD_FAMILIES`); with
clean simulated tracks camnet is right on both within its sigmas, so what
went wrong there lies in those scenes' real matches (docs/benchmarks.md,
"Rigs unlike the paper's"):

- ``narrow_ring``: 12 inward-looking 1280x1024 cameras with 24 degree lenses
  on a ring of radius 0.2 m round a small object on a table; the pair is two
  neighbours 30 degrees apart (about 0.104 m), their K given.
- ``facade``: one 3072x2048 camera (a 58 degree lens) moved along an 18 m path
  19-31 m in front of a building's face with a few metres of relief; the pair
  is two neighbouring views about 2 m apart, nothing else known.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.camera import Camera, LensModel
from camnet.model.observations import Baseline, Observations
from camnet.model.projection import distort_fisheye, look_at, rotation_exp
from camnet.sim.simulate import HEIGHT, WIDTH, SimRig, TrueFloor, make_rig, observe

FAMILIES = ("ring", "ring_K", "two_heads", "tape_pair", "wide", "fisheye")
HARD_FAMILIES = ("narrow_ring", "facade")
FLOOR_FAMILIES = ("ring", "ring_K", "two_heads", "tape_pair")  # a person on a floor: `floor_points` may draw it
RING_RADIUS_M = 2.0
HEAD_BASELINE_M = 0.12
TAPE_SIGMA_M = 0.002  # a tape measure's 1 sigma over 1.5 m
PERSON_SEMI_AXES_M = (0.25, 0.17)  # x, z of the elliptic cylinder
PERSON_HEIGHT_M = 1.7
FLOOR_CLEAR_M = 0.3  # the floor's points start this far from the person's axis (outside its feet)
FLOOR_RADIUS_M = 1.5  # and end this far: inside the ring, where the cameras across see it
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
NARROW_RING_RADIUS_M = 0.2
NARROW_FOCAL_PX = (WIDTH / 2) / np.tan(np.radians(12.0))  # 24 degrees across the image
NARROW_OBJECT_SEMI_AXES_M = (0.03, 0.035, 0.025)  # x, y, z of an ellipsoid resting on the table
FACADE_SIZE = (3072, 2048)
FACADE_FOCAL_PX = (3072 / 2) / np.tan(np.radians(29.0))  # 58 degrees across the image


@dataclass(frozen=True)
class FamilyRig:
    rig: SimRig
    normals: np.ndarray  # (N, 3) outward unit normals of rig.points, left frame; NaN: seen from everywhere
    given: tuple[str, ...] = ()  # cameras whose K and distortion the observations give, fixed (factory-calibrated)
    floor: TrueFloor | None = None  # None: no floor in the scene's points


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


def _floor_disc(n_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) on the floor the person stands on (y down: at its feet), a disc from just outside the person to
    FLOOR_RADIUS_M about its axis, and their normals (up, -y)."""
    r = np.sqrt(rng.uniform(FLOOR_CLEAR_M**2, FLOOR_RADIUS_M**2, n_points))
    phi = rng.uniform(0.0, 2.0 * np.pi, n_points)
    points = np.column_stack([r * np.cos(phi), np.full(n_points, PERSON_HEIGHT_M / 2), r * np.sin(phi)])
    return points, np.tile([0.0, -1.0, 0.0], (n_points, 1))


def _with_floor(cameras: list[Camera], points: np.ndarray, normals: np.ndarray, n_floor: int,
                seed: int) -> tuple[np.ndarray, np.ndarray, TrueFloor | None]:
    """The person's points and normals with `n_floor` floor points after them (drawn from a generator of their own,
    so that the rest of the rig's draws stay as they were), and the floor in cameras[0]'s frame (None: none)."""
    if n_floor == 0:
        return points, normals, None
    on_floor, floor_normals = _floor_disc(n_floor, np.random.default_rng(seed + 2))
    R0 = cameras[0].R
    truth = TrueFloor(R0 @ np.array([0.0, -1.0, 0.0]), float(PERSON_HEIGHT_M / 2 - cameras[0].centre[1]))
    return np.concatenate([points, on_floor]), np.concatenate([normals, floor_normals]), truth


def _in_left_frame(cameras: list[Camera], points: np.ndarray, normals: np.ndarray) -> tuple:
    """Cameras, points and normals re-expressed in cameras[0]'s frame."""
    R0, t0 = cameras[0].R, cameras[0].t
    moved = [replace(c, R=c.R @ R0.T, t=c.t - c.R @ R0.T @ t0) for c in cameras]
    return moved, points @ R0.T + t0, normals @ R0.T


def ring(*, seed: int = 0, n_points: int = 600, heads: int = 1, head_yaw_deg: float = 0.0,
         floor_points: int = 0) -> FamilyRig:
    """8 ring positions; `heads` of them (1 or 2, opposite) hold a parallel head, the rest one camera.

    head_yaw_deg: every head's right camera turned by this about its own y axis (a head toed in, not
    parallel: positive turns it towards the left camera's side). floor_points: as many points on the floor the
    person stands on (after the person's), the floor in the FamilyRig's `floor`.
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
    points, normals, floor = _with_floor(cameras, points, normals, floor_points, seed)
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    return FamilyRig(SimRig(cameras, HEAD_BASELINE_M, points, baselines=known), normals, floor=floor)


def tape_pair(*, seed: int = 0, n_points: int = 600, floor_points: int = 0) -> FamilyRig:
    """8 single cameras on the ring; the pair is two neighbours 45 degrees apart, their distance taped.

    floor_points: as `ring`'s."""
    rng = np.random.default_rng(seed)
    angles = np.radians(np.arange(8) * 45.0 + rng.uniform(-5, 5, 8))
    cameras = [_ring_camera(f"ring{slot}", angles[slot], rng) for slot in range(8)]
    points, normals = _person(n_points, rng)
    points, normals, floor = _with_floor(cameras, points, normals, floor_points, seed)
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    distance_m = float(np.linalg.norm(cameras[1].centre - cameras[0].centre))
    # The tape's reading: off by a draw of its sigma (a generator of its own keeps the rig's draws as they were).
    taped_m = distance_m + np.random.default_rng(seed + 1).normal(scale=TAPE_SIGMA_M)
    return FamilyRig(SimRig(cameras, taped_m, points, stereo_sigma_m=TAPE_SIGMA_M), normals, floor=floor)


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


def narrow_ring(*, seed: int = 0, n_points: int = 800) -> FamilyRig:
    """12 cameras 30 degrees apart on a ring of radius 0.2 m, 24 degree lenses, round a small object on a
    table (points on the object and on the table about it); the pair is two neighbours, their K given."""
    rng = np.random.default_rng(seed)
    angles = np.radians(np.arange(12) * 30.0 + rng.uniform(-3, 3, 12))
    a, b, c = NARROW_OBJECT_SEMI_AXES_M
    cameras = []
    for k, angle in enumerate(angles):
        centre = NARROW_RING_RADIUS_M * np.array([np.sin(angle), 0.0, -np.cos(angle)])
        centre[1] = -0.06 + rng.uniform(-0.01, 0.01)  # y down: a little above the object, looking down at it
        R, t = look_at(centre, rng.normal(scale=0.004, size=3))
        cameras.append(Camera(f"cam{k:02d}", WIDTH, HEIGHT, _K(NARROW_FOCAL_PX, rng), np.zeros(5), R, t))
    n_object = n_points * 3 // 4
    u = rng.normal(size=(n_object, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    on_object = u * np.array([a, b, c])
    object_normals = u / np.array([a, b, c])
    # The table: a disc about the object's foot, its normal up (-y), its points outside the object.
    r = np.sqrt(rng.uniform((1.2 * a) ** 2, 0.07**2, n_points - n_object))
    phi = rng.uniform(0.0, 2.0 * np.pi, n_points - n_object)
    on_table = np.column_stack([r * np.cos(phi), np.full(len(r), b), r * np.sin(phi)])
    table_normals = np.tile([0.0, -1.0, 0.0], (len(r), 1))
    points = np.concatenate([on_object, on_table])
    normals = np.concatenate([object_normals / np.linalg.norm(object_normals, axis=1, keepdims=True), table_normals])
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    distance_m = float(np.linalg.norm(cameras[1].centre - cameras[0].centre))
    return FamilyRig(SimRig(cameras, distance_m, points), normals, given=(cameras[0].id, cameras[1].id))


def facade(*, seed: int = 0, n_points: int = 1500) -> FamilyRig:
    """10 views of one 3072x2048 camera along an 18 m path 19-31 m in front of a 24 x 14 m face with up to
    3 m of relief (a recessed entrance, pillars), each view turned towards the face's middle; the pair is
    two neighbouring views, nothing else known."""
    rng = np.random.default_rng(seed)
    width, height = FACADE_SIZE
    K = np.array([[FACADE_FOCAL_PX, 0.0, (width - 1) / 2], [0.0, FACADE_FOCAL_PX, (height - 1) / 2], [0.0, 0.0, 1.0]])
    # The face: the plane z = 0 seen from z < 0; relief: a recess behind its middle, pillars in front.
    x = rng.uniform(-12.0, 12.0, n_points)
    y = rng.uniform(-12.0, 2.0, n_points)  # y down: from the ground (2 m below the cameras) up 14 m
    z = np.where(np.abs(x) < 3.0, 3.0, 0.0) * (y > -4.0)  # the entrance, 3 m deep and 6 m tall
    pillar = (np.abs(np.abs(x) - 6.0) < 0.6) & (rng.random(n_points) < 0.8)
    z = np.where(pillar, -1.0, z) + rng.normal(scale=0.05, size=n_points)
    points = np.column_stack([x, y, z])
    cameras = []
    alongs = np.linspace(-9.0, 9.0, 10) + rng.uniform(-0.2, 0.2, 10)
    distances = np.linspace(22.0, 28.0, 10) + rng.uniform(-0.2, 0.2, 10)  # walking away from the face a little
    for k, (along, distance) in enumerate(zip(alongs, distances, strict=True)):
        centre = np.array([along, rng.uniform(-0.3, 0.3), -distance])
        R, t = look_at(centre, np.array([0.0, -5.0, 0.0]) + rng.normal(scale=0.5, size=3))
        cameras.append(Camera(f"view{k:02d}", width, height, K.copy(), np.zeros(5), R, t))
    normals = np.full((n_points, 3), np.nan)
    cameras, points, normals = _in_left_frame(cameras, points, normals)
    distance_m = float(np.linalg.norm(cameras[1].centre - cameras[0].centre))
    return FamilyRig(SimRig(cameras, distance_m, points), normals)


def family(name: str, *, seed: int = 0, head_yaw_deg: float = 0.0, floor_points: int = 0) -> FamilyRig:
    """The family `name` (one of FAMILIES) drawn with `seed`; head_yaw_deg: as `ring`'s, for the ring families;
    floor_points: as `ring`'s, for the families round a person (FLOOR_FAMILIES)."""
    if head_yaw_deg and name not in ("ring", "ring_K", "two_heads"):
        raise ValueError(f"head_yaw_deg: family {name!r} has no parallel head; the ring families have")
    if floor_points and name not in FLOOR_FAMILIES:
        raise ValueError(f"floor_points: family {name!r} has no floor; the families round a person have: "
                         f"{', '.join(FLOOR_FAMILIES)}")
    if name == "ring":
        return ring(seed=seed, head_yaw_deg=head_yaw_deg, floor_points=floor_points)
    if name == "ring_K":
        drawn = ring(seed=seed, head_yaw_deg=head_yaw_deg, floor_points=floor_points)
        return replace(drawn, given=tuple(c.id for c in drawn.rig.cameras[:2]))
    if name == "two_heads":
        return ring(seed=seed, heads=2, head_yaw_deg=head_yaw_deg, floor_points=floor_points)
    if name == "tape_pair":
        return tape_pair(seed=seed, floor_points=floor_points)
    if name == "wide":
        return wide(seed=seed)
    if name == "fisheye":
        return fisheye(seed=seed)
    if name == "narrow_ring":
        return narrow_ring(seed=seed)
    if name == "facade":
        return facade(seed=seed)
    raise ValueError(f"unknown family {name!r}; expected one of {FAMILIES + HARD_FAMILIES}")


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
