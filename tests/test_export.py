"""Exports read back by each ecosystem's own reader (OpenCV FileStorage, pycolmap) or PyYAML,
and checked against independent computations of the conventions."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from camnet.errors import InputError
from camnet.io.export import export, kalibr_camchain, opencv_yaml, ros_camera_info
from camnet.io.export_colmap import colmap_binary, colmap_model, colmap_text
from camnet.io.formats import calibration_to_doc, observations_to_doc
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.sim.families import family
from camnet.sim.simulate import make_rig, observe

# Per camera [k1, k2, p1, p2, k3]: none, OpenCV's four, and all five (COLMAP's three models).
DISTORTIONS = [
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [-0.12, 0.05, 0.001, -0.0008, 0.0],
    [-0.08, 0.03, -0.0005, 0.0012, 0.01],
    [0.04, 0.0, 0.0, 0.0, 0.0],
]


def rig_calibration(*, k3: bool = True, seed: int = 4) -> tuple[Calibration, object]:
    """The simulated rig's true cameras with distortion, fx != fy and off-centre principal points."""
    rig = make_rig(seed=seed, pp_offset_px=25.0)
    cameras = []
    for cam, dist in zip(rig.cameras, DISTORTIONS, strict=True):
        K = cam.K.copy()
        K[1, 1] *= 1.002
        d = np.array(dist) if k3 else np.array([*dist[:4], 0.0])
        cameras.append(replace(cam, K=K, dist=d))
    rig = replace(rig, cameras=cameras)
    ids = np.arange(len(rig.points), dtype=np.int64) + 10
    return Calibration(tuple(cameras), ids, rig.points.copy(), 0.5, "left"), rig


def cv2_project(cam: Camera, X: np.ndarray) -> np.ndarray:
    """OpenCV's own projection, independent of camnet.model.projection.project."""
    rvec, _ = cv2.Rodrigues(cam.R)
    uv, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, cam.t.reshape(3, 1), cam.K, cam.dist)
    return uv.reshape(-1, 2)


# ---------------------------------------------------------------- OpenCV


def test_opencv_yaml_reads_back_with_filestorage():
    cal, _ = rig_calibration()
    text = opencv_yaml(cal)
    assert text.startswith("%YAML:1.0")
    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    assert fs.getNode("world_frame").string() == "left"
    assert fs.getNode("rms_reprojection_px").real() == cal.rms_reprojection_px
    assert int(fs.getNode("camera_count").real()) == len(cal.cameras)
    node = fs.getNode("cameras")
    assert node.size() == len(cal.cameras)
    for i, cam in enumerate(cal.cameras):
        c = node.at(i)
        assert c.getNode("id").string() == cam.id
        assert int(c.getNode("image_width").real()) == cam.width
        assert int(c.getNode("image_height").real()) == cam.height
        K, dist, R, t = (c.getNode(k).mat() for k in ("K", "dist", "R", "t"))
        # Every number exactly: FileStorage writes doubles with full precision.
        np.testing.assert_array_equal(K, cam.K)
        np.testing.assert_array_equal(dist.ravel(), cam.dist)
        np.testing.assert_array_equal(R, cam.R)
        np.testing.assert_array_equal(t.ravel(), cam.t)
        # The read-back values project through OpenCV exactly as camnet projects.
        rvec, _ = cv2.Rodrigues(R)
        uv, _ = cv2.projectPoints(cal.points.reshape(-1, 1, 3), rvec, t, K, dist)
        np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(cal.points), atol=1e-6)
    np.testing.assert_array_equal(fs.getNode("points").mat(), cal.points)
    np.testing.assert_array_equal(fs.getNode("point_ids").mat().ravel(), cal.point_ids)


def test_opencv_yaml_says_its_conventions_in_a_comment():
    cal, _ = rig_calibration()
    comments = [line for line in opencv_yaml(cal).splitlines() if line.startswith("#")]
    assert any("x_cam = R X + t" in c for c in comments)
    assert any("metres" in c for c in comments)
    assert any("world frame: the left stereo camera's (left)" in c for c in comments)


