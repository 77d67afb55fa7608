"""The fisheye lens model (OpenCV's fisheye / Kannala-Brandt): projection against cv2.fisheye,
analytic derivatives against finite differences, and a seeded fisheye rig calibrated within its sigmas."""

import cv2
import numpy as np
import pytest

from camnet.geometry.calibrate import calibrate
from camnet.geometry.evaluate import compare
from camnet.geometry.model import Camera, LensModel
from camnet.geometry.projection import normalised, project_points, project_with_jacobians, rotation_exp
from camnet.sim.families import FISHEYE_DIST, family
from camnet.sim.simulate import observe

K = np.array([[515.0, 0.0, 641.3], [0.0, 517.0, 509.8], [0.0, 0.0, 1.0]])


def rays_within(max_angle_deg: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points (n, 3) 0.5 to 3 m away in directions up to max_angle_deg off the z axis."""
    theta = np.radians(rng.uniform(0.0, max_angle_deg, n))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return rays * rng.uniform(0.5, 3.0, (n, 1))


def test_projection_matches_cv2_fisheye():
    rng = np.random.default_rng(0)
    R = rotation_exp(rng.normal(scale=0.3, size=3))
    t = rng.normal(scale=0.2, size=3)
    X = (rays_within(88.0, 300, rng) - t) @ R  # world points whose camera-frame rays reach 88 degrees
    cam = Camera("fish", 1280, 1024, K, np.array(FISHEYE_DIST), R, t, LensModel.FISHEYE)
    expected, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], t, K, np.array(FISHEYE_DIST))
    np.testing.assert_allclose(cam.project(X), expected.reshape(-1, 2), atol=1e-9, rtol=0)
    # The same pixels through the adjustment's vector layout: k1..k4 in the distortion slots.
    intr = np.tile([K[0, 0], K[1, 1] / K[0, 0], K[0, 2], K[1, 2], *FISHEYE_DIST, 0.0], (len(X), 1))
    uv, _ = project_points(intr, np.tile(R, (len(X), 1, 1)), np.tile(-R.T @ t, (len(X), 1)), X, np.ones(len(X), bool))
    np.testing.assert_allclose(uv, expected.reshape(-1, 2), atol=1e-9, rtol=0)
    # And back: OpenCV's inverse of the pixels is each point's ray, up to its end at a distorted angle of 90
    # degrees; beyond, no ray rather than a wrong one.
    xc = X @ R.T + t
    back = normalised(uv, K=K, dist=FISHEYE_DIST, fisheye=True)
    inside = np.linalg.norm(np.linalg.solve(K, np.column_stack([uv, np.ones(len(uv))]).T).T[:, :2], axis=1) < np.pi / 2
    assert 0 < np.sum(~inside) < np.sum(inside)
    np.testing.assert_allclose(back[inside], xc[inside, :2] / xc[inside, 2:], rtol=1e-7)
    assert np.all(np.isnan(back[~inside]))


def test_a_point_behind_a_fisheye_has_no_pixel():
    cam = Camera("fish", 1280, 1024, K, np.array(FISHEYE_DIST), model=LensModel.FISHEYE)
    assert np.all(np.isnan(cam.project(np.array([[0.1, 0.2, -1.0], [0.3, 0.0, 0.0]]))))


def test_fisheye_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    n = 40
    intr = np.tile([515.0, 1.004, 641.3, 509.8, *FISHEYE_DIST, 0.0], (n, 1))
    R = rotation_exp(rng.normal(scale=0.2, size=(n, 3)))
    C = rng.normal(scale=0.1, size=(n, 3))
    xc = rays_within(87.0, n, rng)
    xc[0] = [1e-7, -2e-7, 1.0]  # next to the optical axis, where two terms of the derivative cancel
    xc[1] = [0.0, 0.0, 2.0]  # on it
    X = np.einsum("nji,nj->ni", R, xc) + C
    fisheye = np.ones(n, bool)
    fisheye[-5:] = False  # pinhole rows in the same call
    uv, J_intr, J_rot, J_cen, J_pt = project_with_jacobians(intr, R, C, X, fisheye)
    np.testing.assert_allclose(uv, project_points(intr, R, C, X, fisheye)[0], rtol=1e-13)
    h = 1e-6

    def uv_at(**moved) -> np.ndarray:
        return project_points(**{"intr": intr, "R": R, "C": C, "X": X, "fisheye": fisheye, **moved})[0]

    for k in range(9):
        d = np.zeros(9)
        d[k] = h * max(1.0, abs(intr[0, k]))
        fd = (uv_at(intr=intr + d) - uv_at(intr=intr - d)) / (2 * d[k])
        np.testing.assert_allclose(J_intr[:, :, k], fd, rtol=1e-6, atol=1e-4)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        np.testing.assert_allclose(J_pt[:, :, k], (uv_at(X=X + e) - uv_at(X=X - e)) / (2 * h), rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(J_cen[:, :, k], (uv_at(C=C + e) - uv_at(C=C - e)) / (2 * h), rtol=1e-6, atol=1e-4)
        turned = (uv_at(R=rotation_exp(e) @ R) - uv_at(R=rotation_exp(-e) @ R)) / (2 * h)
        np.testing.assert_allclose(J_rot[:, :, k], turned, rtol=1e-6, atol=1e-4)
    assert not np.any(J_intr[fisheye, :, 8])  # the fisheye's unused slot moves nothing


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fisheye_family_calibrates_within_its_sigmas(seed):
    drawn = family("fisheye", seed=seed)
    obs = observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals).observations
    assert all(c.model == LensModel.FISHEYE and c.K is None for c in obs.cameras)
    result = calibrate(obs)
    cal = result.calibration
    assert all(cam.model == LensModel.FISHEYE and cam.dist.shape == (4,) for cam in cal.cameras)
    c = compare(cal, drawn.rig.cameras, drawn.rig.points)
    assert abs(c.scale_rel) < 3 * c.scale_sigma_rel < 0.05
    for e in c.cameras:
        assert abs(e.focal_rel) < 3 * e.focal_sigma_rel < 0.01
    assert cal.rms_reprojection_px < 0.8
    free = cal.report.free.intrinsics
    assert all({"k1", "k2", "k3", "k4"} <= set(free[cam.id]) for cam in cal.cameras), free
