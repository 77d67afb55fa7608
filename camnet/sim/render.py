"""A pure renderer of textured planar quads seen by a camnet.model.camera.Camera.

Each quad is a textured rectangle in 3-D (origin corner + two edge vectors, m).
A quad is drawn by warping its texture with the exact plane-to-image
homography ``K [R u/w | R v/h | R p0 + t]`` (cv2.warpPerspective), masked by
its polygon clipped to the space in front of the camera. Quads are drawn in
painter's order: by layer (background first), then far to near; the box's
back faces are culled, so a convex object needs no depth buffer. Lens
distortion is applied afterwards by remapping the ideal pinhole image (for a
fisheye, five pinhole faces of a cube about its centre), then sensor noise
is added.

Texel centres follow the pixel convention: texel (a, b) covers the square
around integer (a, b) and its centre lies at ``p0 + (a + 0.5)/w u + (b + 0.5)/h v``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from camnet.model.camera import Camera, LensModel
from camnet.model.projection import distort, full_dist, lens_terms, rotation_exp

_NEAR_M = 0.01  # near clipping plane in camera z


@dataclass(frozen=True, eq=False)
class Quad:
    """A textured rectangle: corners p0, p0+u, p0+u+v, p0+v (m); texture (h, w) uint8.

    The texture's x axis runs along `u`, its y axis along `v`. `layer` orders
    drawing (lower first); `cull_back` hides the quad when seen from the side
    opposite to the normal u x v.
    """

    p0: np.ndarray
    u: np.ndarray
    v: np.ndarray
    texture: np.ndarray
    layer: int = 0
    cull_back: bool = False

    def corners(self) -> np.ndarray:
        return np.stack([self.p0, self.p0 + self.u, self.p0 + self.u + self.v, self.p0 + self.v])

    def point(self, a_px: float, b_px: float) -> np.ndarray:
        """World point (m) of texture coordinates (a, b) in texel units."""
        h, w = self.texture.shape[:2]
        return self.p0 + (a_px + 0.5) / w * self.u + (b_px + 0.5) / h * self.v


def plane_homography(quad: Quad, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """3x3 homography from texture coordinates (texels) to ideal pixel coordinates."""
    h, w = quad.texture.shape[:2]
    origin = quad.p0 + 0.5 * quad.u / w + 0.5 * quad.v / h
    M = np.column_stack([R @ (quad.u / w), R @ (quad.v / h), R @ origin + t])
    return K @ M


def _clip_near(points_cam: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon (n, 3) to z >= near."""
    out = []
    n = len(points_cam)
    for i in range(n):
        a, b = points_cam[i], points_cam[(i + 1) % n]
        a_in, b_in = a[2] >= _NEAR_M, b[2] >= _NEAR_M
        if a_in:
            out.append(a)
        if a_in != b_in:
            s = (_NEAR_M - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out).reshape(-1, 3)


def _triple(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """(a x b) . c of 3-vectors, written out: np.cross's overhead on single vectors costs a sim frame dearly
    (docs/benchmarks.md, "Evidence behind the nodes' choices")."""
    return float((a[1] * b[2] - a[2] * b[1]) * c[0] + (a[2] * b[0] - a[0] * b[2]) * c[1]
                 + (a[0] * b[1] - a[1] * b[0]) * c[2])


def render_ideal(quads: list[Quad], *, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                 size: tuple[int, int], background: int = 0, base: np.ndarray | None = None) -> np.ndarray:
    """Undistorted pinhole image (height, width) uint8 of `quads`; `size` is (width, height).

    `quads` are drawn over a copy of `base` (an image of this size) when given,
    else over a uniform `background` grey.
    """
    width, height = size
    image = np.full((height, width), background, dtype=np.uint8) if base is None else base.copy()
    centre = -R.T @ t
    visible = []
    for quad in quads:
        corners_cam = quad.corners() @ R.T + t
        if quad.cull_back and _triple(quad.u, quad.v, centre - quad.p0) <= 0:
            continue
        polygon = _clip_near(corners_cam)
        if len(polygon) < 3:
            continue
        depth = float(np.linalg.norm(corners_cam.mean(axis=0)))
        visible.append((quad.layer, -depth, quad, polygon))
    visible.sort(key=lambda item: item[:2])
    for _, _, quad, polygon in visible:
        H = plane_homography(quad, K, R, t)
        pix = polygon @ K.T
        pix = pix[:, :2] / pix[:, 2:3]
        if not np.all(np.isfinite(pix)):
            continue
        # Polygon bounds limit the warp to where the quad can appear.
        x0, y0 = np.floor(pix.min(axis=0)).astype(int)
        x1, y1 = np.ceil(pix.max(axis=0)).astype(int)
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, width - 1), min(y1, height - 1)
        if x0 > x1 or y0 > y1:
            continue
        shift = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]])
        roi = (x1 - x0 + 1, y1 - y0 + 1)
        warped = cv2.warpPerspective(quad.texture, shift @ H, roi, flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)
        mask = np.zeros((roi[1], roi[0]), dtype=np.uint8)
        # fillPoly with 4 fractional bits: the quad's edge lands within 1/16 px.
        poly = np.round((pix - [x0, y0]) * 16).astype(np.int32)
        cv2.fillPoly(mask, [poly], 255, lineType=cv2.LINE_8, shift=4)
        region = image[y0:y1 + 1, x0:x1 + 1]
        np.copyto(region, warped, where=mask.astype(bool))
    return image


