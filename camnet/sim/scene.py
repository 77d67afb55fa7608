"""The simulated scene of a rig file: textured box (or person), wall and floor as render.Quads.

Textures are procedural and seeded (multi-scale value noise plus random
shapes), so every run of a rig sees the same feature-rich scene. Texel sizes
are 0.5 mm on the box, 1 mm on the person and 1.5 mm on the wall and floor,
close to the pixel footprint of the cameras meant to see them, to limit aliasing.

The person (scene `object: person`) is an upright elliptic cylinder of
narrow flat strips, each a Quad with its outward normal, so that culling
back faces draws the convex surface with no depth buffer; one texture is
cut into the strips, so the surface shows no seam between them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from camnet.sim.config import SceneConfig
from camnet.sim.render import Quad

BOX_TEXEL_M = 0.0005
PERSON_TEXEL_M = 0.001  # ring cameras 2 m away see about 2 mm per pixel
BACKGROUND_TEXEL_M = 0.0015
PERSON_STRIPS = 72  # 5 degrees each: 1.7 mm at most between a strip and the ellipse it cuts


def procedural_texture(width_px: int, height_px: int, rng: np.random.Generator) -> np.ndarray:
    """A (height, width) uint8 texture rich in corners and blobs at many scales."""
    acc = np.zeros((height_px, width_px), dtype=np.float32)
    for cells in (4, 9, 20, 45, 100):
        grid = rng.random((max(2, cells * height_px // max(width_px, 1)), cells), dtype=np.float32)
        acc += cv2.resize(grid, (width_px, height_px), interpolation=cv2.INTER_CUBIC) / cells**0.3
    acc = (acc - acc.min()) / max(float(np.ptp(acc)), 1e-6)
    image = (40 + 170 * acc).astype(np.uint8)
    max_size = min(60, max(4, max(width_px, height_px) // 8))
    for _ in range(int(width_px * height_px / 500) + 10):
        colour = int(rng.integers(0, 256))
        x, y = int(rng.integers(width_px)), int(rng.integers(height_px))
        # Log-uniform sizes: as many small corners as large blobs.
        size = int(math.exp(rng.uniform(math.log(2), math.log(max_size))))
        shape = rng.integers(3)
        if shape == 0:
            cv2.circle(image, (x, y), size, colour, -1, cv2.LINE_AA)
        elif shape == 1:
            cv2.rectangle(image, (x, y), (x + size, y + int(rng.integers(2, size + 3))), colour, -1)
        else:
            end = (x + int(rng.integers(-size, size + 1)), y + int(rng.integers(-size, size + 1)))
            cv2.line(image, (x, y), end, colour, int(rng.integers(1, 3)), cv2.LINE_AA)
    # A light blur keeps the texture band-limited: no shimmering when it is minified.
    return cv2.GaussianBlur(image, (0, 0), 0.8)


def _texture_for(u: np.ndarray, v: np.ndarray, texel_m: float, rng) -> np.ndarray:
    w = max(8, int(round(np.linalg.norm(u) / texel_m)))
    h = max(8, int(round(np.linalg.norm(v) / texel_m)))
    return procedural_texture(w, h, rng)


def _person_faces(size: np.ndarray, rng) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Strips (p0, u, v, texture) of an upright elliptic cylinder about the origin, normals u x v outwards.

    `size`: width (x), height (y, down) and depth (z) in metres. The strips'
    corners lie on the ellipse; texture columns run once around it.
    """
    a, height, c = size[0] / 2, size[1], size[2] / 2
    phi = np.linspace(0.0, 2.0 * np.pi, PERSON_STRIPS + 1)
    rim = np.stack([a * np.cos(phi), np.full_like(phi, -height / 2), c * np.sin(phi)], axis=1)
    chords = np.diff(rim, axis=0)
    widths_px = np.maximum(1, np.round(np.linalg.norm(chords, axis=1) / PERSON_TEXEL_M)).astype(int)
    texture = procedural_texture(int(widths_px.sum()), int(round(height / PERSON_TEXEL_M)), rng)
    edges = np.concatenate([[0], np.cumsum(widths_px)])
    v = np.array([0.0, height, 0.0])
    faces = []
    for k in range(PERSON_STRIPS):
        # Walking the rim backwards makes u x v point away from the axis (y is down).
        p0, u = rim[k + 1], -chords[k]
        strip = np.ascontiguousarray(texture[:, edges[-1] - edges[k + 1]:edges[-1] - edges[k]])
        faces.append((p0, u, v, strip))
    return faces


def _rot_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class Scene:
    """The static background quads and the box, whose pose depends on time."""

    def __init__(self, config: SceneConfig) -> None:
        self.config = config
        rng = np.random.default_rng(config.seed)
        (x0, x1), (y0, y1) = config.wall_x_range_m, config.wall_y_range_m
        wall_u = np.array([x1 - x0, 0.0, 0.0])
        wall_v = np.array([0.0, y1 - y0, 0.0])
        self.background: list[Quad] = []
        if config.object == "box":
            # Normal u x v = -z: the wall faces the cameras.
            self.background.append(Quad(np.array([x0, y0, config.wall_z_m]), wall_u, wall_v,
                                        _texture_for(wall_u, wall_v, BACKGROUND_TEXEL_M, rng), layer=0))
        z0, z1 = config.floor_z_range_m
        floor_u = np.array([x1 - x0, 0.0, 0.0])
        floor_v = np.array([0.0, 0.0, z1 - z0])
        self.background.append(Quad(np.array([x0, config.floor_y_m, z0]), floor_u, floor_v,
                                    _texture_for(floor_u, floor_v, BACKGROUND_TEXEL_M, rng), layer=0))
        size = np.array(config.box_size_m)
        self._box_faces = self._make_box_faces(size, rng) if config.object == "box" else _person_faces(size, rng)

    @staticmethod
    def _make_box_faces(size: np.ndarray, rng) -> list[tuple[np.ndarray, np.ndarray, np.ndarray,
                                                              np.ndarray]]:
        """Faces (p0, u, v, texture) in box coordinates, normals u x v pointing outwards."""
        hx, hy, hz = size / 2
        X, Y, Z = np.eye(3)
        faces = [
            (np.array([-hx, -hy, -hz]), 2 * hx * X, 2 * hy * Y),   # front (-z)
            (np.array([hx, -hy, hz]), -2 * hx * X, 2 * hy * Y),    # back (+z)
            (np.array([-hx, -hy, hz]), -2 * hz * Z, 2 * hy * Y),   # left (-x)
            (np.array([hx, -hy, -hz]), 2 * hz * Z, 2 * hy * Y),    # right (+x)
            (np.array([-hx, -hy, hz]), 2 * hx * X, -2 * hz * Z),   # top (-y)
            (np.array([-hx, hy, -hz]), 2 * hx * X, 2 * hz * Z),    # bottom (+y)
        ]
        return [(p0, u, v, _texture_for(u, v, BOX_TEXEL_M, rng)) for p0, u, v in faces]

    def box_rotation(self, time_s: float) -> np.ndarray:
        """World-from-box rotation at `time_s` (turning about the world's y axis)."""
        return _rot_y(math.radians(self.config.box_rotation_deg_per_s * time_s))

    def quads(self, time_s: float) -> list[Quad]:
        """Every quad of the scene at `time_s` seconds."""
        R = self.box_rotation(time_s)
        centre = np.array(self.config.box_centre_m)
        box = [Quad(centre + R @ p0, R @ u, R @ v, tex, layer=1, cull_back=True)
               for p0, u, v, tex in self._box_faces]
        return [*self.background, *box]
