"""A calibration as COLMAP's sparse model, in its text and its binary encoding.

`colmap_model` builds one `ColmapModel`; `colmap_text` and `colmap_binary`
only encode it, so the two encodings hold the same numbers. The binary
layout is COLMAP's documented one (little-endian, no padding): cameras.bin,
images.bin and points3D.bin, each a uint64 count followed by its records.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from camnet.errors import InputError
from camnet.io.export_base import num, require_zero_skew, safe_names
from camnet.model.calibration import Calibration, in_world_frame
from camnet.model.camera import LensModel
from camnet.model.observations import Observations

# COLMAP puts the pixel origin at the top-left corner of the top-left pixel, camnet at its centre.
COLMAP_PIXEL_SHIFT = 0.5
# COLMAP's camera model ids (src/colmap/sensor/models.h): what cameras.bin stores instead of the name.
MODEL_IDS = {"PINHOLE": 1, "OPENCV": 4, "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6}
NO_POINT = -1  # a 2-D point in no track: COLMAP's invalid id (the largest uint64, the same 8 bytes)
GREY = 128  # camnet keeps no colour


@dataclass(frozen=True)
class ColmapCamera:
    camera_id: int
    model: str  # a key of MODEL_IDS
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    qvec: np.ndarray  # (4,) QW QX QY QZ of cam_from_world
    tvec: np.ndarray  # (3,) metres
    camera_id: int
    name: str
    xy: np.ndarray  # (n, 2) the 2-D points in COLMAP's pixels
    point3d_ids: np.ndarray  # (n,) int64, NO_POINT for a 2-D point in no track


@dataclass(frozen=True)
class ColmapModel:
    cameras: tuple[ColmapCamera, ...]
    images: tuple[ColmapImage, ...]
    point_ids: np.ndarray  # (N,) int64
    xyz: np.ndarray  # (N, 3) metres, world frame
    errors: np.ndarray  # (N,) mean reprojection error of the track in pixels, -1 unknown
    tracks: tuple[np.ndarray, ...]  # per point, (k, 2) IMAGE_ID, POINT2D_IDX


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
) -> ColmapModel:
    """The calibration as COLMAP's sparse model.

    - Camera and image ``k + 1`` are ``cal.cameras[k]``; the image NAME is the
      camera id (file-safe). Intrinsics: see `colmap_camera`.
    - ``QW QX QY QZ TX TY TZ`` is COLMAP's ``cam_from_world``, the same
      world-to-camera transform as camnet's ``x_cam = R X + t``: the quaternion
      of ``R`` and ``t`` in metres, unchanged. The world is the calibration's
      (`in_world_frame`: its floor frame where it has one); COLMAP's model has
      no field that names it.
    - POINT3D_ID is camnet's track id (must be >= 0); XYZ in metres, in the same
      world; colour grey.
    - With `observations`, every observation becomes a 2-D point of its image
      (``u + 0.5, v + 0.5``); one of a kept point whose reprojection error is
      at most `max_error_px` (default: `camnet.solve.report.reprojection.outlier_limit_px`) joins that
      point's track, others get POINT3D_ID -1. ERROR is the track's mean
      reprojection error in pixels. Without observations the images have no
      2-D points, the tracks are empty and ERROR is -1 (COLMAP's "unknown"):
      COLMAP reads such a model, but tools that need tracks will not use it.
    """
    require_zero_skew(cal, "COLMAP's camera models")
    names = safe_names(cal)
    point_ids = np.asarray(cal.point_ids, dtype=np.int64)
    if len(point_ids) and int(np.min(point_ids)) < 0:
        raise InputError("points: COLMAP needs non-negative point ids")
    cameras = []
    for k, cam in enumerate(cal.cameras):
        model, params = colmap_camera(cam.K, cam.dist, cam.model)
        cameras.append(ColmapCamera(k + 1, model, int(cam.width), int(cam.height), tuple(params)))
    if observations is None:
        cam_k, point_j = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        uv, error = np.zeros((0, 2)), np.zeros(0)
    else:
        cam_k, point_j, error = _link_observations(cal, observations, max_error_px)
        uv = np.asarray(observations.uv, dtype=float)
    # Each observation's index among its image's 2-D points (COLMAP's POINT2D_IDX).
    index_in_image = np.zeros(len(cam_k), dtype=np.int64)
    posed = in_world_frame(cal)
    images = []
    for k, cam in enumerate(posed.cameras):
        rows = np.flatnonzero(cam_k == k)
        index_in_image[rows] = np.arange(len(rows))
        linked = point_j[rows]
        ids = np.full(len(rows), NO_POINT, dtype=np.int64)
        ids[linked >= 0] = point_ids[linked[linked >= 0]]
        images.append(ColmapImage(
            image_id=k + 1, qvec=colmap_quaternion(cam.R), tvec=np.asarray(cam.t, dtype=float), camera_id=k + 1,
            name=names[k], xy=uv[rows] + COLMAP_PIXEL_SHIFT, point3d_ids=ids,
        ))
    # Tracks list their elements in the observations' order.
    rows = np.flatnonzero(point_j >= 0)
    rows = rows[np.argsort(point_j[rows], kind="stable")]
    elements = np.stack([cam_k[rows] + 1, index_in_image[rows]], axis=1)
    ends = np.cumsum(np.bincount(point_j[rows], minlength=len(point_ids)))
    tracks = tuple(np.split(elements, ends[:-1])) if len(point_ids) else ()
    count = np.bincount(point_j[rows], minlength=len(point_ids))
    total = np.bincount(point_j[rows], weights=error[rows], minlength=len(point_ids))
    errors = np.where(count > 0, total / np.maximum(count, 1), -1.0)
    return ColmapModel(tuple(cameras), tuple(images), point_ids, np.asarray(posed.points, dtype=float), errors, tracks)


def _link_observations(cal: Calibration, observations: Observations, max_error_px: float | None):
    """Per observation: its camera's index in `cal` (-1: left out), the index of the point it joins (-1: none),
    its error (px)."""
    from camnet.solve.report.reprojection import outlier_limit_px, reprojection_residuals

    res = reprojection_residuals(cal, observations)
    limit = outlier_limit_px(cal) if max_error_px is None else max_error_px
    point_j = np.full(len(observations.uv), -1, dtype=np.int64)
    ok = np.isfinite(res.error_px) & (res.error_px <= limit)
    point_j[res.obs_row[ok]] = res.point_index[ok]
    error = np.full(len(observations.uv), np.nan)
    error[res.obs_row] = res.error_px
    cal_index = {cam.id: k for k, cam in enumerate(cal.cameras)}
    # A camera the calibration left out (named in its report) has no image: its observations join nothing.
    to_cal = np.array([cal_index.get(cam.id, -1) for cam in observations.cameras], dtype=np.int64)
    return to_cal[np.asarray(observations.cam_index, dtype=np.int64)], point_j, error


def colmap_text(model: ColmapModel) -> dict[str, str]:
    """COLMAP's text model: ``cameras.txt``, ``images.txt``, ``points3D.txt``."""
    cams = [f"# Camera list: CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n# Number of cameras: {len(model.cameras)}\n"]
    for c in model.cameras:
        cams.append(f"{c.camera_id} {c.model} {c.width} {c.height} {' '.join(num(p) for p in c.params)}\n")
    images = [
        "# Image list: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then POINTS2D[] as (X, Y, POINT3D_ID)\n"
        f"# Number of images: {len(model.images)}\n"
    ]
    for im in model.images:
        pose = " ".join(num(x) for x in (*im.qvec, *im.tvec))
        images.append(f"{im.image_id} {pose} {im.camera_id} {im.name}\n")
        points2d = (f"{num(x)} {num(y)} {int(pid)}" for (x, y), pid in zip(im.xy, im.point3d_ids, strict=True))
        images.append(" ".join(points2d) + "\n")
    points = [
        "# 3D point list: POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        f"# Number of points: {len(model.point_ids)}\n"
    ]
    for pid, xyz, error, track in zip(model.point_ids, model.xyz, model.errors, model.tracks, strict=True):
        fields = [str(int(pid)), *(num(x) for x in xyz), *[str(GREY)] * 3, num(error)]
        fields += [f"{int(i)} {int(j)}" for i, j in track]
        points.append(" ".join(fields) + "\n")
    return {"cameras.txt": "".join(cams), "images.txt": "".join(images), "points3D.txt": "".join(points)}


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("point3d_id", "<i8")])