@dataclass(frozen=True, eq=False)
class Face:
    """An ideal pinhole canvas at the camera's centre, turned by R (``x_face = R x_cam``), with its K and size.

    Its rows start at `row` in the atlas that the distorted image looks up.
    """

    R: np.ndarray
    K: np.ndarray
    size: tuple[int, int]
    row: int


@dataclass(frozen=True, eq=False)
class DistortionMap:
    """cv2.remap maps from the distorted image into an atlas of ideal canvases (faces), stacked by rows."""

    map_x: np.ndarray
    map_y: np.ndarray
    faces: tuple[Face, ...]
    atlas_size: tuple[int, int]


# A fisheye sees more than any one pinhole canvas can hold: the faces of a cube, but the back one
# (cv2.fisheye's inverse ends at 90 degrees off the axis anyway).
_FISHEYE_FACES = tuple(
    rotation_exp(np.array(w)) for w in ([0, 0, 0], [0, np.pi / 2, 0], [0, -np.pi / 2, 0], [np.pi / 2, 0, 0],
                                        [-np.pi / 2, 0, 0])
)


def distortion_map(camera: Camera) -> DistortionMap | None:
    """Maps for `camera`'s lens, or None when it has none (a pinhole without distortion: identity).

    Every pixel's ray (OpenCV's inverse of the lens: cv2.fisheye.undistortPoints
    for a fisheye) looks up the face it is most central in, in an ideal canvas
    of the camera's own K; pixels without a ray stay black.
    """
    fisheye = camera.model == LensModel.FISHEYE
    if not fisheye and not np.any(camera.dist):
        return None
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    K = camera.K
    if fisheye:
        normalised = camera.normalised(pixels)
    else:
        distorted = np.stack([(pixels[:, 0] - K[0, 2] - K[0, 1] * (pixels[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0],
                              (pixels[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
        normalised = undistort_normalised(distorted, camera.dist)
    rays = np.column_stack([normalised, np.ones(len(normalised))])
    rotations = _FISHEYE_FACES if fisheye else (np.eye(3),)
    face_of = np.argmax(np.stack([rays @ R[2] for R in rotations]), axis=0)
    has_ray = np.all(np.isfinite(rays), axis=1)
    map_xy = np.full((len(rays), 2), -1.0)
    faces, row = [], 0
    for f, R in enumerate(rotations):
        mine = has_ray & (face_of == f)
        if not mine.any():
            continue
        local = rays[mine] @ R.T
        ideal = (local / local[:, 2:]) @ K[:2].T
        # The canvas covers every pixel the distorted image looks up (plus a margin).
        lo = np.floor(ideal.min(axis=0)) - 2
        hi = np.ceil(ideal.max(axis=0)) + 2
        canvas_K = K.copy()
        canvas_K[:2, 2] -= lo
        size = (int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1)
        map_xy[mine] = ideal - lo + [0, row]
        faces.append(Face(R, canvas_K, size, row))
        row += size[1]
    shape = (camera.height, camera.width)
    return DistortionMap(map_xy[:, 0].reshape(shape).astype(np.float32), map_xy[:, 1].reshape(shape).astype(np.float32),
                         tuple(faces), (max(face.size[0] for face in faces), row))


def undistort_normalised(xd: np.ndarray, dist: np.ndarray, iterations: int = 40) -> np.ndarray:
    """Normalised points (n, 2) whose OpenCV distortion is `xd`, by fixed-point iteration.

    Converges for the moderate distortion of real lenses; the residual is
    checked so a lens beyond that fails loudly instead of rendering garbage.
    """
    coefficients = full_dist(dist)
    x = xd.copy()
    for _ in range(iterations):
        _, radial, dx, dy = lens_terms(x[:, 0], x[:, 1], *coefficients)
        x = np.stack([(xd[:, 0] - dx) / radial, (xd[:, 1] - dy) / radial], axis=1)
    residual = np.abs(distort(x, dist) - xd).max()
    if not residual < 1e-9:
        raise ValueError(f"distortion {list(dist)} cannot be inverted over the image "
                         f"(residual {residual:.2g}); is it too strong?")
    return x


NOISE_MARGIN_PX = 64  # a frame's noise is a window of its camera's noise field, shifted by up to this


class Renderer:
    """Renders one camera's images; holds its precomputed distortion maps.

    The lowest layer of the quads (the static background of a scene) is drawn
    once and kept while the same quad objects come back: painter's order draws
    that layer first whatever the depths of the others, so drawing the higher
    layers over the kept canvas gives the same image as drawing them all.
    Quads are values: one that changes is a new Quad.

    With `noise_seed`, a frame's sensor noise is a window, at an offset drawn
    from that frame's `rng`, of one Gaussian field per camera seeded from it
    (drawing a full frame of normal deviates costs more than the rest of the
    frame: docs/benchmarks.md, "The live network"); without it, every frame's
    noise is drawn afresh from `rng`.
    """

    def __init__(self, camera: Camera, *, noise_seed: object = None) -> None:
        self.camera = camera
        self.distortion = distortion_map(camera)
        self._noise_seed = noise_seed
        self._noise: tuple[float, np.ndarray] | None = None  # (sigma, field) of the latest sigma
        self._static: tuple[tuple[Quad, ...], np.ndarray] | None = None  # the lowest layer and its canvas

    def render(self, quads: list[Quad], *, noise_sigma_dn: float = 0.0,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """The camera's (height, width) uint8 image of `quads`, noise std in digital numbers."""
        lowest = min((quad.layer for quad in quads), default=0)
        static = tuple(quad for quad in quads if quad.layer == lowest)
        moving = [quad for quad in quads if quad.layer != lowest]
        if self._static is None or len(self._static[0]) != len(static) or any(
                a is not b for a, b in zip(self._static[0], static, strict=True)):
            self._static = (static, self._canvas(list(static), None))
        canvas = self._canvas(moving, self._static[1]) if moving else self._static[1]
        d = self.distortion
        image = canvas.copy() if d is None else cv2.remap(canvas, d.map_x, d.map_y, cv2.INTER_LINEAR,
                                                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if noise_sigma_dn > 0:
            rng = rng or np.random.default_rng()
            if self._noise_seed is None:
                return add_noise(image, noise_sigma_dn, rng)
            return self._add_field_noise(image, noise_sigma_dn, rng)
        return image

    def _canvas(self, quads: list[Quad], base: np.ndarray | None) -> np.ndarray:
        """The ideal image (no lens) or, for a distorted lens, the atlas of its faces, over `base`."""
        cam = self.camera
        if self.distortion is None:
            return render_ideal(quads, K=cam.K, R=cam.R, t=cam.t, size=(cam.width, cam.height), base=base)
        d = self.distortion
        atlas = np.zeros((d.atlas_size[1], d.atlas_size[0]), dtype=np.uint8) if base is None else base.copy()
        for face in d.faces:
            width, height = face.size
            rows = slice(face.row, face.row + height)
            atlas[rows, :width] = render_ideal(quads, K=face.K, R=face.R @ cam.R, t=face.R @ cam.t, size=face.size,
                                               base=None if base is None else base[rows, :width])
        return atlas

    def _add_field_noise(self, image: np.ndarray, sigma_dn: float, rng: np.random.Generator) -> np.ndarray:
        height, width = image.shape[:2]
        if self._noise is None or self._noise[0] != sigma_dn:
            field = np.empty((height + NOISE_MARGIN_PX, width + NOISE_MARGIN_PX, *image.shape[2:]), dtype=np.int16)
            cv2.setRNGSeed(int(np.random.default_rng(self._noise_seed).integers(2**31)))
            cv2.randn(field, 0, sigma_dn)
            self._noise = (sigma_dn, field)
        dy, dx = (int(o) for o in rng.integers(0, NOISE_MARGIN_PX + 1, size=2))
        window = self._noise[1][dy:dy + height, dx:dx + width]
        # Saturating uint8 + int16: the same as adding in int16 and clipping to 0-255.
        return cv2.add(image, window, dtype=cv2.CV_8U)


def add_noise(image: np.ndarray, sigma_dn: float, rng: np.random.Generator) -> np.ndarray:
    """`image` plus Gaussian noise of std `sigma_dn`, saturated to uint8."""
    noise = np.empty(image.shape, dtype=np.int16)
    # cv2.randn is several times faster than numpy's normal on a whole frame (docs/benchmarks.md, "Evidence
    # behind the nodes' choices"); seed it from rng.
    cv2.setRNGSeed(int(rng.integers(2**31)))
    cv2.randn(noise, 0, sigma_dn)
    return cv2.add(image.astype(np.int16), noise).clip(0, 255).astype(np.uint8)
