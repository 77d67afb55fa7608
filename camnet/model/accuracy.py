"""Accuracy against ground truth: a point cloud beside the true one (similarity, scale, shape), and a
calibration beside its true cameras (per-camera and whole-network errors) or beside new observations.

Lengths in metres; ``x_cam = R X + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from camnet.model.calibration import Calibration
from camnet.model.camera import Camera


def similarity(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s * R @ src + t`` (Umeyama 1991): (s, R, t).

    weights (n,): per-point weights of the squared distances (default equal).
    """
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    ms, md = w @ src, w @ dst
    a, b = src - ms, dst - md
    U, D, Vt = np.linalg.svd((b * w[:, None]).T @ a)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / np.sum(w[:, None] * a * a))
    return s, R, md - s * R @ ms


def scale_error(estimated: np.ndarray, true: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Relative scale error of an estimated cloud (n, 3): s - 1 for ``est ~ s R true + t``.

    weights (n,): as in `similarity`; camnet's reported scale uses the points'
    inverse variances (`camnet.solve.uncertainty.scale_weights`).
    """
    s, _, _ = similarity(true, estimated, weights)
    return s - 1.0


def shape_rms_m(estimated: np.ndarray, true: np.ndarray) -> float:
    """RMS distance (m) between the true cloud and the estimate after similarity alignment."""
    s, R, t = similarity(estimated, true)
    aligned = s * estimated @ R.T + t
    return float(np.sqrt(np.mean(np.sum((aligned - true) ** 2, axis=1))))


@dataclass(frozen=True)
class CameraError:
    id: str
    focal_rel: float  # (f - f_true) / f_true
    focal_sigma_rel: float  # reported 1-sigma, relative (NaN if none)
    centre_mm: float  # |C - C_true|
    centre_sigma_mm: float  # reported, RMS over axes times sqrt(3) (NaN if none)
    rotation_deg: float  # angle of R R_true^T


@dataclass(frozen=True)
class Comparison:
    scale_rel: float  # similarity scale of the cloud minus 1
    scale_sigma_rel: float
    shape_rms_mm: float
    rms_reprojection_px: float
    cameras: list[CameraError]


def rotation_angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (degrees, 0-180) between two 3-vectors."""
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))))


def compare(cal: Calibration, truth_cameras: list[Camera], truth_points: np.ndarray) -> Comparison:
    """Errors of `cal` against the truth; truth_points are indexed by track id."""
    truth = {c.id: c for c in truth_cameras}
    sigmas = cal.uncertainty.cameras if cal.uncertainty is not None else {}
    cams = []
    for cam in cal.cameras:
        t = truth[cam.id]
        u = sigmas.get(cam.id)
        cams.append(
            CameraError(
                id=cam.id,
                focal_rel=float(cam.K[0, 0] / t.K[0, 0] - 1.0),
                focal_sigma_rel=(u.f_px if u is not None else np.nan) / t.K[0, 0],
                centre_mm=1e3 * float(np.linalg.norm(cam.centre - t.centre)),
                centre_sigma_mm=1e3 * float(np.linalg.norm(u.centre_m)) if u is not None else np.nan,
                rotation_deg=rotation_angle_deg(cam.R @ t.R.T),
            )
        )
    X_true = truth_points[cal.point_ids]
    return Comparison(
        scale_rel=scale_error(cal.points, X_true, point_weights(cal)),
        scale_sigma_rel=scale_sigma_rel(cal),
        shape_rms_mm=1e3 * shape_rms_m(cal.points, X_true),
        rms_reprojection_px=cal.rms_reprojection_px,
        cameras=cams,
    )


def point_weights(cal: Calibration) -> np.ndarray | None:
    """Weights of the calibration's points in its reported scale, None without uncertainty."""
    w = cal.uncertainty.point_weights if cal.uncertainty is not None else None
    return None if w is None or len(w) != len(cal.points) else np.asarray(w, dtype=float)


def scale_sigma_rel(cal: Calibration) -> float:
    """The calibration's reported relative 1 sigma of its scale; NaN when it has none."""
    if cal.uncertainty is None or cal.uncertainty.scale_rel.value is None:
        return float("nan")
    return cal.uncertainty.scale_rel.value


def format_comparison(c: Comparison) -> str:
    lines = [
        f"{'camera':<10} {'focal err %':>12} {'(1 sigma)':>10} "
        f"{'centre err mm':>14} {'(1 sigma)':>10} {'rot err deg':>12}",
    ]
    for e in c.cameras:
        lines.append(
            f"{e.id:<10} {100 * e.focal_rel:>12.3f} {100 * e.focal_sigma_rel:>10.3f} "
            f"{e.centre_mm:>14.3f} {e.centre_sigma_mm:>10.3f} {e.rotation_deg:>12.4f}"
        )
    lines.append(
        f"scale error {100 * c.scale_rel:+.4f}% (1 sigma {100 * c.scale_sigma_rel:.4f}%), "
        f"shape RMS {c.shape_rms_mm:.3f} mm, reprojection RMS {c.rms_reprojection_px:.3f} px"
    )
    return "\n".join(lines)


def compare_cameras(cal: Calibration, truth_cameras: list[Camera]) -> Comparison:
    """As `compare`, for a calibration whose points have no ground truth (a live rig).

    The scale and shape are those of the camera centres: the similarity
    that best maps the calibrated centres onto the true ones.
    """
    truth = {c.id: c for c in truth_cameras}
    centres = np.array([c.centre for c in cal.cameras])
    as_points = replace(cal, point_ids=np.arange(len(centres)), points=centres)
    return compare(as_points, truth_cameras, np.array([truth[c.id].centre for c in cal.cameras]))
