"""Strecha's fountain-P11 layout: eleven views with their LIDAR-referenced cameras.

``images/NNNN.jpg`` (3072 x 2048, free of distortion) and
``gt_dense_cameras/NNNN.jpg.camera``: K (3 rows), the distortion ``0 0 0``,
the camera-to-world rotation R_cw (3 rows), the centre C and the image size.
Read into `camnet.model.camera.Camera` with ``x_cam = R @ X + t``:
``R = R_cw^T``, ``t = -R_cw^T C``, metres, in the LIDAR frame. Camera ids
are the image names (``"0000"`` ... ``"0010"``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camnet.datasets.published import in_frame_of
from camnet.errors import InputError
from camnet.model.camera import Camera


def read_camera(path: Path) -> Camera:
    """One ``.camera`` file; the camera id is the image name before ``.jpg.camera``."""
    try:
        values = np.array(path.read_text().split(), dtype=float)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read a Strecha camera ({exc})") from None
    if values.size != 26:
        raise InputError(f"{path}: expected 26 numbers (K, distortion, R_cw, C, size), got {values.size}")
    K = values[:9].reshape(3, 3)
    R = values[12:21].reshape(3, 3).T
    centre = values[21:24]
    width, height = int(values[24]), int(values[25])
    return Camera(path.name.split(".")[0], width, height, K=K, dist=np.zeros(5), R=R, t=-R @ centre)


def read_cameras(root: str | Path) -> dict[str, Camera]:
    """Every view's published camera, by id, in the LIDAR frame."""
    paths = sorted((Path(root) / "gt_dense_cameras").glob("*.camera"))
    if not paths:
        raise InputError(f"{root}: no gt_dense_cameras/*.camera files")
    return {cam.id: cam for cam in map(read_camera, paths)}


def image_path(root: str | Path, camera_id: str) -> Path:
    return Path(root) / "images" / f"{camera_id}.jpg"


__all__ = ["image_path", "in_frame_of", "read_camera", "read_cameras"]
