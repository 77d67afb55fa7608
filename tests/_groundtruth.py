"""Ground-truth helpers for tests: data location and epipolar distances."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from camnet.model.camera import Camera

DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"
KITTI_ROOT = DATA_ROOT / "kitti_raw_2011_09_26_extract_3cam"
TEMPLE_ROOT = DATA_ROOT / "middlebury_temple_sparse_ring"
STRECHA_ROOT = DATA_ROOT / "strecha_fountain_p11"
CASTLE_ROOT = DATA_ROOT / "strecha_castle_p19"
WEBCAMS4_ROOT = DATA_ROOT / "webcams4_person_board"
FISHEYE_ROOT = DATA_ROOT / "fisheye220_rig4"


def require(path: Path) -> Path:
    """Skip the calling test when a shared data set is absent."""
    if not path.exists():
        pytest.skip(f"shared data set not found at ../shared/data/{path.name} (project-relative)")
    return path


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def fundamental(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F with x_b^T F x_a = 0 for undistorted pixels, from x_cam = R X + t."""
    R = cam_b.R @ cam_a.R.T
    t = cam_b.t - R @ cam_a.t
    return np.linalg.inv(cam_b.K).T @ _skew(t) @ R @ np.linalg.inv(cam_a.K)


def undistort_px(uv: np.ndarray, cam: Camera) -> np.ndarray:
    """Raw pixels (n, 2) to undistorted pixels under the same K."""
    if not np.any(cam.dist) or len(uv) == 0:  # OpenCV returns None for no points
        return np.asarray(uv, dtype=float).reshape(-1, 2)
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, cam.K, cam.dist, P=cam.K).reshape(-1, 2)


def epipolar_distance_px(uv_a: np.ndarray, uv_b: np.ndarray, cam_a: Camera, cam_b: Camera):
    """Per match, the larger of the two point-to-epipolar-line distances (px)."""
    F = fundamental(cam_a, cam_b)
    ha = np.c_[undistort_px(uv_a, cam_a), np.ones(len(uv_a))]
    hb = np.c_[undistort_px(uv_b, cam_b), np.ones(len(uv_b))]
    line_b = ha @ F.T
    line_a = hb @ F
    algebraic = np.abs(np.sum(hb * line_b, axis=1))
    return np.maximum(algebraic / np.hypot(*line_b[:, :2].T), algebraic / np.hypot(*line_a[:, :2].T))


def pairwise_epipolar_fractions(uv: np.ndarray, cameras: list[Camera], tol_px: float) -> dict:
    """For each camera pair of tracks `uv` (T, C, 2; NaN = unseen): (count, fraction within tol)."""
    out = {}
    for i in range(len(cameras)):
        for j in range(i + 1, len(cameras)):
            both = np.isfinite(uv[:, i, 0]) & np.isfinite(uv[:, j, 0])
            d = epipolar_distance_px(uv[both, i], uv[both, j], cameras[i], cameras[j])
            frac = float(np.mean(d <= tol_px)) if d.size else float("nan")
            out[(cameras[i].id, cameras[j].id)] = (int(both.sum()), frac)
    return out
