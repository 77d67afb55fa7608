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
    """When a camera counts as moved: on evidence a static rig cannot produce.

    Its views of new tracks that its neighbours hold on their calibrated poses (`neighbour_views`: each point
    triangulated without it, every other camera seeing it within
    `neighbour_share` of its limit) must lie off its own pose, their
    median error beyond both `min_px` and `factor` times its RMS at the last calibration, over at least
    `min_observations` views; and those from where they leave its pose on must fit one new placement of it
    (its lens held) within that same limit, or `factor` times nearer than its pose (views noisier since the
    move). A static camera of a free-running rig whose views of a moving person were taken a few milliseconds
    from its neighbours' lies off its pose by a displacement that changes with the motion, which no one
    placement explains: a suspected move, not confirmed.
    """

    factor: float = 4.0
    min_px: float = 2.0
    min_observations: int = 12
    # Over this many frame sets (where the observations say how many they pool): one frame set's moving person,
    # seen a few ms apart, can fit a new placement as a moved camera's views do; several moving differently cannot.
    frame_sets: int = 3
    # A neighbour holds a track on its pose within this share of its limit: one further off would carry its own
    # error, through the point it places, into the camera judged.
    neighbour_share: float = 0.5

    def limit_px(self, reference_rms_px: float | None) -> float:
        """The error (px) beyond which a camera's observation is off its calibrated pose."""
        return max(self.min_px, self.factor * (reference_rms_px or 0.0))


@dataclass(frozen=True)
class MoveEvidence:
    """One camera's views judged by `MoveRule` (those its neighbours hold on their poses): from which track id
    on they are judged, how many, their median error (px) on its calibrated pose and on the one new placement
    that fits them best (inf where not tried: on its pose), its limit (px) and the rule's `factor`."""

    first_track_id: int
    views: int
    off_pose_px: float
    replaced_px: float
    limit_px: float
    factor: float = 4.0
    # Of them, those of the newest tracks (`move_evidence`'s `newest_from` on): how many, their median error (px).
    newest_views: int = 0
    newest_off_px: float = float("nan")

    @property
    def off_pose(self) -> bool:
        """Whether its views lie off its calibrated pose: a move suspected."""
        return self.off_pose_px > self.limit_px

    @property
    def moved(self) -> bool:
        """Whether its views lie off its calibrated pose and one new placement explains them: a rigid move. The
        new placement puts them within its limit, or (views noisier since) `factor` times nearer than its pose."""
        return self.off_pose and self.replaced_px <= max(self.limit_px, self.off_pose_px / self.factor)


def _pixel_table(calibration: Calibration, obs: Observations, rows: np.ndarray) -> tuple[list[Camera], np.ndarray]:
    """The calibrated cameras the observations hold, and their pixels (T, C, 2) of the tracks at `rows` (NaN:
    unseen)."""
    cameras = [c for c in calibration.cameras if c.id in obs.camera_ids]
    column = {obs.index_of(c.id): k for k, c in enumerate(cameras)}
    uv = np.full((len(obs.track_ids), len(cameras), 2), np.nan)
    for c, k in column.items():
        mine = obs.cam_index == c
        uv[obs.track_index[mine], k] = obs.uv[mine]
    return cameras, uv[np.asarray(rows, dtype=np.int64)]


