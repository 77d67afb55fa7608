"""What `camnet up` prints of each calibration: a summary of it, its console line, and the final table."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from camnet.io.messages import CalibrationMessage

RECORDED_CLOCK_S = 3600.0  # a capture this far from the host clock was stamped by a recording


def summarise(elapsed_s: float, message: CalibrationMessage, truth) -> dict:
    """What one calibration message holds, how sure it is, and how right when the truth is known."""
    cal = message.calibration
    uncertainty = cal.uncertainty
    summary = {
        "elapsed_s": round(elapsed_s, 3),
        "solve": message.solve,
        "frame_sets": message.frame_sets,
        "cameras": len(cal.cameras),
        "points": len(cal.points),
        "rms_px": float(cal.rms_reprojection_px) if math.isfinite(cal.rms_reprojection_px) else None,
        "scale_sigma_rel": uncertainty.scale_rel.value if uncertainty is not None else None,
        "moved": list(message.moved or ()),
        "left_out": dict(cal.report.cameras_left_out) if cal.report is not None else {},
    }
    if message.latest_capture_ns is not None and message.solved_ns is not None:
        latency_s = (message.solved_ns - message.latest_capture_ns) / 1e9
        # Recorded frames (an image sequence with its timestamps) keep their own clock: no latency then.
        if abs(latency_s) < RECORDED_CLOCK_S:
            from camnet.bus.latency import StageStamps, stage_durations_s

            summary["capture_to_solution_s"] = latency_s
            summary["stages_s"] = stage_durations_s(message.latency_ns or StageStamps(),
                                                    capture_ns=message.latest_capture_ns,
                                                    solved_ns=message.solved_ns)
    if truth:
        from camnet.model.accuracy import compare_cameras

        c = compare_cameras(cal, truth)
        summary["scale_error_rel"] = c.scale_rel
        summary["max_focal_error_rel"] = max(abs(e.focal_rel) for e in c.cameras)
        summary["max_centre_error_mm"] = max(e.centre_mm for e in c.cameras)
    return summary


def progress_line(s: dict) -> str:
    nan = float("nan")
    line = (f"{s['elapsed_s']:7.1f} s  solve {s['solve'] or '?':>3}  {s['cameras']} cameras {s['points']:5d} points  "
            f"rms {s['rms_px'] or nan:.2f} px  scale sigma {100 * (s['scale_sigma_rel'] or nan):.3f}%")
    if "capture_to_solution_s" in s:
        line += f"  capture->solution {s['capture_to_solution_s']:.1f} s"
    if "scale_error_rel" in s:
        line += (f" | vs truth: scale {100 * s['scale_error_rel']:+.3f}%, "
                 f"focal <= {100 * s['max_focal_error_rel']:.2f}%, centres <= {s['max_centre_error_mm']:.1f} mm")
    if s["moved"]:
        line += f"  moved: {', '.join(s['moved'])}"
    if s.get("left_out"):
        line += "  missing: " + "; ".join(f"{cam_id} ({why})" for cam_id, why in s["left_out"].items())
    return line


def final_report(cal, truth) -> str:
    from camnet.io.summary import summary_lines
    from camnet.model.accuracy import compare_cameras, format_comparison

    lines = ["", "final calibration:", *summary_lines(cal)]
    if truth:
        lines += ["", "against the simulation's ground truth:", format_comparison(compare_cameras(cal, truth)),
                  "(scale and shape from the camera centres against the simulation's ground truth)"]
    return "\n".join(lines)
