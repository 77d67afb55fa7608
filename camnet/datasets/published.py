"""A calibration beside a data set's published calibration, where no true 3-D points exist.

Real data sets publish cameras, not scene points, so the scale is judged by
what the known baseline does not fix by construction: the distances between
scene points, triangulated once with the published stereo pair and once by
camnet, and the distance of each other camera from the left stereo camera.

All poses ``x_cam = R @ X + t`` in the left stereo camera's frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from camnet.model.accuracy import rotation_angle_deg, scale_sigma_rel
from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.model.observations import Observations


@dataclass(frozen=True)
class CameraVsPublished:
    id: str
    focal_rel: float  # fx / fx_published - 1
    focal_sigma_rel: float  # reported 1-sigma of fx, relative (0 when held, NaN without uncertainty)
    centre_mm: float  # |C - C_published|
    centre_sigma_mm: float  # reported 1-sigma, root of the summed per-axis variances
    direction_deg: float  # angle between C and C_published seen from the world origin (NaN at the origin)
    distance_rel: float  # |C| / |C_published| - 1 (NaN at the origin)
    rotation_deg: float  # angle of R R_published^T
    rotation_sigma_deg: float  # reported 1-sigma, root of the summed per-axis variances


def compare_cameras(cal: Calibration, published: dict[str, Camera]) -> list[CameraVsPublished]:
    """Per camera of `cal`, its errors against `published` (same ids, same world frame)."""
    sigmas = cal.uncertainty.cameras if cal.uncertainty is not None else {}
    out = []
    for cam in cal.cameras:
        ref = published[cam.id]
        u = sigmas.get(cam.id)
        norm_ref = float(np.linalg.norm(ref.centre))
        if norm_ref > 1e-9 and np.linalg.norm(cam.centre) > 1e-9:
            cos = cam.centre @ ref.centre / (np.linalg.norm(cam.centre) * norm_ref)
            direction = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
            distance = float(np.linalg.norm(cam.centre) / norm_ref - 1.0)
        else:
            direction = distance = float("nan")
        out.append(
            CameraVsPublished(
                id=cam.id,
                focal_rel=float(cam.K[0, 0] / ref.K[0, 0] - 1.0),
                focal_sigma_rel=u.f_px / ref.K[0, 0] if u is not None else float("nan"),
                centre_mm=1e3 * float(np.linalg.norm(cam.centre - ref.centre)),
                centre_sigma_mm=1e3 * float(np.linalg.norm(u.centre_m)) if u is not None else float("nan"),
                direction_deg=direction,
                distance_rel=distance,
                rotation_deg=rotation_angle_deg(cam.R @ ref.R.T),
                rotation_sigma_deg=float(np.linalg.norm(u.rotation_deg)) if u is not None else float("nan"),
            )
        )
    return out


def in_frame_of(cameras: dict[str, Camera], left_id: str) -> dict[str, Camera]:
    """The cameras re-expressed in camera `left_id`'s frame (a calibration's world frame)."""
    left = cameras[left_id]
    out = {}
    for cam_id, cam in cameras.items():
        # X = R_l^T (x_left - t_l), so x_cam = R R_l^T x_left + (t - R R_l^T t_l).
        R = cam.R @ left.R.T
        out[cam_id] = replace(cam, R=R, t=cam.t - R @ left.t)
    return out


def triangulate_stereo(obs: Observations, left: Camera, right: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Tracks seen by both stereo cameras, triangulated with `left` and `right`.

    Returns (track ids (N,), points (N, 3) in metres, world frame of the cameras).
    Pixels are undistorted with each camera's K and dist first.
    """
    seen = np.full((len(obs.track_ids), len(obs.cameras), 2), np.nan)
    seen[obs.track_index, obs.cam_index] = obs.uv
    uv_l, uv_r = seen[:, obs.index_of(left.id)], seen[:, obs.index_of(right.id)]
    both = np.isfinite(uv_l[:, 0]) & np.isfinite(uv_r[:, 0])
    if not both.any():
        return np.empty(0, dtype=np.int64), np.empty((0, 3))
    rays = [
        cv2.undistortPoints(uv[both].reshape(-1, 1, 2), cam.K, cam.dist).reshape(-1, 2).T
        for uv, cam in ((uv_l, left), (uv_r, right))
    ]
    P_l, P_r = (np.c_[cam.R, cam.t] for cam in (left, right))
    X_h = cv2.triangulatePoints(P_l, P_r, rays[0], rays[1])
    return obs.track_ids[both], (X_h[:3] / X_h[3]).T


def distance_scale(
    cal: Calibration,
    reference_ids: np.ndarray,
    reference_points: np.ndarray,
    *,
    depth_range_m: tuple[float, float] = (2.0, 15.0),
    max_points: int = 400,
) -> tuple[float, int]:
    """Median over point pairs of (camnet's distance / the reference distance) - 1, and the point count.

    Uses the points both hold whose reference depth (z in the world frame)
    lies in `depth_range_m`, where the reference triangulation is precise;
    at most `max_points` of them, evenly subsampled by track id.
    """
    index = {int(i): k for k, i in enumerate(cal.point_ids)}
    z = reference_points[:, 2]
    use = [k for k, i in enumerate(reference_ids) if int(i) in index and depth_range_m[0] <= z[k] <= depth_range_m[1]]
    if len(use) < 2:
        return float("nan"), len(use)
    use = np.asarray(use)[np.linspace(0, len(use) - 1, min(len(use), max_points)).astype(int)]
    ours = cal.points[[index[int(i)] for i in reference_ids[use]]]
    ref = reference_points[use]
    iu = np.triu_indices(len(use), k=1)
    d_ours = np.linalg.norm(ours[:, None] - ours[None], axis=2)[iu]
    d_ref = np.linalg.norm(ref[:, None] - ref[None], axis=2)[iu]
    return float(np.median(d_ours / d_ref) - 1.0), len(use)


@dataclass(frozen=True)
class VsPublished:
    """A whole calibration against the published one."""

    cameras: list[CameraVsPublished]
    distance_rel: float  # median relative error of 3-D point distances, see `distance_scale`
    distance_points: int  # points those distances were taken between
    scale_sigma_rel: float  # camnet's reported 1-sigma of its scale (NaN without uncertainty)
    rms_reprojection_px: float
    warnings: list[str]

    def camera(self, cam_id: str) -> CameraVsPublished:
        return next(c for c in self.cameras if c.id == cam_id)


def compare(cal: Calibration, obs: Observations, published: dict[str, Camera], *,
            depth_range_m: tuple[float, float] = (2.0, 15.0)) -> VsPublished:
    """`cal` (solved from `obs`) against `published`; points triangulated with its stereo pair, those at depths
    in `depth_range_m` compared (`distance_scale`)."""
    ids, points = triangulate_stereo(obs, published[obs.stereo.left], published[obs.stereo.right])
    distance_rel, n_points = distance_scale(cal, ids, points, depth_range_m=depth_range_m)
    return VsPublished(
        cameras=compare_cameras(cal, published),
        distance_rel=distance_rel,
        distance_points=n_points,
        scale_sigma_rel=scale_sigma_rel(cal),
        rms_reprojection_px=cal.rms_reprojection_px,
        warnings=list(cal.warnings),
    )
