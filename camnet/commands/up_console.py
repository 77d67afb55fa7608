"""What `camnet up` prints of each calibration: a summary of it, its console line, and the final table."""

from __future__ import annotations

RECORDED_CLOCK_S = 3600.0  # a capture this far from the host clock was stamped by a recording


def summarise(elapsed_s: float, doc: dict, truth) -> dict:
    """What one calibration holds, how sure it is, and how right when the truth is known."""
    summary = {
        "elapsed_s": round(elapsed_s, 3),
        "solve": doc.get("solve"),
        "frame_sets": doc.get("frame_sets"),
        "cameras": len(doc["cameras"]),
        "points": len(doc.get("points", [])),
        "rms_px": doc.get("rms_reprojection_px"),
        "scale_sigma_rel": doc.get("uncertainty", {}).get("scale_rel"),
        "moved": doc.get("moved", []),
        "left_out": _left_out(doc),
    }
    if "latest_capture_ns" in doc and "solved_ns" in doc:
        latency_s = (doc["solved_ns"] - doc["latest_capture_ns"]) / 1e9
        # Recorded frames (an image sequence with its timestamps) keep their own clock: no latency then.
        if abs(latency_s) < RECORDED_CLOCK_S:
            from camnet.bus.latency import stage_durations_s

            summary["capture_to_solution_s"] = latency_s
            summary["stages_s"] = stage_durations_s(doc)
    if truth:
        from camnet.io.formats import parse_calibration
        from camnet.model.accuracy import compare_cameras

        c = compare_cameras(parse_calibration(doc), truth)
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


def _left_out(doc: dict) -> dict[str, str]:
    """The cameras a calibration left out, each with why (its `diagnostics.cameras_left_out`)."""
    left_out = doc.get("diagnostics", {}).get("cameras_left_out", {})
    return {str(k): str(v) for k, v in left_out.items()} if isinstance(left_out, dict) else {}


def final_report(cal, truth) -> str:
    from camnet.io.summary import summary_lines
    from camnet.model.accuracy import compare_cameras, format_comparison

    lines = ["", "final calibration:", *summary_lines(cal)]
    if truth:
        lines += ["", "against the simulation's ground truth:", format_comparison(compare_cameras(cal, truth)),
                  "(scale and shape from the camera centres against the simulation's ground truth)"]
    return "\n".join(lines)
