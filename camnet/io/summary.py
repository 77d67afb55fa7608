"""A calibration in a few lines a person reads: per camera its focal length, centre and rotation with
their 1 sigma in readable units, its RMS and verdict; then the rig's verdict, warnings and notes.

`camnet calibrate` prints it on stderr and `camnet up` at its end.
"""

from __future__ import annotations

import numpy as np

from camnet.model.calibration import Calibration, CameraSigmas
from camnet.solve.report.verdict import format_verdict, judge

GIVEN = "given"  # a parameter that was held, not estimated: its sigma is no measure of anything


def _rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _pm(sigma: float, fmt: str) -> str:
    """'± sigma', 'given' for a held parameter, '± ?' for one the data do not determine."""
    if sigma == 0.0:
        return GIVEN
    return "± ?" if not np.isfinite(sigma) else f"± {sigma:{fmt}}"


def camera_rows(cal: Calibration) -> list[str]:
    """A table: camera, focal length (px), centre (mm), rotation angle (deg), each with 1 sigma, RMS, verdict."""
    report, verdict = cal.report, judge(cal)
    sigmas = cal.uncertainty.cameras if cal.uncertainty is not None else {}
    levels = {c.camera: c.level.value for c in verdict.cameras} if verdict is not None else {}
    left_out = report.cameras_left_out if report is not None else {}
    width = max(6, *(len(c.id) for c in cal.cameras), *(len(c) for c in left_out))
    rows = [f"{'camera':<{width}}  {'focal px':>18}  {'centre x, y, z mm':>34}  {'rotation deg':>16}  "
            f"{'RMS px':>6}  {'inliers':>7}  verdict"]
    for cam in cal.cameras:
        s: CameraSigmas | None = sigmas.get(cam.id)
        stats = report.cameras.get(cam.id) if report is not None else None
        centre_mm = 1e3 * cam.centre
        focal = f"{cam.K[0, 0]:.1f} {_pm(s.f_px, '.1f')}" if s is not None else f"{cam.K[0, 0]:.1f}"
        centre = ", ".join(f"{x:.1f}" for x in centre_mm)
        if s is not None:
            centre += f" {_pm(float(np.linalg.norm(s.centre_m)) * 1e3, '.1f')}"
        rotation = f"{_rotation_deg(cam.R):.2f}"
        if s is not None:
            rotation += f" {_pm(max(s.rotation_deg), '.2f')}"
        rms = f"{stats.rms_px:.2f}" if stats is not None and stats.rms_px is not None else "-"
        inliers = str(stats.inliers) if stats is not None else "-"
        rows.append(f"{cam.id:<{width}}  {focal:>18}  {centre:>34}  {rotation:>16}  {rms:>6}  {inliers:>7}  "
                    f"{levels.get(cam.id, '-')}")
    for cam_id, why in left_out.items():
        rows.append(f"{cam_id:<{width}}  not calibrated: {why}")
    return rows


def _floor_frame_lines(cal: Calibration) -> list[str]:
    """What the frame found from the scene says, where the calibration is written in it (the table below stays in
    the left camera's frame)."""
    frame = cal.floor_frame
    if frame is None:
        return []
    if not frame.found:
        return [f"written in a frame with up from the cameras' own down, no floor in view (the table: camera "
                f"{cal.world_frame}'s frame)"]
    return [f"written in the floor's frame (Z up, origin on the floor): the floor's normal known to "
            f"{frame.normal_sigma_deg:.3f} degrees, its height to {1e3 * frame.height_sigma_m:.1f} mm (1 sigma; "
            f"the table: camera {cal.world_frame}'s frame)"]


def summary_lines(cal: Calibration) -> list[str]:
    """The whole summary: the rig in one line, the camera table, the verdict, warnings and notes."""
    u = cal.uncertainty
    scale = u.scale_rel.value if u is not None else None
    scale_text = f"scale sigma {100 * scale:.2f}%" if scale is not None else "scale sigma unknown"
    lines = [f"{len(cal.cameras)} cameras, {len(cal.points)} points, RMS {cal.rms_reprojection_px:.2f} px, "
             f"{scale_text} (1 sigma; centre sigma: length of its 3 axes; rotation: angle from "
             f"camera {cal.world_frame}, sigma of its largest axis)"]
    lines += _floor_frame_lines(cal)
    lines += camera_rows(cal)
    verdict = judge(cal)
    if verdict is not None:
        lines += format_verdict(verdict)
    lines += [f"warning: {w}" for w in cal.warnings]
    lines += [f"note: {n}" for n in (cal.report.notes if cal.report is not None else ())]
    return lines
