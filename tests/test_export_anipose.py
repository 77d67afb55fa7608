"""The anipose calibration.toml, read back by Python's TOML reader and by aniposelib's own CameraGroup.load.

aniposelib is not in the test extra: it requires opencv-contrib-python, whose
cv2 (built with Qt, needing the system's libGL) would overwrite the headless
OpenCV camnet installs, and it brings jax and numba (about 600 MB). Its
tests run where the `anipose` extra is installed in an environment of its own
(``pip install -e '.[test,anipose]'``); elsewhere they skip and say so.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace

import cv2
import numpy as np
import pytest

from camnet.errors import InputError
from camnet.io.export_anipose import anipose_toml
from camnet.model.calibration import Calibration
from camnet.sim.simulate import make_rig
from tests.test_export import fisheye_calibration, in_image, rig_calibration

NO_ANIPOSELIB = (
    "aniposelib is not installed (the anipose extra): it requires opencv-contrib-python, which would replace "
    "camnet's headless OpenCV, so it lives in an environment of its own"
)


def load_with_aniposelib(tmp_path, text: str):
    cameras = pytest.importorskip("aniposelib.cameras", reason=NO_ANIPOSELIB)
    path = tmp_path / "calibration.toml"
    path.write_text(text)
    return cameras, cameras.CameraGroup.load(str(path))


def many_cameras(n: int) -> Calibration:
    rig = make_rig(n_cameras=n, seed=2)
    return Calibration(tuple(rig.cameras), np.arange(len(rig.points)), rig.points.copy(), 0.4, "left")


def test_toml_holds_each_camera_in_opencvs_conventions():
    cal, _ = rig_calibration()
    doc = tomllib.loads(anipose_toml(cal))
    assert list(doc) == ["cam_0", "cam_1", "cam_2", "cam_3", "metadata"]
    assert doc["metadata"] == {"units": "m", "world_frame": "left", "source": "camnet.calibration/1",
                               "rms_reprojection_px": 0.5}
    for k, cam in enumerate(cal.cameras):
        table = doc[f"cam_{k}"]
        assert (table["name"], table["size"], table["fisheye"]) == (cam.id, [cam.width, cam.height], False)
        np.testing.assert_array_equal(table["matrix"], cam.K)
        np.testing.assert_array_equal(table["distortions"], cam.dist)
        np.testing.assert_array_equal(table["translation"], cam.t)
        np.testing.assert_allclose(cv2.Rodrigues(np.array(table["rotation"]))[0], cam.R, atol=1e-14)
        # What aniposelib does with them: cv2.projectPoints with the Rodrigues vector and t.
        uv, _ = cv2.projectPoints(cal.points, np.array(table["rotation"]), np.array(table["translation"]),
                                  np.array(table["matrix"]), np.array(table["distortions"]))
        np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(cal.points), atol=1e-6)


def test_aniposelib_loads_the_cameras_and_projects_as_camnet(tmp_path):
    cal, _ = rig_calibration()
    cameras, group = load_with_aniposelib(tmp_path, anipose_toml(cal))
    assert [type(c) for c in group.cameras] == [cameras.Camera] * len(cal.cameras)
    assert group.metadata["units"] == "m"
    projected = group.project(cal.points)  # (cameras, points, 2)
    for k, cam in enumerate(cal.cameras):
        c = group.cameras[k]
        assert (c.get_name(), list(c.get_size())) == (cam.id, [cam.width, cam.height])
        np.testing.assert_array_equal(c.get_camera_matrix(), cam.K)
        np.testing.assert_array_equal(c.get_distortions(), cam.dist)
        np.testing.assert_array_equal(c.get_translation(), cam.t)
        np.testing.assert_allclose(c.get_extrinsics_mat()[:3, :3], cam.R, atol=1e-14)
        np.testing.assert_allclose(projected[k], cam.project(cal.points), atol=1e-6)


def test_aniposelib_projects_fisheye_cameras_with_its_fisheye_class(tmp_path):
    cal = fisheye_calibration()
    doc = tomllib.loads(anipose_toml(cal))
    assert all(doc[f"cam_{k}"]["fisheye"] and len(doc[f"cam_{k}"]["distortions"]) == 4 for k in range(4))
    cameras, group = load_with_aniposelib(tmp_path, anipose_toml(cal))
    for k, cam in enumerate(cal.cameras):
        assert type(group.cameras[k]) is cameras.FisheyeCamera
        X = in_image(cam, cal.points)
        np.testing.assert_allclose(group.cameras[k].project(X).reshape(-1, 2), cam.project(X), atol=1e-6)


def test_more_than_ten_cameras_keep_their_order(tmp_path):
    cal = many_cameras(12)
    text = anipose_toml(cal)
    assert list(tomllib.loads(text))[:3] == ["cam_00", "cam_01", "cam_02"]
    _, group = load_with_aniposelib(tmp_path, text)  # it sorts the table names as text
    assert [c.get_name() for c in group.cameras] == [cam.id for cam in cal.cameras]


def test_millimetres_scale_the_translations_and_what_aniposelib_triangulates(tmp_path):
    cal, _ = rig_calibration()
    doc = tomllib.loads(anipose_toml(cal, unit="mm"))
    assert doc["metadata"]["units"] == "mm"
    for k, cam in enumerate(cal.cameras):
        np.testing.assert_allclose(doc[f"cam_{k}"]["translation"], 1000.0 * cam.t, rtol=1e-15)
    _, group = load_with_aniposelib(tmp_path, anipose_toml(cal, unit="mm"))
    # The same pixels from the points in millimetres: the unit of the triangulated points.
    projected = group.project(1000.0 * cal.points)
    for k, cam in enumerate(cal.cameras):
        np.testing.assert_allclose(projected[k], cam.project(cal.points), atol=1e-6)


def test_names_are_escaped_and_bad_input_refused():
    cal, _ = rig_calibration()
    odd = 'cam "A" \\ \x07 é'
    cal = replace(cal, cameras=(replace(cal.cameras[0], id=odd), *cal.cameras[1:]))
    assert tomllib.loads(anipose_toml(cal))["cam_0"]["name"] == odd
    with pytest.raises(InputError, match="--unit: 'cm' is not one of m, mm"):
        anipose_toml(cal, unit="cm")
    K = cal.cameras[1].K.copy()
    K[0, 1] = 0.3
    with pytest.raises(InputError, match=r"cameras\[1\]\.K: skew"):
        anipose_toml(replace(cal, cameras=(cal.cameras[0], replace(cal.cameras[1], K=K), *cal.cameras[2:])))