# ---------------------------------------------------------------- COLMAP


ENCODINGS = {"text": colmap_text, "binary": colmap_binary}


def write_model(tmp_path, files: dict[str, str | bytes]):
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap (the test extra) is not installed")
    for name, content in files.items():
        if isinstance(content, bytes):
            (tmp_path / name).write_bytes(content)
        else:
            (tmp_path / name).write_text(content)
    return pycolmap.Reconstruction(str(tmp_path))


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_colmap_model_reads_back_with_pycolmap(tmp_path, encoding):
    cal, _ = rig_calibration()
    rec = write_model(tmp_path, ENCODINGS[encoding](colmap_model(cal)))
    assert len(rec.cameras) == len(rec.images) == len(cal.cameras)
    expected_models = ["PINHOLE", "OPENCV", "FULL_OPENCV", "OPENCV"]
    for k, cam in enumerate(cal.cameras):
        ccam, image = rec.cameras[k + 1], rec.images[k + 1]
        assert ccam.model.name == expected_models[k]
        assert (ccam.width, ccam.height) == (cam.width, cam.height)
        assert image.name == cam.id and image.camera_id == k + 1
        np.testing.assert_allclose(ccam.focal_length_x, cam.K[0, 0], rtol=1e-15)
        np.testing.assert_allclose(ccam.focal_length_y, cam.K[1, 1], rtol=1e-15)
        # COLMAP's pixel origin is the corner of the top-left pixel, camnet's its centre.
        np.testing.assert_allclose(ccam.principal_point_x, cam.K[0, 2] + 0.5, rtol=1e-15)
        np.testing.assert_allclose(ccam.principal_point_y, cam.K[1, 2] + 0.5, rtol=1e-15)
        pose = image.cam_from_world()
        np.testing.assert_allclose(pose.rotation.matrix(), cam.R, atol=1e-12)
        np.testing.assert_allclose(pose.translation, cam.t, atol=1e-15)
        # COLMAP's own camera model, distortion included, lands on camnet's pixel (+0.5).
        x_cam = np.array([pose * X for X in cal.points])
        colmap_uv = ccam.img_from_cam(x_cam)
        np.testing.assert_allclose(colmap_uv - 0.5, cam.project(cal.points), atol=1e-6)
        np.testing.assert_allclose(colmap_uv - 0.5, cv2_project(cam, cal.points), atol=1e-6)
        assert len(image.points2D) == 0
    assert sorted(rec.points3D) == sorted(cal.point_ids.tolist())
    for pid, X in zip(cal.point_ids, cal.points, strict=True):
        point = rec.points3D[int(pid)]
        np.testing.assert_allclose(point.xyz, X, rtol=1e-15)
        assert point.track.length() == 0


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_colmap_tracks_link_the_observations_within_the_threshold(tmp_path, encoding):
    cal, rig = rig_calibration(seed=6)
    obs = observe(rig, noise_px=0.5, seed=6, outlier_fraction=0.1).observations
    obs = replace(obs, track_ids=obs.track_ids + 10)  # the calibration's point ids
    limit = 1.5
    rec = write_model(tmp_path, ENCODINGS[encoding](colmap_model(cal, obs, max_error_px=limit)))
    # Independently: which observations lie within the limit of their point's OpenCV projection.
    expected_tracks: dict[int, set] = {int(p): set() for p in cal.point_ids}
    expected_points2d = [[] for _ in cal.cameras]
    for cam_i, trk, uv in zip(obs.cam_index, obs.track_index, obs.uv, strict=True):
        pid = int(obs.track_ids[trk])
        proj = cv2_project(cal.cameras[cam_i], cal.points[pid - 10][None])[0]
        linked = np.linalg.norm(proj - uv) <= limit
        expected_points2d[cam_i].append((uv, pid if linked else None))
        if linked:
            expected_tracks[pid].add((cam_i + 1, len(expected_points2d[cam_i]) - 1))
    n_linked = sum(len(t) for t in expected_tracks.values())
    assert 0 < n_linked < len(obs.uv)  # some outliers stay unlinked
    for k in range(len(cal.cameras)):
        points2d = rec.images[k + 1].points2D
        assert len(points2d) == len(expected_points2d[k])
        for p2d, (uv, pid) in zip(points2d, expected_points2d[k], strict=True):
            np.testing.assert_allclose(p2d.xy - 0.5, uv, atol=1e-9)
            assert p2d.has_point3D() == (pid is not None)
            if pid is not None:
                assert p2d.point3D_id == pid
    for pid, expected in expected_tracks.items():
        point = rec.points3D[pid]
        got = {(el.image_id, el.point2D_idx) for el in point.track.elements}
        assert got == expected
        if expected:
            errors = [
                np.linalg.norm(
                    rec.images[i].points2D[j].xy - 0.5 - cv2_project(cal.cameras[i - 1], cal.points[pid - 10][None])[0]
                )
                for i, j in expected
            ]
            assert point.error == pytest.approx(np.mean(errors), rel=1e-6)