def colmap_binary(model: ColmapModel) -> dict[str, bytes]:
    """COLMAP's binary model: ``cameras.bin``, ``images.bin``, ``points3D.bin``.

    cameras.bin: per camera uint32 CAMERA_ID, int32 model id (`MODEL_IDS`),
    uint64 WIDTH, HEIGHT, then the parameters as doubles. images.bin: per
    image uint32 IMAGE_ID, 4 + 3 doubles QVEC TVEC, uint32 CAMERA_ID, the NAME
    ending in a NUL byte, uint64 count, then per 2-D point doubles X Y and
    int64 POINT3D_ID. points3D.bin: per point uint64 POINT3D_ID, 3 doubles
    XYZ, 3 uint8 RGB, double ERROR, uint64 track length, then uint32
    IMAGE_ID, POINT2D_IDX per element.
    """
    cams = [struct.pack("<Q", len(model.cameras))]
    for c in model.cameras:
        cams.append(struct.pack("<IiQQ", c.camera_id, MODEL_IDS[c.model], c.width, c.height))
        cams.append(np.asarray(c.params, dtype="<f8").tobytes())
    images = [struct.pack("<Q", len(model.images))]
    for im in model.images:
        images.append(struct.pack("<I7dI", im.image_id, *im.qvec, *im.tvec, im.camera_id))
        points2d = np.empty(len(im.xy), dtype=_POINT2D)
        points2d["x"], points2d["y"], points2d["point3d_id"] = im.xy[:, 0], im.xy[:, 1], im.point3d_ids
        images += [im.name.encode() + b"\0", struct.pack("<Q", len(points2d)), points2d.tobytes()]
    points = [struct.pack("<Q", len(model.point_ids))]
    for pid, xyz, error, track in zip(model.point_ids, model.xyz, model.errors, model.tracks, strict=True):
        points.append(struct.pack("<Q3d3BdQ", int(pid), *xyz, GREY, GREY, GREY, error, len(track)))
        points.append(np.asarray(track, dtype="<u4").tobytes())
    return {"cameras.bin": b"".join(cams), "images.bin": b"".join(images), "points3D.bin": b"".join(points)}
