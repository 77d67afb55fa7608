"""A calibration as aniposelib's calibration.toml, which anipose, FreeMoCap and Pose2Sim read."""

from __future__ import annotations

import math

import numpy as np

from camnet.errors import InputError
from camnet.io.export_base import num, require_zero_skew
from camnet.model.calibration import Calibration, in_world_frame
from camnet.model.camera import LensModel

# Length units of the translations: aniposelib has none of its own (see `anipose_toml`).
UNITS = {"m": 1.0, "mm": 1000.0}


def anipose_toml(cal: Calibration, *, unit: str = "m") -> str:
    """The layout of aniposelib's ``CameraGroup.dump``: a table per camera, then ``metadata``.

    Tables ``cam_0`` .. ``cam_<M-1>`` in the calibration's camera order,
    zero-padded from eleven cameras on (``CameraGroup.load`` orders them by
    name as text). Per camera: ``name`` (the camera id), ``size`` ``[width,
    height]``, ``matrix`` (K, pixels, OpenCV's pixel convention as camnet),
    ``distortions`` (OpenCV's ``[k1, k2, p1, p2, k3]``), ``rotation`` (the
    Rodrigues vector of R) and ``translation`` (t) of ``x_cam = R X + t``:
    the world-to-camera transform aniposelib hands to ``cv2.projectPoints``.
    A fisheye camera gets ``fisheye = true`` and ``[k1, k2, k3, k4]``:
    aniposelib's FisheyeCamera, which projects with ``cv2.fisheye``, the
    model camnet's fisheye is.

    aniposelib has no unit of its own: translations, and so the points it
    triangulates, are in the unit its calibration board was measured in.
    `unit` is ``m`` (camnet's, and Pose2Sim's) or ``mm`` (what anipose's and
    FreeMoCap's boards are usually given in). The poses are in the
    calibration's world frame (`in_world_frame`: its floor frame's where it has
    one). ``metadata`` records the unit, the world frame, with a floor frame
    its ``world_from_left_R`` and ``world_from_left_t`` (``X_world = R X_left +
    t``, t in `unit`), and the reprojection RMS.
    """
    if unit not in UNITS:
        raise InputError(f"--unit: {unit!r} is not one of {', '.join(UNITS)}")
    require_zero_skew(cal, "aniposelib's cameras (OpenCV's projection ignores skew)")
    import cv2

    width = len(str(len(cal.cameras) - 1)) if len(cal.cameras) > 10 else 1
    posed = in_world_frame(cal)
    out = []
    for k, cam in enumerate(posed.cameras):
        table = {
            "name": cam.id,
            "size": [int(cam.width), int(cam.height)],
            "matrix": np.asarray(cam.K, dtype=float).tolist(),
            "distortions": np.asarray(cam.dist, dtype=float).tolist(),
            "rotation": cv2.Rodrigues(np.asarray(cam.R, dtype=float))[0].ravel().tolist(),
            "translation": (UNITS[unit] * np.asarray(cam.t, dtype=float)).tolist(),
            "fisheye": cam.model == LensModel.FISHEYE,
        }
        out.append(_table(f"cam_{k:0{width}d}", table))
    metadata = {"units": unit, "world_frame": posed.frame, "source": "camnet.calibration/1"}
    if cal.floor_frame is not None:
        metadata["world_from_left_R"] = np.asarray(cal.floor_frame.R, dtype=float).tolist()
        metadata["world_from_left_t"] = (UNITS[unit] * np.asarray(cal.floor_frame.t, dtype=float)).tolist()
    if math.isfinite(cal.rms_reprojection_px):
        metadata["rms_reprojection_px"] = float(cal.rms_reprojection_px)
    out.append(_table("metadata", metadata))
    return "\n".join(out)


def _table(name: str, values: dict) -> str:
    return f"[{name}]\n" + "".join(f"{key} = {_value(v)}\n" for key, v in values.items())


def _value(x) -> str:
    """TOML text of a string, bool, int, float or (nested) list of them."""
    if isinstance(x, str):
        return _string(x)
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, int):
        return str(x)
    if isinstance(x, float):
        return num(x)  # repr is valid TOML for every finite double
    return "[" + ", ".join(_value(v) for v in x) + "]"


def _string(text: str) -> str:
    """A TOML basic string: quote, backslash and control characters escaped."""
    escaped = (
        "\\" + ch if ch in '"\\' else f"\\u{ord(ch):04X}" if ord(ch) < 0x20 or ord(ch) == 0x7F else ch for ch in text
    )
    return '"' + "".join(escaped) + '"'
