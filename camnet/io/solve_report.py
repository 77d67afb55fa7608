"""The further keys of ``camnet.calibration/1`` (docs/calibration-keys.md): the JSON
codec of camnet.model.calibration.SolveReport.

Writing keeps the documented keys and their order. Reading is tolerant of a
document without them (a factory stereo head has no report: None) and of the
keys older writers left out (None in the report), and strict about types:
every error is an `InputError` naming the JSON path.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.io import validate as v
from camnet.model.calibration import (
    CameraSigmas,
    CameraStats,
    FreeSet,
    HalvesCheck,
    LensShift,
    PairPoseCheck,
    PointsLeftOut,
    Rival,
    RivalDifference,
    Sigma,
    SolveReport,
    StartKind,
    Uncertainty,
)
from camnet.model.methods import Method
from camnet.solve.report.verdict import Verdict

# Timings are written to the microsecond: finer digits are noise.
TIMING_DIGITS = 6
# What a rival solution may differ in (camnet.model.calibration.RivalDifference).
DIFFERENCE_PARAMETERS = ("scale", "f_px", "rotation_deg")
# Why a sigma that a document gives as null is unknown.
NULL_SIGMA = "null in the document"


def report_to_doc(report: SolveReport) -> dict:
    """The further keys, in the documented order."""
    diagnostics: dict[str, Any] = {
        "converged": report.converged,
        "reason": report.reason,
        "iterations": report.iterations,
        "observations": report.observations,
        "inliers": report.inliers,
        "cameras": {cam_id: {"rms_px": s.rms_px, "inliers": s.inliers} for cam_id, s in report.cameras.items()},
    }
    if report.cameras_left_out:
        diagnostics["cameras_left_out"] = dict(report.cameras_left_out)
    diagnostics["median_parallax_deg"] = report.median_parallax_deg
    if report.free is not None:
        diagnostics["free"] = {
            "intrinsics": {cam_id: list(names) for cam_id, names in report.free.intrinsics.items()},
            "stereo_rotation_axes": list(report.free.stereo_rotation_axes),
            "stereo_direction": report.free.stereo_direction,
        }
    diagnostics["free_rule"] = list(report.free_rule)
    diagnostics["warnings"] = list(report.warnings)
    diagnostics["notes"] = list(report.notes)
    if report.points_left_out is not None:
        dropped = report.points_left_out
        diagnostics["points_left_out"] = {
            "fewer_than_two_views": dropped.fewer_than_two_views,
            "behind_a_camera": dropped.behind_a_camera,
            "undetermined": dropped.undetermined,
        }
    if report.start is not None:
        diagnostics["start"] = report.start.value
    if report.pair_pose_given:  # written where true only: documents from before it read back as they were
        diagnostics["pair_pose_given"] = True
    if report.halves is not None:
        diagnostics["halves"] = _halves_to_doc(report.halves)
    if report.rivals:  # written where found only, as pair_pose_given
        diagnostics["rivals"] = [_rival_to_doc(r) for r in report.rivals]
    if report.far_principal_points:  # written where found only, as pair_pose_given
        diagnostics["far_principal_points"] = dict(report.far_principal_points)
    if report.pair_checks is not None:
        diagnostics["pair_checks"] = [
            {"cameras": [c.first, c.second], "rotation_deg": c.rotation_deg, "direction_deg": c.direction_deg,
             "in_sigmas": c.in_sigmas, "shared": c.shared, "inliers": c.inliers} for c in report.pair_checks]
    if report.lens_shifts is not None:
        diagnostics["lens_shifts"] = {c: {"f_rel": sh.f_rel, "in_sigmas": sh.in_sigmas, "k1": sh.k1}
                                      for c, sh in report.lens_shifts.items()}
    doc: dict[str, Any] = {
        "method": report.method.value,
        "diagnostics": diagnostics,
        "timings_s": {k: round(t, TIMING_DIGITS) for k, t in report.timings_s.items()},
    }
    if report.uncertainty is not None:
        doc["uncertainty"] = _uncertainty_to_doc(report.uncertainty)
    return doc


def _rival_to_doc(r: Rival) -> dict:
    return {
        "start": r.start,
        "cost_px2": r.cost_px2,
        "kept_cost_px2": r.kept_cost_px2,
        "cost_noise_px2": r.cost_noise_px2,
        "differences": [{"parameter": d.parameter, "camera": d.camera, "kept": d.kept, "rival": d.rival,
                         "kept_sigma": d.kept_sigma} for d in r.differences],
    }


def verdict_to_doc(verdict: Verdict) -> dict:
    """The ``verdict`` key: the rig's level and findings, then each camera's (docs/calibration-keys.md)."""

    def findings(items) -> list[dict]:
        return [{"level": f.level.value, "what": f.what, "cause": f.cause, "action": f.action.value, "todo": f.todo}
                for f in items]

    return {
        "level": verdict.level.value,
        "findings": findings(verdict.findings),
        "cameras": {c.camera: {"level": c.level.value, "findings": findings(c.findings)} for c in verdict.cameras},
    }


def _uncertainty_to_doc(u: Uncertainty) -> dict:
    out: dict[str, Any] = {
        "sigma_px": u.sigma_px,
        "scale_rel": u.scale_rel.value,
        "scale_rel_if_pp_exact": u.scale_rel_if_pp_exact.value,
        # Written where known only: documents from before these keys read back as they were written.
        **{key: getattr(u, key).value for key in ("scale_rel_if_pair_exact", "scale_rel_if_pp_and_pair_exact")
           if getattr(u, key).value is not None},
        "cameras": {
            cam_id: {
                "f_px": _finite(s.f_px),
                "cx_px": _finite(s.cx_px),
                "cy_px": _finite(s.cy_px),
                "k1": _finite(s.k1),
                "k2": _finite(s.k2),
                "rotation_deg": [_finite(x) for x in s.rotation_deg],
                "centre_m": [_finite(x) for x in s.centre_m],
            }
            for cam_id, s in u.cameras.items()
        },
    }
    if u.point_weights is not None:
        out["point_weights"] = np.asarray(u.point_weights, dtype=float).tolist()
    if u.point_sigma_m is not None:
        out["point_sigma_m"] = np.asarray(u.point_sigma_m, dtype=float).tolist()
    return out


def _halves_to_doc(h: HalvesCheck) -> dict:
    out: dict[str, Any] = {"splits": h.splits, "half_differences": dict(h.half_differences),
                           "in_sigmas": {k: _finite(x) for k, x in h.in_sigmas.items()}, "widened": list(h.widened),
                           "sigma_factor": h.sigma_factor}
    if h.reason:
        out["reason"] = h.reason
    if h.ruled_out:
        out["ruled_out"] = list(h.ruled_out)
    if h.from_whole:
        out["from_whole"] = list(h.from_whole)
    return out


def _finite(x: float) -> float | None:
    """A sigma as written: null where the observations do not determine it (infinite)."""
    return float(x) if np.isfinite(x) else None


# ---------------------------------------------------------------- reading


def parse_report(doc: dict) -> SolveReport | None:
    """The report of a calibration document; None when it has no ``diagnostics``."""
    if "diagnostics" not in doc:
        return None
    method = v.string(v.require(doc, "method", ""), "method", choices=tuple(m.value for m in Method))
    diag = v.mapping(doc["diagnostics"], "diagnostics")

    def get(key: str, read, default=None):
        path = f"diagnostics.{key}"
        return read(diag[key], path) if diag.get(key) is not None else default

    start = get("start", lambda x, p: v.string(x, p, choices=tuple(s.value for s in StartKind)))
    timings = v.mapping(doc.get("timings_s", {}), "timings_s")
    return SolveReport(
        method=Method(method),
        converged=v.boolean(v.require(diag, "converged", "diagnostics"), "diagnostics.converged"),
        reason=str(diag.get("reason", "")),
        iterations=get("iterations", v.integer, 0),
        observations=get("observations", v.integer, 0),
        inliers=get("inliers", v.integer, 0),
        cameras=get("cameras", _parse_camera_stats, {}),
        median_parallax_deg=get("median_parallax_deg", v.optional_number),
        free=get("free", _parse_free),
        free_rule=get("free_rule", v.strings, ()),
        warnings=get("warnings", v.strings, ()),
        notes=get("notes", v.strings, ()),  # older documents have none: their caveats are warnings
        points_left_out=get("points_left_out", _parse_points_left_out),
        start=StartKind(start) if start is not None else None,
        timings_s={k: v.number(t, f"timings_s.{k}") for k, t in timings.items()},
        uncertainty=_parse_uncertainty(doc["uncertainty"], "uncertainty") if "uncertainty" in doc else None,
        cameras_left_out=get("cameras_left_out", _parse_left_out, {}),
        pair_pose_given=get("pair_pose_given", v.boolean, False),
        halves=get("halves", _parse_halves),
        rivals=get("rivals", _parse_rivals, ()),
        far_principal_points=get("far_principal_points", _parse_shares, {}),
        pair_checks=get("pair_checks", _parse_pair_checks),
        lens_shifts=get("lens_shifts", _parse_lens_shifts),
    )


def _items(value: Any, path: str):
    """(object, its path) of each item of the array `value` at `path`; each must be an object."""
    for i, item in enumerate(v.array(value, path)):
        yield v.mapping(item, f"{path}[{i}]"), f"{path}[{i}]"


def _parse_pair_checks(value: Any, path: str) -> tuple[PairPoseCheck, ...]:
    out = []
    for c, here in _items(value, path):
        cameras = v.strings(v.require(c, "cameras", here), f"{here}.cameras")
        if len(cameras) != 2:
            raise InputError(f"{here}.cameras: expected two camera ids, got {len(cameras)}")
        out.append(PairPoseCheck(
            cameras[0], cameras[1], *(v.number(v.require(c, k, here), f"{here}.{k}")
                                      for k in ("rotation_deg", "direction_deg", "in_sigmas")),
            *(v.integer(v.require(c, k, here), f"{here}.{k}") for k in ("shared", "inliers"))))
    return tuple(out)


def _parse_lens_shifts(value: Any, path: str) -> dict[str, LensShift]:
    out = {}
    for cam_id, shift in v.mapping(value, path).items():
        here = f"{path}.{cam_id}"
        shift = v.mapping(shift, here)
        out[cam_id] = LensShift(*(v.number(v.require(shift, k, here), f"{here}.{k}")
                                  for k in ("f_rel", "in_sigmas", "k1")))
    return out


def _parse_shares(value: Any, path: str) -> dict[str, float]:
    return {cam_id: v.number(share, f"{path}.{cam_id}") for cam_id, share in v.mapping(value, path).items()}


def _parse_rivals(value: Any, path: str) -> tuple[Rival, ...]:
    out = []
    for r, here in _items(value, path):
        differences = v.array(v.require(r, "differences", here), f"{here}.differences")
        out.append(Rival(
            start=v.string(v.require(r, "start", here), f"{here}.start"),
            **{key: v.number(v.require(r, key, here), f"{here}.{key}")
               for key in ("cost_px2", "kept_cost_px2", "cost_noise_px2")},
            differences=tuple(_parse_difference(d, f"{here}.differences[{k}]") for k, d in enumerate(differences)),
        ))
    return tuple(out)


def _parse_difference(value: Any, path: str) -> RivalDifference:
    d = v.mapping(value, path)
    camera = d.get("camera")
    return RivalDifference(
        parameter=v.string(v.require(d, "parameter", path), f"{path}.parameter", choices=DIFFERENCE_PARAMETERS),
        camera=None if camera is None else v.string(camera, f"{path}.camera"),
        **{key: v.number(v.require(d, key, path), f"{path}.{key}") for key in ("kept", "rival", "kept_sigma")},
    )


def _parse_halves(value: Any, path: str) -> HalvesCheck:
    value = v.mapping(value, path)
    numbers = {}
    for key in ("half_differences", "in_sigmas"):
        inner = v.mapping(value.get(key, {}), f"{path}.{key}")
        # A null in_sigmas is a difference no sigma covers (written for infinity).
        numbers[key] = {k: np.inf if x is None and key == "in_sigmas" else v.number(x, f"{path}.{key}.{k}")
                        for k, x in inner.items()}
    return HalvesCheck(v.integer(v.require(value, "splits", path), f"{path}.splits"), numbers["half_differences"],
                       numbers["in_sigmas"], tuple(v.strings(value.get("widened", []), f"{path}.widened")),
                       v.number(value.get("sigma_factor", 1.0), f"{path}.sigma_factor", positive=True),
                       str(value.get("reason", "")), tuple(v.strings(value.get("ruled_out", []), f"{path}.ruled_out")),
                       tuple(v.strings(value.get("from_whole", []), f"{path}.from_whole")))


def _parse_camera_stats(value: Any, path: str) -> dict[str, CameraStats]:
    out = {}
    for cam_id, stats in v.mapping(value, path).items():
        here = f"{path}.{cam_id}"
        out[cam_id] = CameraStats(
            rms_px=v.optional_number(v.mapping(stats, here).get("rms_px"), f"{here}.rms_px"),
            inliers=v.integer(v.require(stats, "inliers", here), f"{here}.inliers"),
        )
    return out


def _parse_left_out(value: Any, path: str) -> dict[str, str]:
    return {cam_id: v.string(why, f"{path}.{cam_id}") for cam_id, why in v.mapping(value, path).items()}


def _parse_free(value: Any, path: str) -> FreeSet:
    intrinsics = v.mapping(v.require(value, "intrinsics", path), f"{path}.intrinsics")
    return FreeSet(
        intrinsics={cam_id: v.strings(names, f"{path}.intrinsics.{cam_id}") for cam_id, names in intrinsics.items()},
        stereo_rotation_axes=v.strings(v.require(value, "stereo_rotation_axes", path), f"{path}.stereo_rotation_axes"),
        stereo_direction=v.boolean(value.get("stereo_direction", False), f"{path}.stereo_direction"),
    )


def _parse_points_left_out(value: Any, path: str) -> PointsLeftOut:
    counts = v.mapping(value, path)
    return PointsLeftOut(**{
        key: v.integer(counts.get(key, 0), f"{path}.{key}")
        for key in ("fewer_than_two_views", "behind_a_camera", "undetermined")
    })


def _sigma(value: Any, path: str) -> Sigma:
    number = v.optional_number(value, path)
    return Sigma(number) if number is not None else Sigma.unknown(NULL_SIGMA)


def _parse_uncertainty(value: Any, path: str) -> Uncertainty:
    u = v.mapping(value, path)
    sigma_px = v.optional_number(v.require(u, "sigma_px", path), f"{path}.sigma_px")
    if sigma_px is None:
        raise v.fail(f"{path}.sigma_px", "expected a number, got null")
    weights = u.get("point_weights")
    point_sigma = u.get("point_sigma_m")
    return Uncertainty(
        sigma_px=sigma_px,
        scale_rel=_sigma(u.get("scale_rel"), f"{path}.scale_rel"),
        scale_rel_if_pp_exact=_sigma(u.get("scale_rel_if_pp_exact"), f"{path}.scale_rel_if_pp_exact"),
        cameras={
            cam_id: _parse_camera_sigmas(s, f"{path}.cameras.{cam_id}")
            for cam_id, s in v.mapping(u.get("cameras", {}), f"{path}.cameras").items()
        },
        point_weights=None if weights is None else v.vector(weights, f"{path}.point_weights"),
        point_sigma_m=None if point_sigma is None else v.vector(point_sigma, f"{path}.point_sigma_m"),
        **{key: _sigma(u[key], f"{path}.{key}") for key in ("scale_rel_if_pair_exact", "scale_rel_if_pp_and_pair_exact")
           if key in u},  # absent (older documents, or no such cause): the dataclass's reason
    )


def _parse_camera_sigmas(value: Any, path: str) -> CameraSigmas:
    s = v.mapping(value, path)

    def one(value: Any, where: str) -> float:
        number = v.optional_number(value, where)
        return np.inf if number is None else number  # null: not determined

    def axes(key: str) -> tuple[float, float, float]:
        values = v.require(s, key, path)
        if not isinstance(values, list) or len(values) != 3:
            raise v.fail(f"{path}.{key}", "expected 3 numbers or nulls")
        return tuple(one(x, f"{path}.{key}[{i}]") for i, x in enumerate(values))

    return CameraSigmas(
        **{key: one(v.require(s, key, path), f"{path}.{key}") for key in ("f_px", "cx_px", "cy_px", "k1", "k2")},
        rotation_deg=axes("rotation_deg"),
        centre_m=axes("centre_m"),
    )