def _triangulate_many(P: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Points (T, 3) from normalised views `xn` (T, C, 2; NaN: unseen) of cameras `P` (C, 3, 4), linear least
    squares over the views each track has (two or more)."""
    seen = np.isfinite(xn[:, :, 0])
    x = np.where(seen[..., None], xn, 0.0)
    rows = np.concatenate([x[:, :, :1] * P[None, :, 2] - P[None, :, 0],
                           x[:, :, 1:] * P[None, :, 2] - P[None, :, 1]], axis=1)  # (T, 2C, 4)
    rows *= np.concatenate([seen, seen], axis=1)[..., None]
    _, _, vt = np.linalg.svd(rows)
    Xh = vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return Xh[:, :3] / Xh[:, 3:]


def neighbour_views(calibration: Calibration, obs: Observations, rows: np.ndarray,
                    limits_px: Mapping[str, float], without: Mapping[str, str] | None = None,
                    ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per calibrated camera, its views of the tracks at `rows` that its neighbours hold on their poses: (track
    ids, points X (n, 3) in metres, world frame, its pixels (n, 2)).

    Each point is triangulated without the camera, from the two or more other cameras that see the track, and
    kept only where every one of them sees it in front and within its `limits_px` (a camera missing there: no
    limit). A static rig's views of a moving person taken at slightly different instants put the neighbours
    off too, where one moved camera leaves them on theirs. without: per camera, another left out of its
    neighbours too (only the cameras named are judged then).
    """
    cameras, uv = _pixel_table(calibration, obs, rows)
    ids = obs.track_ids[np.asarray(rows, dtype=np.int64)]
    xn = np.full(uv.shape, np.nan)
    for k, cam in enumerate(cameras):
        seen = np.isfinite(uv[:, k, 0])
        if seen.any():
            xn[seen, k] = cam.normalised(uv[seen, k])
    P = np.array([np.hstack([cam.R, cam.t[:, None]]) for cam in cameras])
    limit = np.array([limits_px.get(cam.id, np.inf) for cam in cameras])
    views = {}
    for k, cam in enumerate(cameras):
        if without is not None and cam.id not in without:
            continue
        others = [j for j in range(len(cameras)) if j != k and (without is None or cameras[j].id != without[cam.id])]
        seen = np.isfinite(uv[:, :, 0])
        judged = seen[:, k] & (seen[:, others].sum(axis=1) >= 2)
        X = _triangulate_many(P[others], xn[judged][:, others])
        on = np.all(np.isfinite(X), axis=1)
        for j in others:
            there = seen[judged, j]
            depth = np.einsum("ij,nj->ni", cameras[j].R, X)[:, 2] + cameras[j].t[2]
            with np.errstate(invalid="ignore"):
                err = np.linalg.norm(cameras[j].project(X) - uv[judged, j], axis=1)
            on &= ~there | ((depth > 0) & (err <= limit[j]))
        depth = np.einsum("ij,nj->ni", cam.R, X)[:, 2] + cam.t[2]
        on &= depth > 0
        views[cam.id] = (ids[judged][on], X[on], uv[judged, k][on])
    return views


def neighbour_errors(calibration: Calibration, obs: Observations, rows: np.ndarray,
                     limits_px: Mapping[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per calibrated camera, (track ids, errors px) of its views that its neighbours hold on their poses
    (`neighbour_views`), against the pose `calibration` gives it."""
    by_id = {c.id: c for c in calibration.cameras}
    return {cam_id: (ids, np.linalg.norm(by_id[cam_id].project(X) - uv, axis=1))
            for cam_id, (ids, X, uv) in neighbour_views(calibration, obs, rows, limits_px).items()}


def replaced_errors(camera: Camera, X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The errors (px) of the views `uv` (n, 2) of points `X` (n, 3, metres, world frame) on the pose that fits
    them best by least squares (n >= 6), `camera`'s lens held: how well one new placement explains them."""
    xn = camera.normalised(uv)
    ok, rvec, tvec = cv2.solvePnP(X.astype(np.float64), xn.astype(np.float64), np.eye(3), None,
                                  flags=cv2.SOLVEPNP_EPNP)
    if not ok:
        return np.full(len(uv), np.inf)
    ok, rvec, tvec = cv2.solvePnP(X.astype(np.float64), xn.astype(np.float64), np.eye(3), None, rvec, tvec,
                                  useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    R = cv2.Rodrigues(rvec)[0]
    placed = replace(camera, R=R, t=tvec.ravel())
    with np.errstate(invalid="ignore"):
        err = np.linalg.norm(placed.project(X) - uv, axis=1)
    return np.where(np.isfinite(err), err, np.inf)


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


def move_evidence(calibration: Calibration, obs: Observations, rows: np.ndarray,
                  reference_rms_px: Mapping[str, float | None], rule: MoveRule = MoveRule(),
                  since: Mapping[str, int] | None = None, newest_from: int | None = None,
                  partners: Mapping[str, str] | None = None) -> dict[str, MoveEvidence]:
    """Per camera with at least `rule.min_observations` views of the tracks at `rows` that its neighbours hold
    on their poses (`neighbour_views`), the evidence `MoveRule` judges. Its views are judged from track id
    `since[camera]` on where given, else from where they leave its pose (`first_moved_track`); those of tracks
    from `newest_from` on (None: all) also alone.

    partners: cameras that move together (a stereo head's two), each by the other's id. Where a camera's partner
    sees most of its tracks and moved with it, the partner puts every one of them off, and the camera has too few
    views left to judge: it is judged on its views without its partner among its neighbours.
    """
    limits = {c.id: rule.limit_px(reference_rms_px.get(c.id)) for c in calibration.cameras}
    by_id = {c.id: c for c in calibration.cameras}
    evidence = {}
    held = {c: rule.neighbour_share * limit for c, limit in limits.items()}
    views = neighbour_views(calibration, obs, rows, held)
    hidden = {c: p for c, p in (partners or {}).items() if c in views and len(views[c][0]) < rule.min_observations}
    if hidden:
        views |= neighbour_views(calibration, obs, rows, held, without=hidden)
    for cam_id, (ids, X, uv) in views.items():
        err = np.linalg.norm(by_id[cam_id].project(X) - uv, axis=1)
        if not len(err):
            continue
        first = since[cam_id] if since is not None and cam_id in since else first_moved_track(ids, err, limits[cam_id])
        mine = ids >= first
        if mine.sum() < rule.min_observations:
            continue
        off_px, replaced = float(np.median(err[mine])), np.inf
        if off_px > limits[cam_id] and mine.sum() >= 6:
            replaced = float(np.median(replaced_errors(by_id[cam_id], X[mine], uv[mine])))
        newest = mine & (ids >= (first if newest_from is None else newest_from))
        evidence[cam_id] = MoveEvidence(first, int(mine.sum()), off_px, replaced, limits[cam_id], rule.factor,
                                        int(newest.sum()), float(np.median(err[newest])) if newest.any() else np.nan)
    return evidence


def off_their_pose(calibration: Calibration, obs: Observations, cutoffs: Mapping[str, int],
                   limits_px: Mapping[str, float], *, min_observations: int,
                   neighbour_limits_px: Mapping[str, float] | None = None) -> dict[str, float]:
    """Of the cameras in `cutoffs` that `calibration` places, those whose views of the tracks from their
    cut-off on lie off the pose it gives them, each with its median error (px): a moved camera solved
    back at (or near) its old pose. A camera is judged against its `limits_px` on at least
    `min_observations` views (those its neighbours hold within `neighbour_limits_px`, `neighbour_views`;
    None: any), and passes with fewer.
    """
    placed = {c.id for c in calibration.cameras}
    judged = {cam_id: cut for cam_id, cut in cutoffs.items() if cam_id in placed and cam_id in obs.camera_ids}
    if not judged:
        return {}
    errors = neighbour_errors(calibration, obs, np.flatnonzero(obs.track_ids >= min(judged.values())),
                              {**(neighbour_limits_px or {}), **limits_px})
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
