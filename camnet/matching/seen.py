"""Which of a camera's keypoints the matcher has seen before, at a new keyframe too.

A camera's feature stage marks as reused the keypoints it copied from its
keyframe (`camnet.matching.edge`), but a new keyframe, every
`keyframe_period` frames, detects the whole image again: the same static
background, at the same pixels give or take the sensor noise. Matching its
pairs whole again, at a dozen times the cost of matching what changed, only
finds the background the pool holds already, and keyframes' whole matches
then make most of a frame set's matching (docs/benchmarks.md, "Sixteen
cameras across hosts"; "Evidence behind the nodes' choices").

So the matcher remembers each camera's previous keypoints. At a keyframe, a
keypoint within `RADIUS_PX` of one of them, with a descriptor within
`MAX_DESCRIPTOR_DISTANCE` of its descriptor, was seen (and matched, in the
frame set where it first appeared); only the others are new. A keyframe with
at least `CONTINUE_SHARE` of its keypoints seen continues its camera's
epoch: the pairs' F from their last whole match still hold, and its pairs
are matched on what is new. A keyframe that does not (the camera moved, the
light changed) starts a new epoch, whose pairs are matched whole.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from camnet.matching.edge import CameraFeatures
from camnet.matching.features import Features

# Sensor noise moves a re-detected keypoint by a fraction of a pixel; one pixel still tells two keypoints apart
# (the pool's duplicate radius).
RADIUS_PX = 1.0
# Of SIFT's descriptors (whole numbers, norm about 512): the same static point re-detected under new noise is
# some tens apart, a different point at the same pixel (the moving object in front of the background) hundreds.
MAX_DESCRIPTOR_DISTANCE = 120.0
# A keyframe with at least this share of its keypoints seen before shows the same scene from the same place: a
# static camera's keyframe has well over this share seen (the rest lie where the scene moved, or are noise), a
# moved camera's none (docs/benchmarks.md, "Sixteen cameras across hosts").
CONTINUE_SHARE = 0.15


@dataclass(frozen=True)
class _Previous:
    keyframe_seq: int  # the stage's keyframe of the previous frame
    epoch: int  # the matcher's: the keyframe whose whole matches the camera's pairs still rest on
    uv: np.ndarray
    descriptors: np.ndarray


def seen_mask(uv: np.ndarray, descriptors: np.ndarray, tree: cKDTree, previous_descriptors: np.ndarray, *,
              radius_px: float = RADIUS_PX, max_distance: float = MAX_DESCRIPTOR_DISTANCE) -> np.ndarray:
    """Boolean (n,): keypoints `uv` (n, 2) px within `radius_px` of a previous keypoint (`tree` of their
    pixels) whose descriptor is within `max_distance` (L2) of theirs."""
    if len(uv) == 0 or tree.n == 0:
        return np.zeros(len(uv), dtype=bool)
    _, nearest = tree.query(uv, k=1, distance_upper_bound=radius_px)
    near = nearest < tree.n
    seen = np.zeros(len(uv), dtype=bool)
    rows = np.flatnonzero(near)
    if len(rows):
        diff = descriptors[rows].astype(np.float32) - previous_descriptors[nearest[rows]].astype(np.float32)
        seen[rows] = np.einsum("ij,ij->i", diff, diff) <= max_distance**2
    return seen


class SeenBefore:
    """Per camera, its previous keypoints; `mark` reorders a frame's keypoints seen before to the front.

    Not thread-safe: call it once per frame set, before the pairs are matched.
    """

    def __init__(self) -> None:
        self._previous: dict[str, _Previous] = {}
        self.continued = 0  # keyframes that continued their camera's epoch
        self.restarted = 0  # keyframes that started a new one

    def forget(self, camera_id: str) -> None:
        self._previous.pop(camera_id, None)

    def mark(self, camera: CameraFeatures) -> CameraFeatures:
        """`camera` with its keypoints seen before first (`reused` of them) and `keyframe_seq` its epoch.

        Between keyframes the stage's own reused keypoints are the seen ones: testing its new keypoints too
        finds few of them seen, at about the cost it saves (docs/benchmarks.md, "Sixteen cameras across hosts")."""
        features = camera.features
        previous = self._previous.get(camera.camera_id)
        self._previous[camera.camera_id] = _Previous(camera.keyframe_seq, camera.keyframe_seq, features.uv,
                                                     features.descriptors)
        if previous is None:
            return camera
        if previous.keyframe_seq == camera.keyframe_seq:
            self._previous[camera.camera_id] = replace(self._previous[camera.camera_id], epoch=previous.epoch)
            return camera if previous.epoch == camera.keyframe_seq else replace(camera, keyframe_seq=previous.epoch)
        seen = seen_mask(features.uv, features.descriptors, cKDTree(previous.uv), previous.descriptors)
        if len(seen) == 0 or seen.mean() < CONTINUE_SHARE:
            self.restarted += 1
            return camera
        self.continued += 1
        self._previous[camera.camera_id] = replace(self._previous[camera.camera_id], epoch=previous.epoch)
        order = np.concatenate([np.flatnonzero(seen), np.flatnonzero(~seen)])
        kept = Features(features.uv[order], features.descriptors[order], features.detector, features.shortage)
        return replace(camera, features=kept, keyframe_seq=previous.epoch, reused=int(seen.sum()))
