"""The fisheye lens model (OpenCV's fisheye / Kannala-Brandt): projection against cv2.fisheye,
analytic derivatives against finite differences, a seeded fisheye rig calibrated within its sigmas,
and the model in the documents and the rig file."""

import json
import subprocess
import sys
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.formats import calibration_to_doc, observations_to_doc, parse_calibration, parse_observations
from camnet.io.rig import parse_rig
from camnet.model.accuracy import compare
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera, LensModel
from camnet.model.projection import normalised, project_points, project_with_jacobians, rotation_exp
from camnet.sim.families import FISHEYE_DIST, family
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from camnet.solve.context import (
    FISHEYE_START_CORNER_RAD,
    camera_order,
    centred,
    initial_intrinsics,
    with_guessed_fisheye_focal,
)

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
    cam = Camera("fish", 1280, 1024, K, model=LensModel.FISHEYE)  # no dist given: the equidistant lens
    assert cam.dist.tolist() == [0.0] * 4
    assert np.all(np.isnan(cam.project(np.array([[0.1, 0.2, -1.0], [0.3, 0.0, 0.0]]))))
    with pytest.raises(ValueError, match=r"'fish': a fisheye's dist is \[k1, k2, k3, k4\]"):
        Camera("fish", 1280, 1024, K, np.array([0.1, 0.0, 0.0, 0.0, 0.0]), model=LensModel.FISHEYE)


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


# ---------------------------------------------------------------- the documents and the rig file


def fisheye_observations(seed: int = 0):
    drawn = family("fisheye", seed=seed)
    return drawn, observe(drawn.rig, noise_px=0.5, seed=seed, normals=drawn.normals, with_intrinsics=True).observations


def test_observations_carry_the_model_and_its_dist():
    _, obs = fisheye_observations()
    doc = observations_to_doc(obs)
    assert doc["cameras"][0]["model"] == "fisheye" and doc["cameras"][0]["dist"] == list(FISHEYE_DIST)
    back = parse_observations(json.loads(json.dumps(doc)))
    for cam, orig in zip(back.cameras, obs.cameras, strict=True):
        assert cam.model == LensModel.FISHEYE
        np.testing.assert_array_equal(cam.dist, orig.dist)
    # A pinhole camera says nothing of its model (the default), and reads back as one.
    pinhole = observations_to_doc(observe(make_rig(seed=1), with_intrinsics=True).observations)
    assert "model" not in pinhole["cameras"][0] and len(pinhole["cameras"][0]["dist"]) == 5
    assert parse_observations(pinhole).cameras[0].model == LensModel.PINHOLE


FISHEYE_DIST_ERROR = r"cameras\[1\]\.dist: a fisheye's dist is \[k1, k2, k3, k4\]: expected 4 numbers"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"model": "kannala"}, r"cameras\[1\]\.model: unknown value 'kannala' \(expected pinhole, fisheye\)"),
        ({"model": "fisheye", "dist": [0.1, 0.0, 0.0, 0.0, 0.0]}, FISHEYE_DIST_ERROR),
        ({"model": "fisheye", "dist": [0.1, 0.0]}, FISHEYE_DIST_ERROR),
        ({"dist": [0.1, 0.0, 0.0, 0.0, 0.0, 0.2]}, r"cameras\[1\]\.dist: a pinhole.s dist is at most \[k1, k2, p1, p2"),
    ],
)
def test_a_wrong_model_or_dist_is_one_line_naming_the_field(change, message):
    _, obs = fisheye_observations()
    doc = observations_to_doc(obs)
    doc["cameras"][1].pop("model")
    doc["cameras"][1].update(change)
    with pytest.raises(InputError, match=message) as caught:
        parse_observations(doc)
    assert "\n" not in str(caught.value)


def test_a_fisheye_calibration_document_reads_back():
    drawn, _ = fisheye_observations()
    ids = np.arange(len(drawn.rig.points), dtype=np.int64)
    cal = Calibration(tuple(drawn.rig.cameras), ids, drawn.rig.points, 0.5, "left")
    doc = json.loads(json.dumps(calibration_to_doc(cal)))
    assert [c["model"] for c in doc["cameras"]] == ["fisheye"] * 4
    back = parse_calibration(doc)
    for cam, orig in zip(back.cameras, cal.cameras, strict=True):
        assert cam.model == LensModel.FISHEYE
        np.testing.assert_array_equal(cam.dist, orig.dist)
        np.testing.assert_array_equal(cam.project(cal.points), orig.project(cal.points))
    doc["cameras"][2]["dist"] = doc["cameras"][2]["dist"] + [0.0]
    with pytest.raises(InputError, match=r"cameras\[2\]\.dist: a fisheye's dist"):
        parse_calibration(doc)