def test_colmap_rejects_skew_and_negative_ids():
    cal, _ = rig_calibration()
    K = cal.cameras[2].K.copy()
    K[0, 1] = 0.5
    skewed = replace(cal, cameras=(*cal.cameras[:2], replace(cal.cameras[2], K=K), *cal.cameras[3:]))
    with pytest.raises(InputError, match=r"cameras\[2\]\.K: skew"):
        colmap_model(skewed)
    with pytest.raises(InputError, match="non-negative"):
        colmap_model(replace(cal, point_ids=cal.point_ids - 100))


def test_colmap_binary_is_byte_for_byte_what_colmap_writes(tmp_path):
    """COLMAP's own binary writer, given the text model, writes exactly the bytes of the binary export."""
    cal, rig = rig_calibration(seed=6)
    obs = observe(rig, noise_px=0.5, seed=6, outlier_fraction=0.1).observations
    model = colmap_model(cal, replace(obs, track_ids=obs.track_ids + 10))
    (tmp_path / "text").mkdir()
    rec = write_model(tmp_path / "text", colmap_text(model))
    assert rec.num_points3D() == len(cal.points) and sum(len(rec.images[k + 1].points2D) for k in range(4)) > 200
    rec.write_binary(str(tmp_path))
    for name, content in colmap_binary(model).items():
        assert (tmp_path / name).read_bytes() == content, name


# ---------------------------------------------------------------- ROS


def test_ros_camera_info_matches_the_plumb_bob_model():
    cal, _ = rig_calibration()
    files = ros_camera_info(cal)
    assert sorted(files) == sorted(f"{c.id}.yaml" for c in cal.cameras)
    for cam in cal.cameras:
        doc = yaml.safe_load(files[f"{cam.id}.yaml"])
        assert (doc["image_width"], doc["image_height"], doc["camera_name"]) == (cam.width, cam.height, cam.id)
        assert doc["distortion_model"] == "plumb_bob"
        mats = {}
        for key, shape in [
            ("camera_matrix", (3, 3)),
            ("distortion_coefficients", (1, 5)),
            ("rectification_matrix", (3, 3)),
            ("projection_matrix", (3, 4)),
        ]:
            assert (doc[key]["rows"], doc[key]["cols"]) == shape
            mats[key] = np.array(doc[key]["data"]).reshape(shape)
        np.testing.assert_array_equal(mats["camera_matrix"], cam.K)
        np.testing.assert_array_equal(mats["distortion_coefficients"].ravel(), cam.dist)
        # ROS's meaning of R and P: undistorting and rectifying the raw pixel with (K, D, R, P)
        # gives P applied to the point in the camera frame (image_geometry's projection).
        raw = cam.project(cal.points)
        rect = cv2.undistortPoints(
            raw.reshape(-1, 1, 2),
            mats["camera_matrix"],
            mats["distortion_coefficients"],
            R=mats["rectification_matrix"],
            P=mats["projection_matrix"],
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
        ).reshape(-1, 2)
        x_cam = cal.points @ cam.R.T + cam.t
        h = np.hstack([x_cam, np.ones((len(x_cam), 1))]) @ mats["projection_matrix"].T
        np.testing.assert_allclose(rect, h[:, :2] / h[:, 2:], atol=1e-3)


