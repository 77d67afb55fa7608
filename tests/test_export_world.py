"""Exports of a calibration with a floor frame are written in it, as its document is; one without, in the left
camera's frame, as before."""

from __future__ import annotations

import io
import json
import tomllib
from dataclasses import replace

import cv2
import numpy as np
import pytest
import yaml

from camnet.io.export import export
from camnet.io.formats import calibration_to_doc
from camnet.io.messages import CalibrationMessage
from camnet.io.run_dir import write_results
from camnet.model.calibration import Calibration
from camnet.solve.world_frame import floor_frame, world_frame
from tests.test_export import write_model
from tests.test_world_frame import calibration, room

FLOOR_POINTS = 400  # room()'s first points lie on its floor
EXACT_M = 1e-9
HEIGHT_TOLERANCE_M = 0.01  # the floor is fitted to points with 2 mm of noise


@pytest.fixture(scope="module")
def floored() -> tuple[Calibration, np.ndarray]:
    """A calibration of room() with the floor frame found from its points, and each camera's true height (m) above
    the floor, measured along the room's true up from its floor points, apart from the frame's fit."""
    cameras, points, up = room(4, floor=FLOOR_POINTS)
    cal = calibration(cameras, points)
    cal = replace(cal, floor_frame=floor_frame(world_frame(cal, x_toward=("cam1", "cam2"))))
    floor_level = np.median(points[:FLOOR_POINTS] @ up)
    return cal, np.array([cam.centre @ up for cam in cameras]) - floor_level


def document(cal: Calibration) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, dict]:
    """The poses ``(R, t)`` and points of the calibration's JSON document, read back from its text."""
    doc = json.loads(json.dumps(calibration_to_doc(cal)))
    poses = [(np.array(c["R"]), np.array(c["t"])) for c in doc["cameras"]]
    return poses, np.array([p["xyz"] for p in doc["points"]]).reshape(-1, 3), doc


def check_in_document_frame(cal: Calibration, poses: list[tuple[np.ndarray, np.ndarray]], points: np.ndarray) -> None:
    """The exported poses and points are the document's, to EXACT_M."""
    want_poses, want_points, _ = document(cal)
    assert len(poses) == len(want_poses)
    for (R, t), (want_R, want_t) in zip(poses, want_poses, strict=True):
        np.testing.assert_allclose(R, want_R, rtol=0, atol=EXACT_M)
        np.testing.assert_allclose(t, want_t, rtol=0, atol=EXACT_M)
    np.testing.assert_allclose(points, want_points, rtol=0, atol=EXACT_M)


def check_heights(poses: list[tuple[np.ndarray, np.ndarray]], heights: np.ndarray) -> None:
    """Each camera's centre ``-R^T t`` has Z its height above the floor: Z up, the floor at Z = 0."""
    centres = np.array([-R.T @ t for R, t in poses])
    np.testing.assert_allclose(centres[:, 2], heights, rtol=0, atol=HEIGHT_TOLERANCE_M)


def read_opencv(text: str) -> tuple[cv2.FileStorage, list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    node = fs.getNode("cameras")
    poses = [(node.at(i).getNode("R").mat(), node.at(i).getNode("t").mat().ravel()) for i in range(node.size())]
    return fs, poses, fs.getNode("points").mat().reshape(-1, 3)


def read_colmap(rec) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray]:
    """The poses, point ids and points of a pycolmap.Reconstruction."""
    poses = []
    for k in range(len(rec.images)):
        pose = rec.images[k + 1].cam_from_world()
        poses.append((pose.rotation.matrix(), np.asarray(pose.translation)))
    ids = np.array(sorted(rec.points3D))
    return poses, ids, np.array([rec.points3D[int(i)].xyz for i in ids]).reshape(-1, 3)


def test_opencv_export_is_in_the_floor_frame_and_says_so(floored):
    cal, heights = floored
    fs, poses, points = read_opencv(export(cal, "opencv")["calibration.yaml"])
    check_in_document_frame(cal, poses, points)
    check_heights(poses, heights)
    assert fs.getNode("world_frame").string() == "floor"
    _, _, doc = document(cal)
    world_from_left = fs.getNode("world_from_left")
    np.testing.assert_array_equal(world_from_left.getNode("R").mat(), doc["world_from_left"]["R"])
    np.testing.assert_array_equal(world_from_left.getNode("t").mat().ravel(), doc["world_from_left"]["t"])


