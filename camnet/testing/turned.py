"""A calibration with one camera turned in place: a camera placed wrong, made on purpose, for the checks that
must find one (tests and benchmarks)."""

from __future__ import annotations

from dataclasses import replace

from scipy.spatial.transform import Rotation

from camnet.model.calibration import Calibration


def turned(cal: Calibration, cam_id: str, degrees: float) -> Calibration:
    """`cal` with camera `cam_id` turned by `degrees` about its own vertical (y) axis, its centre kept
    (``x_cam = R X + t``: R becomes Ry R, t becomes -R C)."""
    cams = []
    for c in cal.cameras:
        if c.id == cam_id:
            R = Rotation.from_euler("y", degrees, degrees=True).as_matrix() @ c.R
            c = replace(c, R=R, t=-R @ c.centre)
        cams.append(c)
    return replace(cal, cameras=tuple(cams))
