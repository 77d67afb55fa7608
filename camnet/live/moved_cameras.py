"""Detecting that a camera moved since the last calibration.

A live rig is calibrated once and then re-solved warm as tracks come in. When
somebody bumps a camera, the new tracks no longer fit that camera's
calibrated pose while they still fit the others. The test here: triangulate
each new track with the calibrated stereo pair alone (the pair fixes the
metric point without the camera under test), reproject it into every camera
that sees it, and compare each camera's median error with its reprojection
RMS at the last calibration.

Conventions: pixels with the origin at the centre of the top-left pixel,
``x_cam = R X + t``, metres.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, replace

import cv2
import numpy as np

from camnet.model.calibration import Calibration
from camnet.model.camera import Camera
from camnet.model.observations import Observations


@dataclass(frozen=True)
class MoveRule:
    """When a camera counts as moved.

    Its median error on new tracks must exceed both `min_px` and `factor`
    times its RMS at the last calibration, over at least `min_observations`
    observations.
    """

    factor: float = 4.0
    min_px: float = 2.0
    min_observations: int = 12

    def limit_px(self, reference_rms_px: float | None) -> float:
        """The error (px) beyond which a camera's observation is off its calibrated pose."""
        return max(self.min_px, self.factor * (reference_rms_px or 0.0))