@pytest.mark.parametrize("fmt", ["colmap", "colmap-bin"])
def test_colmap_export_is_in_the_floor_frame(tmp_path, floored, fmt):
    cal, heights = floored
    poses, ids, points = read_colmap(write_model(tmp_path, export(cal, fmt)))
    np.testing.assert_array_equal(ids, cal.point_ids)  # in their order: the document's points are in it too
    check_in_document_frame(cal, poses, points)
    check_heights(poses, heights)


def test_ply_export_is_in_the_floor_frame(floored):
    plyfile = pytest.importorskip("plyfile", reason="plyfile (the test extra) is not installed")
    cal, _ = floored
    ply = plyfile.PlyData.read(io.BytesIO(export(cal, "ply")["points.ply"]))
    vertex = ply["vertex"]
    points = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    want_poses, _, _ = document(cal)
    check_in_document_frame(cal, want_poses, points)
    assert np.median(np.abs(points[:FLOOR_POINTS, 2])) < 0.003  # the floor's points at Z = 0
    assert any("world frame floor" in c for c in ply.comments)


def test_anipose_export_is_in_the_floor_frame_and_keeps_world_from_left(floored):
    cal, heights = floored
    toml = tomllib.loads(export(cal, "anipose")["calibration.toml"])
    poses = [(cv2.Rodrigues(np.array(toml[f"cam_{k}"]["rotation"]))[0], np.array(toml[f"cam_{k}"]["translation"]))
             for k in range(len(cal.cameras))]
    _, points, doc = document(cal)
    check_in_document_frame(cal, poses, points)
    check_heights(poses, heights)
    assert toml["metadata"]["world_frame"] == "floor"
    np.testing.assert_array_equal(toml["metadata"]["world_from_left_R"], doc["world_from_left"]["R"])
    np.testing.assert_array_equal(toml["metadata"]["world_from_left_t"], doc["world_from_left"]["t"])


def test_relative_and_pose_free_exports_are_the_same_in_any_world_frame(floored):
    cal, _ = floored
    plain = replace(cal, floor_frame=None)
    assert export(cal, "ros") == export(plain, "ros")  # camera_info holds no pose
    chain, plain_chain = (yaml.safe_load(export(c, "kalibr")["camchain.yaml"]) for c in (cal, plain))
    assert list(chain) == list(plain_chain)
    for name in chain:
        assert chain[name]["cam_overlaps"] == plain_chain[name]["cam_overlaps"]
        if "T_cn_cnm1" in chain[name]:
            np.testing.assert_allclose(chain[name]["T_cn_cnm1"], plain_chain[name]["T_cn_cnm1"], rtol=0, atol=1e-12)


def test_without_its_floor_frame_a_calibration_exports_the_left_cameras_frame(tmp_path, floored):
    cal, _ = floored
    plain = replace(cal, floor_frame=None)
    held = [(cam.R, cam.t) for cam in plain.cameras]
    fs, poses, points = read_opencv(export(plain, "opencv")["calibration.yaml"])
    assert fs.getNode("world_frame").string() == "cam0" and fs.getNode("world_from_left").empty()
    check_in_document_frame(plain, poses, points)
    check_in_document_frame(plain, held, plain.points)  # the document too is in the frame held
    poses, _, points = read_colmap(write_model(tmp_path, export(plain, "colmap")))
    check_in_document_frame(plain, poses, points)
    np.testing.assert_allclose(poses[0][0], np.eye(3), atol=1e-12)  # the left camera at the origin, unturned
    np.testing.assert_allclose(poses[0][1], 0.0, atol=1e-12)


def test_the_run_directorys_exports_are_in_the_floor_frame(tmp_path, floored):
    cal, heights = floored
    write_results(tmp_path, CalibrationMessage(cal, frame_sets=1, latest_capture_ns=1), None)
    doc = json.loads((tmp_path / "calibration.json").read_text())
    assert doc["world_frame"] == "floor"
    np.testing.assert_array_equal([p["xyz"] for p in doc["points"]], document(cal)[1])
    fs, poses, points = read_opencv((tmp_path / "calibration.yaml").read_text())
    check_in_document_frame(cal, poses, points)
    check_heights(poses, heights)
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap (the test extra) is not installed")
    poses, _, points = read_colmap(pycolmap.Reconstruction(str(tmp_path / "colmap")))
    check_in_document_frame(cal, poses, points)
