"""Middlebury's "templeSparseRing": sixteen 640 x 480 views of a plaster temple from a ring about 0.6 m away.

``templeSR_par.txt``: the view count, then one line per view, ``name k11 ...
k33 r11 ... r33 t1 t2 t3`` with ``P = K [R t]``, so ``x_cam = R @ X + t``,
metres, no distortion; one camera took every view (one K). Camera ids are
the image names (``"templeSR0001"`` ... ``"templeSR0016"``). Views 0001 and
0011 were taken from one viewpoint (no baseline between them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camnet.errors import InputError
from camnet.model.camera import Camera

PARAMETERS_FILE = "templeSR_par.txt"
WIDTH_PX, HEIGHT_PX = 640, 480


def parse_parameters(text: str, *, source: str = PARAMETERS_FILE) -> dict[str, Camera]:
    """Every view's published camera, by id, from the text of a Middlebury ``*_par.txt``."""
    lines = [line for line in text.splitlines() if line.strip()]
    if not lines:
        raise InputError(f"{source}: empty; expected the view count, then one line per view")
    cameras = {}
    for lineno, line in enumerate(lines[1:], start=2):
        name, *values = line.split()
        try:
            v = np.array(values, dtype=float)
        except ValueError:
            raise InputError(f"{source}:{lineno}: {name}: expected 21 numbers (K, R, t)") from None
        if v.size != 21:
            raise InputError(f"{source}:{lineno}: {name}: expected 21 numbers (K, R, t), got {v.size}")
        cam_id = name.removesuffix(".png")
        cameras[cam_id] = Camera(cam_id, WIDTH_PX, HEIGHT_PX, K=v[:9].reshape(3, 3), dist=np.zeros(5),
                                 R=v[9:18].reshape(3, 3), t=v[18:21])
    if str(len(cameras)) != lines[0].strip():
        raise InputError(f"{source}: the first line says {lines[0].strip()} views, {len(cameras)} follow")
    return cameras


def read_cameras(root: str | Path) -> dict[str, Camera]:
    """Every view's published camera, by id, in the data set's world frame (metres)."""
    path = Path(root) / PARAMETERS_FILE
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return parse_parameters(text, source=str(path))


def image_path(root: str | Path, camera_id: str) -> Path:
    return Path(root) / f"{camera_id}.png"
