"""The renderer puts known 3-D points on the pixels the ground truth projects them to."""

from dataclasses import replace

import numpy as np
import pytest

from camnet.io.rig import load_rig
from camnet.model.camera import Camera, LensModel
from camnet.model.projection import look_at, rotation_exp
from camnet.sim.families import FISHEYE_DIST
from camnet.sim.render import Quad, Renderer, distortion_map
from camnet.sim.scene import Scene
from tests.test_rig import CONFIG

BLOB_SIGMA_TEXELS = 1.6


def dot_texture(size_px: int, dots_px: np.ndarray) -> np.ndarray:
    """Black texture with Gaussian dots centred at sub-texel positions (a, b)."""
    a, b = np.meshgrid(np.arange(size_px), np.arange(size_px))
    tex = np.zeros((size_px, size_px))
    for a0, b0 in dots_px:
        tex += np.exp(-((a - a0) ** 2 + (b - b0) ** 2) / (2 * BLOB_SIGMA_TEXELS**2))
    return np.clip(np.round(250 * tex), 0, 255).astype(np.uint8)


def centroid(image: np.ndarray, near: np.ndarray, radius_px: int = 7) -> np.ndarray:
    u0, v0 = np.round(near).astype(int)
    patch = image[v0 - radius_px:v0 + radius_px + 1, u0 - radius_px:u0 + radius_px + 1]
    w = patch.astype(float)
    vs, us = np.mgrid[-radius_px:radius_px + 1, -radius_px:radius_px + 1]
    return np.array([u0 + (w * us).sum() / w.sum(), v0 + (w * vs).sum() / w.sum()])


CAMERAS = {
    "frontal": Camera("f", 1280, 1024, np.array([[1500, 0, 639.5], [0, 1500, 511.5], [0, 0, 1]])),
    "oblique_distorted": Camera(
        "o", 1280, 1024, np.array([[1300, 0, 650.2], [0, 1310, 500.7], [0, 0, 1]]),
        dist=np.array([-0.12, 0.05, 0.001, -0.0015, 0.0]),
        **dict(zip(("R", "t"), look_at(np.array([-0.30, 0.02, 0.05]),
                                       np.array([0.0625, 0.0, 0.65])), strict=True))),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_known_points_land_on_projected_pixels(name):
    camera = CAMERAS[name]
    rng = np.random.default_rng(3)
    size = 600
    grid = np.stack(np.meshgrid(np.linspace(40, size - 40, 7), np.linspace(40, size - 40, 7)),
                    axis=-1).reshape(-1, 2)
    dots = grid + rng.uniform(-0.5, 0.5, grid.shape)
    # A tilted plane 0.3 m wide around (0.06, 0, 0.65): ~0.5 mm texels, ~1.1 px each.
    tilt = np.deg2rad(25)
    u = 0.3 * np.array([np.cos(tilt), 0.0, np.sin(tilt)])
    v = np.array([0.0, 0.3, 0.0])
    p0 = np.array([0.0625, 0.0, 0.65]) - (u + v) / 2
    quad = Quad(p0, u, v, dot_texture(size, dots))
    image = Renderer(camera).render([quad])
    points = np.array([quad.point(a, b) for a, b in dots])
    expected = camera.project(points)
    inside = np.all((expected > 10) & (expected < [camera.width - 11, camera.height - 11]), axis=1)
    assert inside.sum() >= 30
    errors = np.array([np.linalg.norm(centroid(image, e) - e) for e in expected[inside]])
    assert errors.max() < 0.1, f"max error {errors.max():.3f} px"


def test_a_fisheye_puts_points_on_its_pixels_across_the_seams_of_its_faces():
    # 160 degrees across the diagonal; a wall to the right from 37 to 77 degrees off the axis,
    # across the seam at 45 degrees between the front face and the right one.
    camera = Camera("fish", 1280, 1024, np.array([[550.0, 0, 642.3], [0, 551.0, 508.9], [0, 0, 1]]),
                    dist=np.array(FISHEYE_DIST), R=rotation_exp(np.array([0.02, -0.03, 0.01])), t=np.zeros(3),
                    model=LensModel.FISHEYE)
    rng = np.random.default_rng(4)
    size = 600
    grid = np.stack(np.meshgrid(np.linspace(30, size - 30, 12), np.linspace(30, size - 30, 12)),
                    axis=-1).reshape(-1, 2)
    dots = grid + rng.uniform(-0.5, 0.5, grid.shape)
    quad = Quad(np.array([0.45, -0.25, 0.1]), np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.5, 0.0]),
                dot_texture(size, dots))
    image = Renderer(camera).render([quad])
    points = np.array([quad.point(a, b) for a, b in dots])
    expected = camera.project(points)
    inside = np.all((expected > 10) & (expected < [camera.width - 11, camera.height - 11]), axis=1)
    angle = np.degrees(np.arccos((points @ camera.R.T)[:, 2] / np.linalg.norm(points, axis=1)))
    assert np.any(inside & (angle < 44)) and np.any(inside & (angle > 46))
    errors = np.array([np.linalg.norm(centroid(image, e, radius_px=5) - e) for e in expected[inside]])
    assert errors.max() < 0.1, f"max error {errors.max():.3f} px"
    # Where cv2.fisheye's inverse ends (90 degrees distorted), the corners of a wider lens look up nothing.
    wider = distortion_map(replace(camera, K=np.array([[380.0, 0, 639.5], [0, 380.0, 511.5], [0, 0, 1]])))
    assert wider.map_x[0, 0] == wider.map_y[0, 0] == -1 and wider.map_x[512, 640] >= 0