def _normalised(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Undistorted normalised image coordinates (n, 2) of pixels (n, 2)."""
    return camera.normalised(uv)


def stereo_points(calibration: Calibration, obs: Observations, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points of the tracks at `rows` (indices into obs.track_ids) seen by both stereo cameras.

    Returns (rows kept, X (n, 3) in metres, world frame), triangulated linearly
    from the calibrated pair's undistorted rays.
    """
    by_id = {c.id: c for c in calibration.cameras}
    left, right = by_id[obs.stereo.left], by_id[obs.stereo.right]
    uv = {}
    for cam in (left, right):
        c = obs.index_of(cam.id)
        pix = np.full((len(obs.track_ids), 2), np.nan)
        mine = obs.cam_index == c
        pix[obs.track_index[mine]] = obs.uv[mine]
        uv[cam.id] = pix[rows]
    both = np.isfinite(uv[left.id][:, 0]) & np.isfinite(uv[right.id][:, 0])
    rows = np.asarray(rows)[both]
    if not len(rows):
        return rows, np.empty((0, 3))
    P = [np.hstack([cam.R, cam.t[:, None]]) for cam in (left, right)]
    xl, xr = (_normalised(cam, uv[cam.id][both]) for cam in (left, right))
    Xh = cv2.triangulatePoints(P[0], P[1], xl.T, xr.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T
    return rows, X


def new_track_errors(calibration: Calibration, obs: Observations, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Per camera id, the reprojection errors (px) of its observations of the tracks at `rows`.

    Each point is triangulated by the stereo pair alone (`stereo_points`);
    tracks the pair does not both see, and points behind a camera, are left
    out. Cameras missing from `calibration` get no entry.
    """
    return {cam_id: err for cam_id, (_, err) in track_errors(calibration, obs, rows).items()}


def track_errors(calibration: Calibration, obs: Observations,
                 rows: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """`new_track_errors` with, beside each camera's errors (px), the ids of the tracks they are of."""
    rows, X = stereo_points(calibration, obs, rows)
    point_of_row = np.full(len(obs.track_ids), -1)
    point_of_row[rows] = np.arange(len(rows))
    errors = {}
    for cam in calibration.cameras:
        if cam.id not in obs.camera_ids:
            continue
        mine = (obs.cam_index == obs.index_of(cam.id)) & (point_of_row[obs.track_index] >= 0)
        pixels = cam.project(X[point_of_row[obs.track_index[mine]]])
        err = np.linalg.norm(pixels - obs.uv[mine], axis=1)
        finite = np.isfinite(err)
        errors[cam.id] = (obs.track_ids[obs.track_index[mine]][finite], err[finite])
    return errors


def first_moved_track(track_ids: np.ndarray, errors_px: np.ndarray, limit_px: float) -> int:
    """The track id from which a moved camera's observations (of tracks `track_ids`, errors `errors_px`
    against its calibrated pose) lie off that pose.

    Track ids grow with time, so the observations of the old pose come first: the id returned splits
    them best, most of those before it within `limit_px` and most from it on beyond. A track pooled
    after the last solve but before the move saw the old pose: the first track id since that solve is
    not where the move began.
    """
    order = np.argsort(track_ids, kind="stable")
    off = np.where(errors_px[order] > limit_px, 1, -1)
    # From each position on: the observations off the pose less those on it.
    off_less_on = np.cumsum(off[::-1])[::-1]
    return int(track_ids[order][int(np.argmax(off_less_on))])


def moved_cameras(errors: dict[str, np.ndarray], reference_rms_px: dict[str, float],
                  rule: MoveRule = MoveRule()) -> list[str]:
    """Ids of the cameras whose errors on new tracks say they moved (see MoveRule)."""
    moved = []
    for cam_id, err in errors.items():
        if len(err) < rule.min_observations:
            continue
        if np.median(err) > rule.limit_px(reference_rms_px.get(cam_id)):
            moved.append(cam_id)
    return sorted(moved)


def off_their_pose(calibration: Calibration, obs: Observations, cutoffs: Mapping[str, int],
                   limits_px: Mapping[str, float], *, min_observations: int) -> dict[str, float]:
    """Of the cameras in `cutoffs` that `calibration` places, those whose views of the tracks from their
    cut-off on lie off the pose it gives them, each with its median error (px): a moved camera solved
    back at (or near) its old pose. A camera is judged against its `limits_px` on at least
    `min_observations` views (tracks the stereo pair sees: `track_errors`), and passes with fewer.
    """
    placed = {c.id for c in calibration.cameras}
    judged = {cam_id: cut for cam_id, cut in cutoffs.items() if cam_id in placed and cam_id in obs.camera_ids}
    if not judged:
        return {}
    errors = track_errors(calibration, obs, np.flatnonzero(obs.track_ids >= min(judged.values())))
    off = {}
    for cam_id, cut in judged.items():
        ids, err = errors.get(cam_id, (np.empty(0), np.empty(0)))
        err = err[ids >= cut]
        if len(err) >= min_observations and np.median(err) > limits_px[cam_id]:
            off[cam_id] = float(np.median(err))
    return off


def drop_before(obs: Observations, cutoffs: dict[str, int]) -> Observations:
    """`obs` without each camera's observations of tracks older than its cutoff.

    ``cutoffs[camera_id]`` is the first track id recorded after that camera
    moved: its earlier observations describe the old pose. Tracks left with
    fewer than two observations go too.
    """
    keep = np.ones(len(obs.uv), dtype=bool)
    for cam_id, first_id in cutoffs.items():
        if cam_id in obs.camera_ids:
            keep &= ~((obs.cam_index == obs.index_of(cam_id)) & (obs.track_ids[obs.track_index] < first_id))
    views = np.bincount(obs.track_index[keep], minlength=len(obs.track_ids))
    keep &= views[obs.track_index] >= 2
    rows = np.flatnonzero(views >= 2)
    new_row = np.full(len(obs.track_ids), -1)
    new_row[rows] = np.arange(len(rows))
    # replace(): the known distances beyond the stereo pair's stay (a new Observations lost them).
    return replace(obs, track_ids=obs.track_ids[rows], cam_index=obs.cam_index[keep],
                   track_index=new_row[obs.track_index[keep]], uv=obs.uv[keep])


def without_cameras(obs: Observations, camera_ids: Collection[str]) -> Observations:
    """`obs` without the cameras `camera_ids`, their observations and their known distances; tracks left with
    fewer than two observations go too."""
    dropped = drop_before(obs, {cam_id: int(obs.track_ids.max(initial=-1)) + 1 for cam_id in camera_ids})
    kept = np.array([c.id not in camera_ids for c in obs.cameras])
    new_index = np.cumsum(kept) - 1
    return replace(dropped, cameras=tuple(c for c, k in zip(obs.cameras, kept, strict=True) if k),
                   cam_index=new_index[dropped.cam_index],
                   baselines=tuple(b for b in obs.baselines if b.a not in camera_ids and b.b not in camera_ids))