# ---------------------------------------------------------------- Kalibr


def test_kalibr_chain_reproduces_each_pose_relative_to_cam0():
    cal, _ = rig_calibration(k3=False)
    text = kalibr_camchain(cal)
    doc = yaml.safe_load(text)
    # Kalibr counts the cameras by the top-level keys: nothing else may be there.
    assert list(doc) == [f"cam{n}" for n in range(len(cal.cameras))]

    def T(cam):
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = cam.R, cam.t
        return out

    chained = np.eye(4)  # T_cn_c0
    for n, cam in enumerate(cal.cameras):
        entry = doc[f"cam{n}"]
        # The types Kalibr's reader insists on.
        assert entry["camera_model"] == "pinhole" and entry["distortion_model"] == "radtan"
        assert all(isinstance(x, float) for x in entry["intrinsics"] + entry["distortion_coeffs"])
        assert all(isinstance(x, int) for x in entry["resolution"])
        assert entry["intrinsics"] == [cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]]
        assert entry["distortion_coeffs"] == cam.dist[:4].tolist()
        assert entry["resolution"] == [cam.width, cam.height]
        assert entry["rostopic"] == f"/{cam.id}/image_raw"
        assert n not in entry["cam_overlaps"] and set(entry["cam_overlaps"]) <= set(range(len(cal.cameras)))
        if n == 0:
            assert "T_cn_cnm1" not in entry
            continue
        T_step = np.array(entry["T_cn_cnm1"])
        np.testing.assert_array_equal(T_step[3], [0, 0, 0, 1])
        chained = T_step @ chained
        np.testing.assert_allclose(chained, T(cam) @ np.linalg.inv(T(cal.cameras[0])), atol=1e-12)
    # cam1 sits one baseline from cam0, as the stereo pair.
    np.testing.assert_allclose(np.linalg.norm(np.array(doc["cam1"]["T_cn_cnm1"])[:3, 3]), 0.125, rtol=1e-12)


def test_kalibr_rejects_k3():
    cal, _ = rig_calibration(k3=True)
    with pytest.raises(InputError, match=r"cameras\[2\]\.dist: k3"):
        kalibr_camchain(cal)


def test_export_checks_format_and_observations():
    cal, rig = rig_calibration()
    with pytest.raises(InputError, match="unknown format 'bundler'"):
        export(cal, "bundler")
    with pytest.raises(InputError, match="--observations"):
        export(cal, "opencv", observations=observe(rig).observations)


# ---------------------------------------------------------------- the command


def run_camnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], capture_output=True, text=True, timeout=120)


@pytest.fixture()
def files(tmp_path):
    cal, rig = rig_calibration(k3=False)
    obs = observe(rig, noise_px=0.3, seed=1).observations
    obs = replace(obs, track_ids=obs.track_ids + 10)
    cal_path, obs_path = tmp_path / "cal.json", tmp_path / "obs.json"
    cal_path.write_text(json.dumps(calibration_to_doc(cal)))
    obs_path.write_text(json.dumps(observations_to_doc(obs)))
    return cal, cal_path, obs_path