def test_a_rig_file_gives_a_camera_the_fisheye_model():
    camera = {"id": "a", "driver": "sim", "model": "fisheye",
              "sim": {"width": 64, "height": 48, "f_px": 20, "dist": list(FISHEYE_DIST)},
              "intrinsics": {"dist": list(FISHEYE_DIST), "fixed": []}}
    rig = parse_rig({"rig": "r", "cameras": [camera, {**camera, "id": "b"}]}, source="rig.yaml")
    entry = rig.camera("a")
    assert entry.model == LensModel.FISHEYE and entry.intrinsics.dist.tolist() == list(FISHEYE_DIST)
    cam = entry.config.camera("a")
    assert cam.model == LensModel.FISHEYE and cam.dist.tolist() == list(FISHEYE_DIST)
    camera["sim"]["dist"] = [0.1, 0.0, 0.0, 0.0, 0.0]
    with pytest.raises(InputError, match=r"rig\.yaml: cameras\[0\]\.sim\.dist: a fisheye's dist"):
        parse_rig({"rig": "r", "cameras": [camera]}, source="rig.yaml")
    with pytest.raises(InputError, match=r"cameras\[0\]\.model: unknown value 'wide'"):
        parse_rig({"rig": "r", "cameras": [{**camera, "model": "wide"}]}, source="rig.yaml")


def test_camnet_calibrate_solves_a_fisheye_document(tmp_path):
    drawn = family("fisheye", seed=2)
    obs = observe(drawn.rig, noise_px=0.5, seed=2, normals=drawn.normals).observations
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(observations_to_doc(obs)))
    proc = subprocess.run([sys.executable, "-m", "camnet", "calibrate", str(src), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    cal = parse_calibration(json.loads(out.read_text()))
    assert all(cam.model == LensModel.FISHEYE and cam.dist.shape == (4,) for cam in cal.cameras)
    truth = {c.id: c for c in drawn.rig.cameras}
    for cam in cal.cameras:
        np.testing.assert_allclose(cam.dist, truth[cam.id].dist, atol=0.03)


def test_a_fisheye_start_makes_its_pixels_pinhole_ones_with_a_guessed_focal_length():
    drawn = family("fisheye", seed=1)
    cameras = list(drawn.rig.cameras)
    cameras[3] = replace(cameras[3], model=LensModel.PINHOLE, dist=np.zeros(5))  # a pinhole among them
    obs = observe(replace(drawn.rig, cameras=cameras), noise_px=0.0, seed=1).observations
    order = camera_order(obs)
    intr = initial_intrinsics(obs, order)
    guessed = with_guessed_fisheye_focal(obs, order, intr)
    g = np.hypot(1280, 1024) / 2 / FISHEYE_START_CORNER_RAD
    np.testing.assert_array_equal(guessed[:, 0], [g, g, g, np.nan])
    np.testing.assert_array_equal(guessed[:, 1:], intr[:, 1:])
    xy = centred(obs, order, intr)  # guesses the same itself
    # An equidistant lens of focal length g: a pixel r from the centre is g tan(r / g) from it in the pinhole image.
    m_of = np.argsort(order)[obs.cam_index]
    for m in range(4):
        rows = m_of == m
        r = np.linalg.norm(obs.uv[rows] - intr[m, 2:4], axis=1)
        expected = g * np.tan(r / g) if m < 3 else r
        np.testing.assert_allclose(np.linalg.norm(xy[rows], axis=1), expected, rtol=1e-6)
    assert np.isnan(intr[:, 0]).all()  # the guess is for the start's pixels only


def test_a_warm_start_from_a_fisheye_calibration_document_keeps_its_free_set():
    drawn, _ = fisheye_observations(seed=4)
    obs = observe(drawn.rig, noise_px=0.5, seed=4, normals=drawn.normals).observations
    cold = calibrate(obs).calibration
    initial = parse_calibration(json.loads(json.dumps(calibration_to_doc(cold))))
    assert initial.report.free.intrinsics["left"][-4:] == ("k1", "k2", "k3", "k4")
    warm = calibrate(obs, initial=initial).calibration
    assert warm.report.start.value == "warm"
    assert warm.report.free.intrinsics == cold.report.free.intrinsics
    for a, b in zip(warm.cameras, cold.cameras, strict=True):
        assert a.model == LensModel.FISHEYE
        np.testing.assert_allclose(a.K, b.K, rtol=1e-6)
        np.testing.assert_allclose(a.dist, b.dist, atol=1e-4)  # to the solves' tolerance: the polynomial is flat
