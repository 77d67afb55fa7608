"""Reprojection residuals of a calibration against the observations it was solved from.

Used by the exports (COLMAP tracks) and the HTML report (per-point errors,
histograms). Pixels follow camnet's convention: origin at the centre of the
top-left pixel, u right, v down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camnet.errors import InputError
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations


@dataclass(frozen=True)
class Residuals:
    """One row per observation of a point the calibration kept.

    ``cam_index`` indexes ``cal.cameras``, ``point_index`` indexes
    ``cal.points`` (so ``cal.point_ids[point_index]`` is the track id) and
    ``obs_row`` the row of the observation in ``obs.uv``.
    """

    cam_index: np.ndarray  # (n,) int
    point_index: np.ndarray  # (n,) int
    obs_row: np.ndarray  # (n,) int
    uv_px: np.ndarray  # (n, 2) observed pixels
    residual_px: np.ndarray  # (n, 2) projected minus observed, pixels
    dropped_observations: int  # observations of tracks the calibration left out (outliers)

    @property
    def error_px(self) -> np.ndarray:
        """Reprojection error per observation (n,), pixels."""
        return np.linalg.norm(self.residual_px, axis=1)


def outlier_limit_px(cal: Calibration) -> float:
    """The solver's outlier rule (camnet.solve.options.Options): 4 sigma_px, at least 1.5 px.

    sigma_px is the calibration's ``uncertainty.sigma_px``, else its RMS;
    without either, infinity (nothing is an outlier).
    """
    from camnet.solve.options import Options

    options = Options()
    sigma = cal.uncertainty.sigma_px if cal.uncertainty is not None else cal.rms_reprojection_px
    if not math.isfinite(sigma):
        return math.inf
    return max(options.outlier_sigmas * float(sigma), options.min_outlier_px)


def reprojection_residuals(cal: Calibration, obs: Observations) -> Residuals:
    """Project every kept point into every camera that observed it.

    The observations of a camera that the calibration's report names as
    left out are skipped; any other observation camera that the calibration
    lacks is an `InputError`.
    """
    cal_index = {cam.id: m for m, cam in enumerate(cal.cameras)}
    left_out = cal.report.cameras_left_out if cal.report is not None else {}
    for cam in obs.cameras:
        if cam.id not in cal_index and cam.id not in left_out:
            raise InputError(f"observations: camera {cam.id!r} is not in the calibration")
    cam_of_obs_camera = np.array([cal_index.get(c.id, -1) for c in obs.cameras], dtype=np.int64)
    point_of_id = {int(pid): j for j, pid in enumerate(cal.point_ids)}
    point_of_track = np.array([point_of_id.get(int(t), -1) for t in obs.track_ids], dtype=np.int64)
    point_index = point_of_track[obs.track_index] if len(obs.track_index) else np.zeros(0, dtype=np.int64)
    placed = cam_of_obs_camera[obs.cam_index] >= 0 if len(obs.cam_index) else np.zeros(0, dtype=bool)
    kept = (point_index >= 0) & placed
    rows = np.flatnonzero(kept)
    cam_index = cam_of_obs_camera[obs.cam_index[rows]]
    point_index = point_index[rows]
    projected = np.full((len(rows), 2), np.nan)
    for m, cam in enumerate(cal.cameras):
        mine = cam_index == m
        if mine.any():
            projected[mine] = cam.project(cal.points[point_index[mine]])
    uv = obs.uv[rows]
    return Residuals(
        cam_index=cam_index,
        point_index=point_index,
        obs_row=rows,
        uv_px=uv,
        residual_px=projected - uv,
        dropped_observations=int(np.sum(~kept & placed)),
    )