def test_command_writes_every_format(tmp_path, files):
    cal, cal_path, obs_path = files
    for fmt, extra, expected in [
        ("opencv", [], ["cal.yaml"]),
        ("kalibr", [], ["cal.yaml"]),
        ("ros", [], [f"{c.id}.yaml" for c in cal.cameras]),
        ("colmap", ["--observations", str(obs_path)], ["cameras.txt", "images.txt", "points3D.txt"]),
        ("colmap-bin", ["--observations", str(obs_path)], ["cameras.bin", "images.bin", "points3D.bin"]),
        ("anipose", ["--unit", "mm"], ["calibration.toml"]),
        ("ply", [], ["points.ply"]),
    ]:
        one_file = {"opencv": "cal.yaml", "kalibr": "cal.yaml", "anipose": "calibration.toml", "ply": "points.ply"}
        out = tmp_path / fmt / one_file.get(fmt, "model")
        out.parent.mkdir()
        proc = run_camnet("export", str(cal_path), "--to", fmt, "-o", str(out), *extra)
        assert proc.returncode == 0, proc.stderr
        assert sorted(p.name for p in (out.parent if out.suffix else out).iterdir()) == sorted(expected)
    assert "4 OPENCV" in (tmp_path / "colmap" / "model" / "cameras.txt").read_text()
    rec = write_model(tmp_path / "colmap-bin" / "model", {})
    assert rec.num_points3D() == len(cal.points) and rec.cameras[4].model.name == "OPENCV"
    anipose = tomllib.loads((tmp_path / "anipose" / "calibration.toml").read_text())
    np.testing.assert_allclose(anipose["cam_1"]["translation"], 1000.0 * cal.cameras[1].t, rtol=1e-15)
    assert (tmp_path / "ply" / "points.ply").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    # An existing directory as -o of a one-file format gets the default name.
    proc = run_camnet("export", str(cal_path), "--to", "kalibr", "-o", str(tmp_path / "kalibr"))
    assert proc.returncode == 0, proc.stderr
    assert yaml.safe_load((tmp_path / "kalibr" / "camchain.yaml").read_text())["cam0"]["rostopic"] == "/left/image_raw"


def test_command_bad_input_is_one_line_and_writes_nothing(tmp_path, files):
    _, cal_path, obs_path = files
    broken = tmp_path / "broken.json"
    broken.write_text(cal_path.read_text().replace('"K"', '"Kx"', 1))
    blocker = tmp_path / "blocker"
    blocker.write_text("keep me")
    out = tmp_path / "out"
    cases = [
        (["--to", "bundler", "-o", str(out)], "unknown format 'bundler'"),
        (["--to", "opencv", "-o", str(out), "--observations", str(obs_path)], "--observations"),
        (["--to", "colmap", "-o", str(blocker)], "exists and is not a directory"),
        (["--to", "colmap", "-o", str(tmp_path / "missing" / "model")], "does not exist"),
        (["--to", "ply", "-o", str(out), "--unit", "mm"], "--unit: only the anipose export uses it"),
        (["--to", "anipose", "-o", str(out), "--max-error-px", "2"], "--max-error-px: only the colmap exports"),
    ]
    for args, message in cases:
        proc = run_camnet("export", str(cal_path), *args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
    proc = run_camnet("export", str(broken), "--to", "opencv", "-o", str(out))
    assert proc.returncode == 2 and "cameras[0].K: missing" in proc.stderr and proc.stderr.count("\n") == 1
    assert not out.exists()
    assert blocker.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker", "broken.json", "cal.json", "obs.json"]


# ---------------------------------------------------------------- the fisheye model in every export


def fisheye_calibration() -> Calibration:
    """The fisheye family's true cameras (160-degree lenses) with fx != fy and off-centre principal points."""
    rig = family("fisheye", seed=3).rig
    cameras = []
    for k, cam in enumerate(rig.cameras):
        K = cam.K.copy()
        K[1, 1] *= 1.002
        K[:2, 2] += [3.0 * k - 4.0, 2.0 - k]
        cameras.append(replace(cam, K=K))
    return Calibration(tuple(cameras), np.arange(len(rig.points)) + 10, rig.points.copy(), 0.5, "left")


def in_image(cam: Camera, X: np.ndarray) -> np.ndarray:
    """The points of X (n, 3) that `cam` sees inside its image: the ones an export must reproject."""
    uv = cam.project(X)
    inside = np.all((uv >= 0) & (uv <= [cam.width - 1, cam.height - 1]), axis=1)
    assert inside.sum() > 100
    return X[inside]


def test_fisheye_opencv_yaml_projects_with_cv2_fisheye():
    cal = fisheye_calibration()
    fs = cv2.FileStorage(opencv_yaml(cal), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    for i, cam in enumerate(cal.cameras):
        c = fs.getNode("cameras").at(i)
        assert c.getNode("distortion_model").string() == "fisheye"
        K, D, R, t = (c.getNode(k).mat() for k in ("K", "dist", "R", "t"))
        assert D.shape == (1, 4)
        X = in_image(cam, cal.points)
        uv, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], t, K, D)
        np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(X), atol=1e-6)
    assert cv2.FileStorage(opencv_yaml(rig_calibration()[0]), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY).getNode(
        "cameras").at(0).getNode("distortion_model").string() == "pinhole"


