"""A calibration in the formats of the tools people calibrate with today.

Every exporter is a pure function from a `Calibration` to ``{file name: text}``;
the `export` command writes the files. camnet's conventions (see
camnet/geometry/projection.py): ``x_cam = R @ X_world + t`` with the world the left stereo
camera's frame, lengths in metres, ``K`` in pixels with the origin at the
centre of the top-left pixel, distortion in OpenCV's order
``[k1, k2, p1, p2, k3]``, or ``[k1, k2, k3, k4]`` for a camera with the
fisheye lens model (OpenCV's fisheye, which COLMAP calls OPENCV_FISHEYE,
ROS and Kalibr equidistant). Each exporter's docstring says what it changes.
"""

from __future__ import annotations

import math
import re

import numpy as np

from camnet.errors import InputError
from camnet.geometry.model import Calibration, LensModel, Observations

FORMATS = ("opencv", "colmap", "ros", "kalibr")
# COLMAP puts the pixel origin at the top-left corner of the top-left pixel, camnet at its centre.
COLMAP_PIXEL_SHIFT = 0.5
SKEW_TOLERANCE = 1e-9
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def export(
    cal: Calibration, fmt: str, *, observations: Observations | None = None, max_error_px: float | None = None
) -> dict[str, str]:
    """``{file name: text}`` of `cal` in `fmt` (one of `FORMATS`).

    Only the COLMAP export uses `observations` and `max_error_px` (its 2-D
    tracks; see `colmap_model`).
    """
    if fmt not in FORMATS:
        raise InputError(f"--to: unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if observations is not None and fmt != "colmap":
        raise InputError(f"--observations: the {fmt} export does not use observations (only colmap does)")
    if fmt == "opencv":
        return {"calibration.yaml": opencv_yaml(cal)}
    if fmt == "colmap":
        return colmap_model(cal, observations, max_error_px=max_error_px)
    if fmt == "ros":
        return ros_camera_info(cal)
    return {"camchain.yaml": kalibr_camchain(cal)}


def is_multi_file(fmt: str) -> bool:
    """Whether `fmt` writes a directory rather than one file."""
    return fmt in ("colmap", "ros")


def safe_names(cal: Calibration) -> list[str]:
    """Camera ids made safe for file names, COLMAP image names and ROS topics (one per camera)."""
    names = [_UNSAFE.sub("_", cam.id) for cam in cal.cameras]
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise InputError(f"cameras[{i}].id: {cal.cameras[i].id!r} clashes with another camera once made file-safe")
    return names


def _num(x: float) -> str:
    """Shortest text that reads back as exactly the same double."""
    return repr(float(x))


def _require_zero_skew(cal: Calibration, what: str) -> None:
    for i, cam in enumerate(cal.cameras):
        if abs(cam.K[0, 1]) > SKEW_TOLERANCE * cam.K[0, 0]:
            raise InputError(f"cameras[{i}].K: skew {cam.K[0, 1]:g} px has no place in {what}")


# ---------------------------------------------------------------- OpenCV


def opencv_yaml(cal: Calibration) -> str:
    """OpenCV FileStorage YAML (``%YAML:1.0``), written by OpenCV itself.

    Per camera (a sequence ``cameras``): ``id``, ``image_width``,
    ``image_height``, ``distortion_model`` (``pinhole`` or ``fisheye``), ``K``
    (3x3, pixels, origin at the centre of the top-left pixel, as OpenCV),
    ``dist`` (1x5, ``[k1, k2, p1, p2, k3]``; a fisheye's 1x4, ``[k1, k2, k3,
    k4]``), ``R`` (3x3) and ``t`` (3x1, m) with ``x_cam = R X + t``: the
    world-to-camera transform that ``cv2.projectPoints(X,
    cv2.Rodrigues(R)[0], t, K, dist)`` expects (``cv2.fisheye.projectPoints``
    for a fisheye).
    Also ``points`` (Nx3, m, world frame), ``point_ids`` (Nx1) and the
    calibration's ``world_frame`` and ``rms_reprojection_px``. No conversion:
    camnet uses OpenCV's conventions.
    """
    import cv2

    # OpenCV 5 writes YAML 1.2 unless asked; the 1.0 flavour is what every OpenCV reads.
    yaml_flavour = getattr(cv2, "FILE_STORAGE_FORMAT_YAML_1_0", cv2.FILE_STORAGE_FORMAT_YAML)
    fs = cv2.FileStorage("calibration.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | yaml_flavour)
    fs.write("format", "opencv export of camnet.calibration/1")
    fs.write("world_frame", cal.world_frame)
    fs.write("units", "m")
    if math.isfinite(cal.rms_reprojection_px):
        fs.write("rms_reprojection_px", float(cal.rms_reprojection_px))
    fs.write("camera_count", len(cal.cameras))
    fs.startWriteStruct("cameras", cv2.FILE_NODE_SEQ)
    for cam in cal.cameras:
        fs.startWriteStruct("", cv2.FILE_NODE_MAP)
        fs.write("id", cam.id)
        fs.write("image_width", int(cam.width))
        fs.write("image_height", int(cam.height))
        fs.write("distortion_model", cam.model.value)
        fs.write("K", np.asarray(cam.K, dtype=np.float64))
        fs.write("dist", np.asarray(cam.dist, dtype=np.float64).reshape(1, -1))
        fs.write("R", np.asarray(cam.R, dtype=np.float64))
        fs.write("t", np.asarray(cam.t, dtype=np.float64).reshape(3, 1))
        fs.endWriteStruct()
    fs.endWriteStruct()
    if len(cal.points):
        fs.write("point_ids", np.asarray(cal.point_ids, dtype=np.int32).reshape(-1, 1))
        fs.write("points", np.asarray(cal.points, dtype=np.float64).reshape(-1, 3))
    return fs.releaseAndGetString()


# ---------------------------------------------------------------- COLMAP


def colmap_camera(K: np.ndarray, dist: np.ndarray, model: LensModel = LensModel.PINHOLE) -> tuple[str, list[float]]:
    """COLMAP camera model and parameters for `K` and OpenCV `dist` of the lens `model`.

    PINHOLE ``fx fy cx cy`` without distortion, OPENCV ``... k1 k2 p1 p2``
    when k3 is zero, FULL_OPENCV ``... k1 k2 p1 p2 k3 k4 k5 k6`` (k4..k6 = 0)
    otherwise; a fisheye is OPENCV_FISHEYE ``... k1 k2 k3 k4``, the same
    model. The principal point moves by +0.5 px: COLMAP's pixel origin is
    the top-left corner of the top-left pixel.
    """
    fx, fy = float(K[0, 0]), float(K[1, 1])
    cx, cy = float(K[0, 2]) + COLMAP_PIXEL_SHIFT, float(K[1, 2]) + COLMAP_PIXEL_SHIFT
    if model == LensModel.FISHEYE:
        return "OPENCV_FISHEYE", [fx, fy, cx, cy, *(float(x) for x in dist)]
    k1, k2, p1, p2, k3 = (float(x) for x in dist)
    if not any((k1, k2, p1, p2, k3)):
        return "PINHOLE", [fx, fy, cx, cy]
    if k3 == 0.0:
        return "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
    return "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]


def colmap_quaternion(R: np.ndarray) -> np.ndarray:
    """``[qw, qx, qy, qz]`` (Hamilton, qw >= 0) of the rotation matrix `R`."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat(canonical=True)
    return np.array([w, x, y, z])


def colmap_model(
    cal: Calibration, observations: Observations | None = None, *, max_error_px: float | None = None
) -> dict[str, str]:
    """COLMAP's text model: ``cameras.txt``, ``images.txt``, ``points3D.txt``.

    - Camera and image ``k + 1`` are ``cal.cameras[k]``; the image NAME is the
      camera id (file-safe). Intrinsics: see `colmap_camera`.
    - ``QW QX QY QZ TX TY TZ`` is COLMAP's ``cam_from_world``, the same
      world-to-camera transform as camnet's ``x_cam = R X + t``: the quaternion
      of ``R`` and ``t`` in metres, unchanged.
    - POINT3D_ID is camnet's track id (must be >= 0); XYZ in metres; colour grey.
    - With `observations`, every observation becomes a 2-D point of its image
      (``u + 0.5, v + 0.5``); one of a kept point whose reprojection error is
      at most `max_error_px` (default: `camnet.geometry.residuals.outlier_limit_px`) joins that
      point's track, others get POINT3D_ID -1. ERROR is the track's mean
      reprojection error in pixels. Without observations the images have no
      2-D points, the tracks are empty and ERROR is -1 (COLMAP's "unknown"):
      COLMAP reads such a model, but tools that need tracks will not use it.
    """
    _require_zero_skew(cal, "COLMAP's camera models")
    names = safe_names(cal)
    if len(cal.point_ids) and int(np.min(cal.point_ids)) < 0:
        raise InputError("points: COLMAP needs non-negative point ids")

    cams = [f"# Camera list: CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n# Number of cameras: {len(cal.cameras)}\n"]
    for k, cam in enumerate(cal.cameras):
        model, params = colmap_camera(cam.K, cam.dist, cam.model)
        cams.append(f"{k + 1} {model} {cam.width} {cam.height} {' '.join(_num(p) for p in params)}\n")

    points2d: list[list[str]] = [[] for _ in cal.cameras]
    tracks: list[list[str]] = [[] for _ in cal.point_ids]
    track_errors: list[list[float]] = [[] for _ in cal.point_ids]
    if observations is not None:
        _link_observations(cal, observations, max_error_px, points2d, tracks, track_errors)

    images = [
        "# Image list: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then POINTS2D[] as (X, Y, POINT3D_ID)\n"
        f"# Number of images: {len(cal.cameras)}\n"
    ]
    for k, cam in enumerate(cal.cameras):
        pose = [*colmap_quaternion(cam.R), *np.asarray(cam.t, dtype=float)]
        images.append(f"{k + 1} {' '.join(_num(x) for x in pose)} {k + 1} {names[k]}\n")
        images.append(" ".join(points2d[k]) + "\n")

    points = [
        "# 3D point list: POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        f"# Number of points: {len(cal.point_ids)}\n"
    ]
    for j, (pid, xyz) in enumerate(zip(cal.point_ids, cal.points, strict=True)):
        error = float(np.mean(track_errors[j])) if track_errors[j] else -1.0
        fields = [str(int(pid)), *(_num(x) for x in xyz), "128", "128", "128", _num(error), *tracks[j]]
        points.append(" ".join(fields) + "\n")
    return {"cameras.txt": "".join(cams), "images.txt": "".join(images), "points3D.txt": "".join(points)}


def _link_observations(cal, observations, max_error_px, points2d, tracks, track_errors) -> None:
    from camnet.geometry.residuals import outlier_limit_px, reprojection_residuals

    res = reprojection_residuals(cal, observations)
    limit = outlier_limit_px(cal) if max_error_px is None else max_error_px
    error = res.error_px
    linked_point = np.full(len(observations.uv), -1, dtype=np.int64)
    ok = np.isfinite(error) & (error <= limit)
    linked_point[res.obs_row[ok]] = res.point_index[ok]
    error_of_row = np.full(len(observations.uv), np.nan)
    error_of_row[res.obs_row] = error
    cal_index = {cam.id: k for k, cam in enumerate(cal.cameras)}
    for row, (cam, uv) in enumerate(zip(observations.cam_index, observations.uv, strict=True)):
        k = cal_index[observations.cameras[cam].id]
        j = linked_point[row]
        pid = int(cal.point_ids[j]) if j >= 0 else -1
        if j >= 0:
            tracks[j].append(f"{k + 1} {len(points2d[k])}")
            track_errors[j].append(float(error_of_row[row]))
        points2d[k].append(f"{_num(uv[0] + COLMAP_PIXEL_SHIFT)} {_num(uv[1] + COLMAP_PIXEL_SHIFT)} {pid}")


# ---------------------------------------------------------------- ROS


def _ros_matrix(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(x) for x in np.asarray(data, dtype=float).ravel()]}


def ros_camera_info(cal: Calibration) -> dict[str, str]:
    """One ROS ``camera_info`` YAML per camera (camera_calibration_parsers' format), ``<id>.yaml``.

    ``camera_matrix`` is K and ``distortion_coefficients`` the plumb_bob
    ``[k1, k2, p1, p2, k3]``, both as camnet (ROS shares OpenCV's pixel
    convention); a fisheye's are the ``equidistant`` model's ``[k1, k2, k3,
    k4]`` (image_geometry undistorts them with cv2.fisheye). Each camera is described alone, as a monocular calibration:
    ``rectification_matrix`` is the identity and ``projection_matrix`` is
    ``[K | 0]``. The poses are not part of camera_info (ROS keeps them in tf).
    """
    import yaml

    out = {}
    for cam, name in zip(cal.cameras, safe_names(cal), strict=True):
        doc = {
            "image_width": int(cam.width),
            "image_height": int(cam.height),
            "camera_name": name,
            "camera_matrix": _ros_matrix(3, 3, cam.K),
            "distortion_model": "equidistant" if cam.model == LensModel.FISHEYE else "plumb_bob",
            "distortion_coefficients": _ros_matrix(1, len(cam.dist), cam.dist),
            "rectification_matrix": _ros_matrix(3, 3, np.eye(3)),
            "projection_matrix": _ros_matrix(3, 4, np.hstack([cam.K, np.zeros((3, 1))])),
        }
        out[f"{name}.yaml"] = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=1000)
    return out


# ---------------------------------------------------------------- Kalibr


def world_from_cam_4x4(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 4x4 homogeneous inverse of ``x_cam = R X + t``."""
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ t
    return T


def cam_from_world_4x4(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 4x4 homogeneous transform of ``x_cam = R X + t``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def overlapping_cameras(cal: Calibration) -> list[list[int]]:
    """Per camera, the other cameras that see at least one common point (in front, inside the image)."""
    seen = []
    for cam in cal.cameras:
        uv = cam.project(cal.points) if len(cal.points) else np.zeros((0, 2))
        inside = np.isfinite(uv).all(axis=1)
        inside &= (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5)
        inside &= (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5)
        seen.append(inside)
    return [[j for j in range(len(seen)) if j != i and np.any(seen[i] & seen[j])] for i in range(len(seen))]


def kalibr_camchain(cal: Calibration) -> str:
    """Kalibr's camchain YAML: ``cam0`` .. ``camN`` in the calibration's camera order.

    Per camera: ``camera_model: pinhole``, ``intrinsics: [fu, fv, pu, pv]``
    (pixels, OpenCV's pixel convention as camnet), ``distortion_model:
    radtan`` with ``distortion_coeffs: [k1, k2, r1, r2]`` (OpenCV's k1 k2 p1
    p2; radtan has no k3, so a non-zero k3 is an error), or for a fisheye
    ``equidistant`` (Kalibr's pinhole-equi, OpenCV's fisheye model) with
    ``[k1, k2, k3, k4]``, ``resolution: [w,
    h]``, ``rostopic: /<id>/image_raw`` and ``cam_overlaps`` (see
    `overlapping_cameras`). From cam1 on, ``T_cn_cnm1`` is the 4x4 transform
    taking a point from the previous camera's frame to this camera's frame
    (metres): ``T_n @ inv(T_{n-1})`` with ``T_k`` camnet's ``[R_k | t_k]``.
    """
    import yaml

    _require_zero_skew(cal, "Kalibr's pinhole model")
    names = safe_names(cal)
    overlaps = overlapping_cameras(cal)
    chain = {}
    for n, cam in enumerate(cal.cameras):
        fisheye = cam.model == LensModel.FISHEYE
        if not fisheye and cam.dist[4] != 0.0:
            raise InputError(f"cameras[{n}].dist: k3 = {cam.dist[4]:g} has no place in Kalibr's radtan model")
        entry = {
            "camera_model": "pinhole",
            "intrinsics": [float(cam.K[0, 0]), float(cam.K[1, 1]), float(cam.K[0, 2]), float(cam.K[1, 2])],
            "distortion_model": "equidistant" if fisheye else "radtan",
            "distortion_coeffs": [float(x) for x in cam.dist[:4]],
            "resolution": [int(cam.width), int(cam.height)],
            "rostopic": f"/{names[n]}/image_raw",
            "cam_overlaps": overlaps[n],
        }
        if n > 0:
            prev = cal.cameras[n - 1]
            T = cam_from_world_4x4(cam.R, cam.t) @ world_from_cam_4x4(prev.R, prev.t)
            entry["T_cn_cnm1"] = [[float(x) for x in row] for row in T]
        chain[f"cam{n}"] = entry
    header = "".join(f"# cam{n}: camnet camera {cam.id}\n" for n, cam in enumerate(cal.cameras))
    return header + yaml.safe_dump(chain, sort_keys=False, default_flow_style=None, width=1000)
