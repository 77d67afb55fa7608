"""What every exporter of camnet/io/export*.py shares: file-safe names, exact numbers, the skew check."""

from __future__ import annotations

import re

from camnet.errors import InputError
from camnet.model.calibration import Calibration

SKEW_TOLERANCE = 1e-9
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def safe_names(cal: Calibration) -> list[str]:
    """Camera ids made safe for file names, COLMAP image names and ROS topics (one per camera)."""
    names = [_UNSAFE.sub("_", cam.id) for cam in cal.cameras]
    for i, name in enumerate(names):
        if names.index(name) != i:
            raise InputError(f"cameras[{i}].id: {cal.cameras[i].id!r} clashes with another camera once made file-safe")
    return names


def num(x: float) -> str:
    """Shortest text that reads back as exactly the same double."""
    return repr(float(x))


def require_zero_skew(cal: Calibration, what: str) -> None:
    """Refuse a camera whose K has a skew term: `what` (the target's camera model) has none."""
    for i, cam in enumerate(cal.cameras):
        if abs(cam.K[0, 1]) > SKEW_TOLERANCE * cam.K[0, 0]:
            raise InputError(f"cameras[{i}].K: skew {cam.K[0, 1]:g} px has no place in {what}")