def test_fisheye_colmap_camera_is_opencv_fisheye_read_by_pycolmap(tmp_path):
    cal = fisheye_calibration()
    rec = write_model(tmp_path, colmap_binary(colmap_model(cal)))
    for k, cam in enumerate(cal.cameras):
        ccam = rec.cameras[k + 1]
        assert ccam.model.name == "OPENCV_FISHEYE"
        np.testing.assert_array_equal(ccam.params[4:], cam.dist)
        X = in_image(cam, cal.points)
        pose = rec.images[k + 1].cam_from_world()
        colmap_uv = ccam.img_from_cam(np.array([pose * x for x in X]))
        np.testing.assert_allclose(colmap_uv - 0.5, cam.project(X), atol=1e-6)


def test_fisheye_ros_camera_info_is_equidistant():
    cal = fisheye_calibration()
    files = ros_camera_info(cal)
    for cam in cal.cameras:
        doc = yaml.safe_load(files[f"{cam.id}.yaml"])
        assert doc["distortion_model"] == "equidistant"
        assert (doc["distortion_coefficients"]["rows"], doc["distortion_coefficients"]["cols"]) == (1, 4)
        K, D, R, P = (
            np.array(doc[key]["data"]).reshape(doc[key]["rows"], doc[key]["cols"])
            for key in ("camera_matrix", "distortion_coefficients", "rectification_matrix", "projection_matrix")
        )
        # image_geometry's equidistant rectification (cv2.fisheye with K, D, R, P) of camnet's pixel is P x_cam.
        X = in_image(cam, cal.points)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        rect = cv2.fisheye.undistortPoints(cam.project(X).reshape(-1, 1, 2), K, D, R=R, P=P, criteria=criteria)
        h = np.hstack([X @ cam.R.T + cam.t, np.ones((len(X), 1))]) @ P.T
        np.testing.assert_allclose(rect.reshape(-1, 2), h[:, :2] / h[:, 2:], rtol=1e-6)


def test_fisheye_kalibr_camera_is_pinhole_equi():
    cal = fisheye_calibration()
    doc = yaml.safe_load(kalibr_camchain(cal))
    for n, cam in enumerate(cal.cameras):
        entry = doc[f"cam{n}"]
        assert (entry["camera_model"], entry["distortion_model"]) == ("pinhole", "equidistant")
        fu, fv, pu, pv = entry["intrinsics"]
        K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
        X = in_image(cam, cal.points)
        x_cam = X @ cam.R.T + cam.t
        uv, _ = cv2.fisheye.projectPoints(x_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                          np.array(entry["distortion_coeffs"]))
        np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(X), atol=1e-6)
