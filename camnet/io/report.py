"""A calibration as one self-contained HTML page.

At the top a banner: the verdict, whether the solve converged, and (for a
simulated rig) how far it is from the ground truth. Sections: a summary,
the verdict's findings, the comparison with the ground truth (when it is
known), the solver's warnings, a table per camera, the
reprojection error of every point in every camera (the paper's Fig. 5) and
the residual histograms (both need the observations), the uncertainty of
each parameter, the point cloud's bounding box in millimetres (the paper's
Sec. IV) and the camera layout (a floor plan and a side view where the
calibration has a floor frame, else from above). The plots are
camnet.io.report_plots'.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.io.report_plots import (
    ROBUST_PERCENTILES,
    BoundingBox,
    bounding_box,
    outside,
    plot_bounding_box,
    plot_layout,
    plot_limits,
    plot_per_point_errors,
    plot_residual_histograms,
    plot_uncertainty,
    robust_box,
)
from camnet.model.accuracy import Comparison, compare_cameras
from camnet.model.calibration import Calibration, CameraSigmas, SolveReport, Uncertainty
from camnet.model.camera import Camera
from camnet.model.observations import Observations
from camnet.solve.report.reprojection import Residuals, outlier_limit_px, reprojection_residuals
from camnet.solve.report.verdict import Level, Verdict, judge

SECTIONS = {
    "summary": "Summary",
    "verdict": "Verdict",
    "truth": "Against the simulation's ground truth",  # only with the ground truth
    "warnings": "Warnings and notes",
    "cameras": "Cameras",
    "reprojection": "Reprojection error per point",
    "residuals": "Residual histograms",
    "uncertainty": "Uncertainty per parameter",
    "bounding-box": "Point cloud bounding box",
    "layout": "Camera layout",
}
NEEDS_OBSERVATIONS = "Needs the observations: run <code>camnet report CALIBRATION.json --observations OBS.json</code>."
CSS = """
body { font-family: sans-serif; margin: 24px; color: #222; max-width: 1200px; }
h1 { font-size: 22px; } h2 { font-size: 18px; border-bottom: 1px solid #ccc; padding-bottom: 4px; }
table { border-collapse: collapse; font-size: 13px; margin: 8px 0; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #f0f0f0; } td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
svg { max-width: 100%; height: auto; }
.note { color: #666; } .warning { color: #a40000; }
.good { color: #1a7f37; } .usable { color: #9a6700; } .poor { color: #a40000; font-weight: bold; }
.banner { border: 2px solid; border-radius: 6px; padding: 4px 16px; margin: 12px 0 20px; color: #222; }
.banner p { margin: 8px 0; } .banner .level { font-size: 18px; font-weight: bold; }
.banner-good { border-color: #1a7f37; background: #eef8f0; }
.banner-usable { border-color: #9a6700; background: #fff8e5; }
.banner-poor { border-color: #a40000; background: #fdecec; }
.banner-none { border-color: #999; background: #f4f4f4; }
"""
# What each level of the verdict asks of the user (its Level).
LEVEL_ADVICE = {
    Level.GOOD: "Use it.",
    Level.USABLE: "Use it, knowing the limits its findings name.",
    Level.POOR: "Do not rely on it: do what its findings say and solve again.",
}


# ---------------------------------------------------------------- tables


def _esc(value: Any) -> str:
    return html.escape(str(value))


def _fmt(x: Any, digits: int) -> str:
    if isinstance(x, bool) or x is None:
        return _esc(x)
    if isinstance(x, int | float | np.floating) and math.isfinite(x):
        return f"{x:.{digits}f}"
    return _esc(x)


def _sigma(x: float, digits: int) -> str:
    """A 1 sigma as shown: 'given' for a held parameter (its 0 is no measure), 'not determined' for infinity."""
    if x == 0.0:
        return '<span class="note">given</span>'
    return "not determined" if not math.isfinite(x) else f"{x:.{digits}f}"


def _table(header: list[str], rows: list[list[str]], *, text_columns: tuple[int, ...] = (0,)) -> str:
    """A table whose `text_columns` are text (left-aligned) and whose other columns are numbers (right-aligned)."""
    def cell(tag: str, i: int, content: str) -> str:
        return f"<{tag}>{content}</{tag}>" if i in text_columns else f'<{tag} class="num">{content}</{tag}>'

    head = "".join(cell("th", i, _esc(h)) for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", i, c) for i, c in enumerate(row)) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def convergence_sentence(report: SolveReport | None) -> str:
    """Whether the solve converged, and why it stopped, as a sentence."""
    if report is None:
        return "The calibration holds no solve report: whether its solve converged is not known."
    return f"The solve {'converged' if report.converged else 'did not converge'}: {report.reason}."


def _banner(verdict: Verdict | None, report: SolveReport | None, comparison: Comparison | None) -> str:
    """The verdict with what it asks of the user, whether the solve converged, and its error against the truth."""
    if verdict is None:
        head, level = "Nothing was solved: no verdict.", "none"
    else:
        level = verdict.level.value
        findings = len(verdict.all_findings())
        more = f' <a href="#verdict">{findings} finding{"s" * (findings != 1)} below.</a>' if findings else ""
        head = f'<span class="level">Verdict: {level}.</span> {LEVEL_ADVICE[verdict.level]}{more}'
    lines = [head, _esc(convergence_sentence(report))]
    if comparison is not None:
        lines.append(f"Against the simulation's ground truth: the scale is off by {100 * comparison.scale_rel:+.3f}% "
                     f"(1 sigma {100 * comparison.scale_sigma_rel:.3f}%), focal lengths by at most "
                     f"{100 * max(abs(e.focal_rel) for e in comparison.cameras):.2f}%, camera centres by at most "
                     f'{max(e.centre_mm for e in comparison.cameras):.1f} mm (<a href="#truth">per camera below</a>).')
    return f'<div id="banner" class="banner banner-{level}">' + "".join(f"<p>{line}</p>" for line in lines) + "</div>"


def _truth_html(c: Comparison) -> str:
    def sigma(x: float, digits: int) -> str:
        return "n/a" if math.isnan(x) else _sigma(x, digits)  # NaN: the calibration reports none

    rows = [[_esc(e.id), _fmt(100 * e.focal_rel, 3), sigma(100 * e.focal_sigma_rel, 3), _fmt(e.centre_mm, 2),
             sigma(e.centre_sigma_mm, 2), _fmt(e.rotation_deg, 4)] for e in c.cameras]
    header = ["camera", "focal length error (%)", "1 sigma (%)", "centre error (mm)", "1 sigma (mm)",
              "rotation error (deg)"]
    return (f"<p>The scale is off by <b>{100 * c.scale_rel:+.4f}%</b> (its reported 1 sigma: "
            f"{100 * c.scale_sigma_rel:.4f}%); the camera centres' shape, after the best similarity onto the true "
            f"ones, is off by {c.shape_rms_mm:.3f} mm RMS. Errors are the calibration's minus the truth's, in the "
            "left stereo camera's frame.</p>" + _table(header, rows))


def truth_comparison(cal: Calibration, truth: list[Camera]) -> Comparison:
    """`cal` against the ground truth of its cameras (a simulated rig's); InputError when the truth lacks one."""
    missing = sorted({c.id for c in cal.cameras} - {c.id for c in truth})
    if missing:
        raise InputError(f"the ground truth has no camera {', '.join(missing)} of the calibration; is it the truth "
                         "of another rig?")
    return compare_cameras(cal, truth)


def _summary(cal: Calibration, res: Residuals | None) -> str:
    report, uncertainty = cal.report, cal.uncertainty
    scale_rel = uncertainty.scale_rel.value if uncertainty is not None else None
    if report is None:
        counts, parallax = "n/a / n/a", None
    else:
        counts, parallax = f"{report.observations} / {report.inliers}", report.median_parallax_deg
    method = report.method.value if report is not None else "unknown"
    about = (f"<p>World frame: camera {_esc(cal.world_frame)}'s (x right, y down, z forward; metres). Method: "
             f"{_esc(method)}.</p>")
    rows = [
        ["cameras", str(len(cal.cameras))],
        ["points", str(len(cal.points))],
        ["reprojection RMS (px)", _fmt(cal.rms_reprojection_px, 3)],
        ["pixel noise sigma (px)", _fmt(uncertainty.sigma_px if uncertainty is not None else None, 3)],
        ["scale uncertainty (1 sigma, %)", _fmt(100 * scale_rel, 4) if scale_rel is not None else "n/a"],
        *_scale_if_exact_rows(uncertainty),
        ["observations / inliers", counts],
        ["median parallax (deg)", _fmt(parallax, 2)],
    ]
    if res is not None:
        rows.append(["observations of dropped tracks", str(res.dropped_observations)])
    return about + _table(["quantity", "value"], rows)


def _scale_if_exact_rows(uncertainty: Uncertainty | None) -> list[list[str]]:
    """The scale's sigma with each assumption it counts removed, where it counts one (what each costs)."""
    if uncertainty is None:
        return []
    figures = (("the guessed principal points", uncertainty.scale_rel_if_pp_exact),
               ("the stereo pair's held rotation", uncertainty.scale_rel_if_pair_exact),
               ("both of these", uncertainty.scale_rel_if_pp_and_pair_exact))
    return [[f"scale uncertainty were {what} exact (%)", _fmt(100 * s.value, 4)]
            for what, s in figures if s.value is not None]


def _camera_table(cal: Calibration) -> str:
    stats = cal.report.cameras if cal.report is not None else {}
    sigmas = cal.uncertainty.cameras if cal.uncertainty is not None else {}
    rows = []
    for cam in cal.cameras:
        d, u = stats.get(cam.id), sigmas.get(cam.id)
        rows.append(
            [
                _esc(cam.id),
                f"{cam.width}x{cam.height}",
                *(_fmt(x, 1) for x in (cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2])),
                " ".join(f"{x:.4g}" for x in cam.dist),
                " ".join(_fmt(1e3 * x, 1) for x in cam.centre),
                _sigma(u.f_px, 2) if u is not None else "n/a",
                f"{_sigma(u.cx_px, 2)} / {_sigma(u.cy_px, 2)}" if u is not None else "n/a",
                _fmt(d.rms_px if d is not None else None, 3),
                _esc(d.inliers if d is not None else "n/a"),
            ]
        )
    header = ["camera", "size", "fx", "fy", "cx", "cy", "k1 k2 p1 p2 k3", "centre X Y Z (mm)", "sigma f (px)"]
    return _table([*header, "sigma cx / cy (px)", "RMS (px)", "inliers"], rows)


def _uncertainty_table(cal: Calibration, per_camera: Mapping[str, CameraSigmas]) -> str:
    rows = []
    for cam in cal.cameras:
        u = per_camera.get(cam.id)
        if u is None:
            continue
        rows.append(
            [
                _esc(cam.id),
                *(_sigma(x, 3) for x in (u.f_px, u.cx_px, u.cy_px)),
                *(_sigma(x, 4) for x in (u.k1, u.k2)),
                " ".join(_sigma(1e3 * x, 3) for x in u.centre_m),
                " ".join(_sigma(x, 4) for x in u.rotation_deg),
            ]
        )
    header = ["camera", "f (px)", "cx (px)", "cy (px)", "k1", "k2", "centre X Y Z (mm)", "rotation x y z (deg)"]
    return _table(header, rows)


def _bounding_box_text(points_m: np.ndarray, box: BoundingBox) -> str:
    full = bounding_box(points_m)
    far = int(outside(points_m, BoundingBox(*plot_limits(box.min_m, box.max_m))).sum())
    sx, sy, sz = box.size_mm
    lo, hi = 1e3 * box.min_m, 1e3 * box.max_m
    rows = [[axis, _fmt(lo[i], 1), _fmt(hi[i], 1), _fmt(box.size_mm[i], 1), _fmt(full.size_mm[i], 1)]
            for i, axis in enumerate("XYZ")]
    p_lo, p_hi = ROBUST_PERCENTILES
    return (
        f"<p>The body of the cloud ({p_lo:g}th to {p_hi:g}th percentile along each axis) fits inside a box of "
        f"<b>{sx:.1f} mm x {sy:.1f} mm x {sz:.1f} mm</b> (X x Y x Z), axes of the world frame; {far} of "
        f"{len(points_m)} points lie far beyond it (drawn on the plots' edges).</p>"
        + _table(["axis", "min (mm)", "max (mm)", "size (mm)", "all points (mm)"], rows)
    )


def _verdict_html(verdict: Verdict | None) -> str:
    if verdict is None:
        return '<p class="note">Nothing was solved: no verdict.</p>'
    lv = verdict.level.value
    head = f'<p>The rig: <span class="{lv}">{lv}</span> (docs/calibration-keys.md, "The verdict").</p>'
    rows = []
    for camera, f in verdict.all_findings():
        level = f'<span class="{f.level.value}">{f.level.value}</span>'
        rows.append([_esc(camera if camera is not None else "rig"), level, _esc(f.what), _esc(f.cause), _esc(f.todo)])
    levels = [[_esc(c.camera), f'<span class="{c.level.value}">{c.level.value}</span>'] for c in verdict.cameras]
    findings = _table(["where", "level", "what", "likely cause", "to do"], rows, text_columns=(0, 1, 2, 3, 4)) \
        if rows else ""
    return head + _table(["camera", "verdict"], levels, text_columns=(0, 1)) + findings


# ---------------------------------------------------------------- the page


def render_report(cal: Calibration, obs: Observations | None = None, *, title: str = "camnet calibration",
                  truth: list[Camera] | None = None) -> str:
    """The whole HTML page of `cal`; with `obs`, also the per-point errors and histograms; with `truth` (a
    simulated rig's cameras, in the calibration's world frame), also its errors against them."""
    uncertainty = cal.uncertainty
    res = reprojection_residuals(cal, obs) if obs is not None else None
    comparison = truth_comparison(cal, truth) if truth else None
    verdict = judge(cal)
    limit_px = outlier_limit_px(cal)
    box = robust_box(cal.points)
    needs_observations = f'<p class="note">{NEEDS_OBSERVATIONS}</p>'
    body = {
        "summary": _summary(cal, res),
        "verdict": _verdict_html(verdict),
        "truth": _truth_html(comparison) if comparison is not None else None,
        "warnings": "".join(f'<p class="warning">warning: {_esc(w)}</p>' for w in cal.warnings)
        + "".join(f'<p class="note">note: {_esc(n)}</p>' for n in (cal.report.notes if cal.report else ()))
        or '<p class="note">None.</p>',
        "cameras": _camera_table(cal),
        "reprojection": plot_per_point_errors(cal, res, limit_px) if res is not None else needs_observations,
        "residuals": plot_residual_histograms(cal, res, limit_px, uncertainty.sigma_px if uncertainty else None)
        if res is not None
        else needs_observations,
        "uncertainty": _uncertainty_table(cal, uncertainty.cameras) + plot_uncertainty(cal, uncertainty.cameras)
        if uncertainty is not None and uncertainty.cameras
        else '<p class="note">The calibration holds no uncertainty.</p>',
        "bounding-box": _bounding_box_text(cal.points, box) + plot_bounding_box(cal, box)
        if box is not None
        else '<p class="note">The calibration holds no points.</p>',
        "layout": plot_layout(cal),
    }
    sections = "".join(f'<section id="{key}"><h2>{SECTIONS[key]}</h2>{body[key]}</section>\n' for key in SECTIONS
                       if body[key] is not None)
    banner = _banner(verdict, cal.report, comparison)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{_esc(title)}</title>'
        f"<style>{CSS}</style></head>\n<body><h1>{_esc(title)}</h1>\n{banner}\n{sections}</body></html>\n"
    )
