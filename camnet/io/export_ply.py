"""The calibration's point cloud as a PLY file, with each point's uncertainty as a property."""

from __future__ import annotations

import numpy as np

from camnet.errors import InputError
from camnet.model.calibration import Calibration, in_world_frame

# PLY has no 64-bit integer type; camnet's track ids are counters far below this.
MAX_PLY_INT = np.iinfo(np.int32).max


def point_sigmas(cal: Calibration) -> np.ndarray | None:
    """The calibration's per-point 1-sigma position errors (m), None when its document gives none."""
    sigma = cal.uncertainty.point_sigma_m if cal.uncertainty is not None else None
    if sigma is None:
        return None
    if len(sigma) != len(cal.points):
        raise InputError(f"uncertainty.point_sigma_m: {len(sigma)} values for {len(cal.points)} points")
    return np.asarray(sigma, dtype=float)


def ply_points(cal: Calibration) -> bytes:
    """Binary little-endian PLY: one ``vertex`` per calibration point.

    Properties: ``double x, y, z`` (metres, in the calibration's world frame,
    `in_world_frame`: its floor frame's where it has one, Z up, else the left
    stereo camera's; ``x_cam = R X + t`` in the other exports), ``int point_id``
    (camnet's track id, the POINT3D_ID of the COLMAP export) and, when the
    calibration reports it (``uncertainty.point_sigma_m``), ``double sigma_m``:
    the point's 1-sigma position error in metres, RMS over the three axes.
    Doubles keep every digit of the calibration. Tools that know only x, y, z
    (MeshLab, Open3D) skip the rest; CloudCompare loads them as scalar fields.
    """
    ids = np.asarray(cal.point_ids, dtype=np.int64)
    if len(ids) and (ids.min() < 0 or ids.max() > MAX_PLY_INT):
        raise InputError(f"point_ids: the PLY export needs ids from 0 to {MAX_PLY_INT}")
    sigma = point_sigmas(cal)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("point_id", "<i4")]
    if sigma is not None:
        fields.append(("sigma_m", "<f8"))
    vertices = np.empty(len(ids), dtype=fields)
    posed = in_world_frame(cal)
    points = np.asarray(posed.points, dtype=float).reshape(-1, 3)
    vertices["x"], vertices["y"], vertices["z"], vertices["point_id"] = points[:, 0], points[:, 1], points[:, 2], ids
    if sigma is not None:
        vertices["sigma_m"] = sigma
    ply_type = {"<f8": "double", "<i4": "int"}
    header = [
        "ply",
        "format binary_little_endian 1.0",
        f"comment camnet calibration points: metres, world frame {_printable(posed.frame)} "
        + ("(left stereo camera)" if cal.floor_frame is None else "(Z up, origin on the floor)"),
        "comment sigma_m: 1-sigma position error, RMS over the axes, metres"
        if sigma is not None else "comment no per-point uncertainty in the calibration",
        f"element vertex {len(ids)}",
        *(f"property {ply_type[kind]} {name}" for name, kind in fields),
        "end_header",
    ]
    return ("\n".join(header) + "\n").encode("ascii") + vertices.tobytes()


def _printable(text: str) -> str:
    """`text` fit for a one-line ASCII header comment."""
    return "".join(ch if " " <= ch <= "~" else "_" for ch in text)
