"""What a rig file says of a simulation: a simulated camera (`SimConfig`) and the scene (`SceneConfig`).

Parsed and validated by `camnet.io.rig`; used by the sim driver and
`camnet.sim.scene`. World frame = the left stereo camera's (x right, y down,
z forward), lengths in metres, pixels as in `camnet.model.projection`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.camera import Camera, LensModel
from camnet.model.projection import full_dist, look_at
from camnet.sim.clock import SimClock


@dataclass(frozen=True)
class SimConfig:
    """A simulated camera: ideal pinhole + OpenCV distortion, pose from its centre and target.

    `dist` is in `model`'s order (pinhole [k1, k2, p1, p2, k3], fisheye [k1, k2, k3, k4]).
    With `look_at_m` absent the camera has R = I (axes along the world's).
    `noise_sigma_dn` is the std of additive Gaussian sensor noise in digital numbers.
    `clock`: when and how it exposes and stamps its frames (camnet.sim.clock); None: triggered with
    every other simulated camera on one common clock, stamping the exposure instant.
    """

    width: int
    height: int
    encoding: str
    fps: float
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    dist: tuple[float, ...]
    centre_m: tuple[float, float, float]
    look_at_m: tuple[float, float, float] | None
    up: tuple[float, float, float]
    noise_sigma_dn: float
    model: LensModel = LensModel.PINHOLE
    clock: SimClock | None = None

    def camera(self, camera_id: str) -> Camera:
        """The ground-truth camnet.model.camera.Camera of this simulated camera."""
        K = np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0, 0, 1.0]])
        centre = np.array(self.centre_m, dtype=float)
        if self.look_at_m is None:
            R = np.eye(3)
            t = -centre
        else:
            R, t = look_at(centre, np.array(self.look_at_m), np.array(self.up))
        dist = full_dist(self.dist, self.model.dist_size)
        return Camera(id=camera_id, width=self.width, height=self.height, K=K, dist=dist, R=R, t=t, model=self.model)


@dataclass(frozen=True)
class SceneConfig:
    """The simulated scene: a textured box on a floor before a textured wall (metres).

    World frame = the left camera's: x right, y down, z forward. The box
    turns about the vertical axis through its centre at `box_rotation_deg_per_s`.
    `object` "person" puts a person-sized upright elliptic cylinder of extents
    `box_size_m` (width, height, depth) in the box's place, turning the same
    way, and leaves the wall out: cameras stand all around it.
    """

    seed: int
    box_centre_m: tuple[float, float, float]
    box_size_m: tuple[float, float, float]
    box_rotation_deg_per_s: float
    wall_z_m: float
    wall_x_range_m: tuple[float, float]
    wall_y_range_m: tuple[float, float]
    floor_y_m: float
    floor_z_range_m: tuple[float, float]
    object: str = "box"  # "box" or "person"
