"""A calibration in the formats of the tools people calibrate and measure with.

Every exporter is a pure function from a `Calibration` to ``{file name:
content}`` (text, or bytes for the binary formats); the `export` command
writes the files. camnet's conventions (see camnet/model/projection.py):
``x_cam = R @ X_world + t`` with the world the calibration's, as its
document is written (`in_world_frame`): its floor frame where it has one,
else the left stereo camera's frame; lengths in metres, ``K`` in pixels with
the origin at the centre of the top-left pixel, distortion in OpenCV's order
``[k1, k2, p1, p2, k3]``, or ``[k1, k2, k3, k4]`` for a camera with the
fisheye lens model (OpenCV's fisheye, which COLMAP calls OPENCV_FISHEYE, ROS
and Kalibr equidistant).
Each exporter's docstring says what it changes. OpenCV, ROS and Kalibr are
here; COLMAP, aniposelib and PLY in the export_*.py modules beside this one.
"""

from __future__ import annotations

import math

import numpy as np

from camnet.errors import InputError
from camnet.io.export_anipose import anipose_toml
from camnet.io.export_base import require_zero_skew, safe_names
from camnet.io.export_colmap import colmap_binary, colmap_model, colmap_text
from camnet.io.export_ply import ply_points
from camnet.model.calibration import Calibration, in_world_frame
from camnet.model.camera import LensModel
from camnet.model.observations import Observations

FORMATS = ("opencv", "colmap", "colmap-bin", "ros", "kalibr", "anipose", "ply")
# Formats that write a directory of files rather than one file.
MULTI_FILE = ("colmap", "colmap-bin", "ros")
COLMAP_FORMATS = ("colmap", "colmap-bin")


def export(
    cal: Calibration,
    fmt: str,
    *,
    observations: Observations | None = None,
    max_error_px: float | None = None,
    unit: str = "m",
) -> dict[str, str | bytes]:
    """``{file name: content}`` of `cal` in `fmt` (one of `FORMATS`).

    Only the COLMAP exports use `observations` and `max_error_px` (their
    2-D tracks; see `camnet.io.export_colmap.colmap_model`); only the
    anipose export uses `unit` (see `camnet.io.export_anipose.anipose_toml`).
    """
    if fmt not in FORMATS:
        raise InputError(f"--to: unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if observations is not None and fmt not in COLMAP_FORMATS:
        raise InputError(f"--observations: the {fmt} export does not use observations (only colmap does)")
    if fmt == "opencv":
        return {"calibration.yaml": opencv_yaml(cal)}
    if fmt in COLMAP_FORMATS:
        model = colmap_model(cal, observations, max_error_px=max_error_px)
        return colmap_text(model) if fmt == "colmap" else colmap_binary(model)
    if fmt == "ros":
        return ros_camera_info(cal)
    if fmt == "anipose":
        return {"calibration.toml": anipose_toml(cal, unit=unit)}
    if fmt == "ply":
        return {"points.ply": ply_points(cal)}
    return {"camchain.yaml": kalibr_camchain(cal)}


def is_multi_file(fmt: str) -> bool:
    """Whether `fmt` writes a directory rather than one file."""
    return fmt in MULTI_FILE


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
    calibration's ``world_frame`` and ``rms_reprojection_px``. The world is
    the calibration's (`in_world_frame`): with a floor frame ``world_frame``
    is ``floor`` and ``world_from_left`` (a map of ``R`` 3x3 and ``t`` 3x1, m,
    ``X_world = R X_left + t``) says how it lies to the left camera's, as in
    the calibration document. No conversion: camnet uses OpenCV's
    conventions. A comment at the top says them, for whoever opens the file
    without this docstring.
    """
    import cv2

    # OpenCV 5 writes YAML 1.2 unless asked; the 1.0 flavour is what every OpenCV reads.
    yaml_flavour = getattr(cv2, "FILE_STORAGE_FORMAT_YAML_1_0", cv2.FILE_STORAGE_FORMAT_YAML)
    fs = cv2.FileStorage("calibration.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | yaml_flavour)
    fs.write("format", "opencv export of camnet.calibration/1")
    fs.writeComment("pose: x_cam = R X + t (R, t take a world point into the camera's frame)")
    fs.writeComment("units: metres (t, points); K in pixels, origin at the centre of the top-left pixel")
    posed = in_world_frame(cal)
    floor = cal.floor_frame
    if floor is None:
        fs.writeComment(f"world frame: the left stereo camera's ({posed.frame}): its R = I, t = 0")
    else:
        fs.writeComment("world frame: the floor's (Z up, origin on the floor); world_from_left: X_world = R X_left + t")
    fs.write("world_frame", posed.frame)
    if floor is not None:
        fs.startWriteStruct("world_from_left", cv2.FILE_NODE_MAP)
        fs.write("R", np.asarray(floor.R, dtype=np.float64))
        fs.write("t", np.asarray(floor.t, dtype=np.float64).reshape(3, 1))
        fs.endWriteStruct()
    fs.write("units", "m")
    if math.isfinite(cal.rms_reprojection_px):
        fs.write("rms_reprojection_px", float(cal.rms_reprojection_px))
    fs.write("camera_count", len(cal.cameras))
    fs.startWriteStruct("cameras", cv2.FILE_NODE_SEQ)
    for cam in posed.cameras:
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
        fs.write("points", np.asarray(posed.points, dtype=np.float64).reshape(-1, 3))
    return fs.releaseAndGetString()


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
    ``[K | 0]``. The poses are not part of camera_info (ROS keeps them in tf),
    so the world frame (a floor frame's or the left camera's) changes nothing here.
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
    The camchain holds only poses between cameras, which are the same in any
    world frame: a calibration's floor frame changes none of its numbers.
    """
    import yaml

    require_zero_skew(cal, "Kalibr's pinhole model")
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