def test_default_rig_every_camera_sees_texture():
    rig = load_rig(CONFIG / "sim.yaml")
    scene = Scene(rig.scene)
    for entry in rig.cameras:
        image = Renderer(entry.config.camera(entry.id)).render(scene.quads(0.0))
        assert image.shape == (1024, 1280)
        for block in (image[:512, :640], image[:512, 640:], image[512:, :640], image[512:, 640:]):
            assert block.std() > 20, entry.id
        assert (image == 0).mean() < 0.01


def test_the_fisheye_rig_fills_its_wide_view():
    rig = load_rig(CONFIG / "fisheye.yaml")
    camera = rig.camera("left").config.camera("left")
    assert camera.model == LensModel.FISHEYE
    image = Renderer(camera).render(Scene(rig.scene).quads(0.0))
    for block in (image[:512, :640], image[:512, 640:], image[512:, :640], image[512:, 640:]):
        assert block.std() > 20
    assert (image == 0).mean() < 0.05


def test_box_turns_over_time_and_background_stays():
    rig = load_rig(CONFIG / "sim.yaml")
    scene = Scene(rig.scene)
    renderer = Renderer(rig.camera("left").config.camera("left"))
    first, later = renderer.render(scene.quads(0.0)), renderer.render(scene.quads(4.0))
    changed = np.abs(first.astype(int) - later) > 0
    assert changed[400:600, 600:760].mean() > 0.5  # on the box
    assert changed[:150, :300].mean() == 0  # far wall, top left


def test_the_person_is_an_upright_elliptic_cylinder_of_its_size():
    rig = load_rig(CONFIG / "surround.yaml")
    person = [q for q in Scene(rig.scene).quads(0.0) if q.layer == 1]
    half_width, height, half_depth = np.array(rig.scene.box_size_m) / [2, 1, 2]
    phi = np.linspace(0, 2 * np.pi, 3601)
    for camera_id in ("head_left", "ring2", "ring3"):
        camera = rig.camera(camera_id).config.camera(camera_id)
        image = Renderer(camera).render(person)
        # The silhouette at mid-height: the extreme projections of the rim there.
        rim = np.stack([half_width * np.cos(phi), np.zeros_like(phi), half_depth * np.sin(phi)], axis=1)
        uv = camera.project(rim)
        row = image[int(round(uv[:, 1].mean()))]
        drawn = np.flatnonzero(row > 0)
        assert abs(drawn.min() - uv[:, 0].min()) < 1.5 and abs(drawn.max() - uv[:, 0].max()) < 1.5, camera_id
        # Top and bottom at the centre column: the rims' outermost crossings of it.
        col = int(round(uv[:, 0].mean()))
        column = np.flatnonzero(image[:, col] > 0)
        top, bottom = (camera.project(rim + [0.0, y, 0.0]) for y in (-height / 2, height / 2))
        expected_top = top[np.abs(top[:, 0] - col) < 0.5, 1].min()
        expected_bottom = bottom[np.abs(bottom[:, 0] - col) < 0.5, 1].max()
        assert abs(column.min() - expected_top) < 1.5 and abs(column.max() - expected_bottom) < 1.5, camera_id
        assert 0.9 < (row > 0).mean() * camera.width / np.ptp(uv[:, 0]) <= 1.02  # textured all across
