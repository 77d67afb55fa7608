"""One camera's feature stage: detect only where the image changed since the camera's keyframe.

A static camera sees the same background in every frame; detecting it again
costs the same SIFT time and brings the matcher nothing new. So each camera
keeps a keyframe (a frame detected whole) and, for every later frame:

- finds the box of pixels that differ from the keyframe (compared on
  copies blurred and downscaled `CHANGE_CELL_PX` times, which smooths away
  sensor noise), grown by `margin_px`, so that SIFT's support around a
  keypoint lies inside;
- detects afresh inside the box only, and keeps the keyframe's keypoints
  outside it as they are ("reused": the same pixels, the same descriptors).

A frame that changed over more than `max_changed_fraction` of the image
(the camera moved, the light changed), or every `keyframe_period` frames,
is detected whole and becomes the keyframe. The reused keypoints come first,
so a consumer knows which keypoints it has seen before (`CameraFeatures`).
The same code runs beside a driver (`camnet driver --features`) and inside
the matcher for a camera that sends only frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from camnet.matching.features import (
    Features,
    MatcherConfig,
    detect_grey,
    detection_grey,
    detection_scale,
    empty_descriptors,
    few_features_reason,
    to_8bit,
)

CHANGE_CELL_PX = 8  # the change mask is computed on 8x8-pixel cells


@dataclass(frozen=True)
class EdgeConfig:
    """When a frame is detected whole, and how a change is told from noise."""

    keyframe_period: int = 30  # at least every this many frames, detect whole (1: always)
    change_threshold_dn: float = 6.0  # a cell changed when its mean grey moved by more (of 255)
    margin_px: int = 32  # the box of change grows by this on every side
    max_changed_fraction: float = 0.5  # a box over this part of the image: detect whole

    def __post_init__(self) -> None:
        if self.keyframe_period < 1:
            raise ValueError(f"keyframe_period must be at least 1, got {self.keyframe_period}")
        if not self.change_threshold_dn > 0 or self.margin_px < 0:
            raise ValueError("change_threshold_dn must be > 0 and margin_px >= 0")
        if not 0.0 <= self.max_changed_fraction <= 1.0:
            raise ValueError(f"max_changed_fraction must be in [0, 1], got {self.max_changed_fraction}")


@dataclass(frozen=True)
class CameraFeatures:
    """The features of one frame of one camera, and which of them were seen before.

    The first `reused` keypoints of `features` are keypoints of the frame
    `keyframe_seq` of this camera, unchanged (static background); the rest
    were detected in this frame. `reused` is 0 for a keyframe.
    """

    camera_id: str
    seq: int
    timestamp_ns: int
    width: int
    height: int
    features: Features
    keyframe_seq: int
    reused: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.reused <= len(self.features):
            raise ValueError(f"reused must be in [0, {len(self.features)}], got {self.reused}")


def change_box(reference: np.ndarray, small: np.ndarray, *, threshold_dn: float, margin_px: int,
               shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) pixels of the cells where `small` differs from `reference` (cell means, uint8),
    grown by `margin_px` and clipped to `shape` (h, w); None where nothing changed."""
    changed = cv2.absdiff(reference, small) > threshold_dn
    if not changed.any():
        return None
    rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
    x0 = max(0, cols[0] * CHANGE_CELL_PX - margin_px)
    y0 = max(0, rows[0] * CHANGE_CELL_PX - margin_px)
    x1 = min(shape[1], (cols[-1] + 1) * CHANGE_CELL_PX + margin_px)
    y1 = min(shape[0], (rows[-1] + 1) * CHANGE_CELL_PX + margin_px)
    return int(x0), int(y0), int(x1), int(y1)


def _cells(grey8: np.ndarray) -> np.ndarray:
    """Mean grey of each CHANGE_CELL_PX cell: averaging 64 pixels divides the noise by 8."""
    h, w = grey8.shape
    return cv2.resize(grey8, (max(1, w // CHANGE_CELL_PX), max(1, h // CHANGE_CELL_PX)),
                      interpolation=cv2.INTER_AREA)


class FeatureExtractor:
    """The feature stage of one camera; `extract` one frame after the other. Not thread-safe."""

    def __init__(self, camera_id: str, config: MatcherConfig | None = None, edge: EdgeConfig | None = None) -> None:
        self.camera_id = camera_id
        self.config = MatcherConfig() if config is None else config
        self.edge = EdgeConfig() if edge is None else edge
        self._key: CameraFeatures | None = None
        self._key_cells: np.ndarray | None = None
        self._since_key = 0
        self.full = 0  # frames detected whole
        self.partial = 0  # frames detected in their box of change only

    def extract(self, image: np.ndarray, *, seq: int, timestamp_ns: int) -> CameraFeatures:
        raw, grey = detection_grey(image, self.config)
        cells = _cells(to_8bit(raw))
        h, w = grey.shape
        box = None
        key = self._key
        if key is not None and (key.width, key.height) == (w, h) and self._since_key < self.edge.keyframe_period - 1:
            box = change_box(self._key_cells, cells, threshold_dn=self.edge.change_threshold_dn,
                             margin_px=self.edge.margin_px, shape=(h, w))
            if box is None:
                box = (0, 0, 0, 0)
            if (box[2] - box[0]) * (box[3] - box[1]) > self.edge.max_changed_fraction * w * h:
                box = None
        if box is None:
            return self._keyframe(raw, grey, cells, seq=seq, timestamp_ns=timestamp_ns)
        return self._partial(raw, grey, box, seq=seq, timestamp_ns=timestamp_ns)

    def _keyframe(self, raw, grey, cells, *, seq: int, timestamp_ns: int) -> CameraFeatures:
        config = self.config
        uv, descriptors = detect_grey(grey, config, scale=detection_scale(grey.shape, config))
        features = self._features(raw, uv, descriptors)
        self._key = CameraFeatures(self.camera_id, seq, timestamp_ns, grey.shape[1], grey.shape[0], features,
                                   keyframe_seq=seq)
        self._key_cells = cells
        self._since_key = 0
        self.full += 1
        return self._key

    def _partial(self, raw, grey, box, *, seq: int, timestamp_ns: int) -> CameraFeatures:
        x0, y0, x1, y1 = box
        key = self._key.features
        outside = ~((key.uv[:, 0] >= x0) & (key.uv[:, 0] < x1) & (key.uv[:, 1] >= y0) & (key.uv[:, 1] < y1))
        uv, descriptors = [key.uv[outside]], [key.descriptors[outside]]
        if x1 > x0 and y1 > y0:
            # The box gets what its area had in the keyframe, at least a quarter of the budget.
            budget = max(self.config.max_features - int(outside.sum()), self.config.max_features // 4)
            crop = np.ascontiguousarray(grey[y0:y1, x0:x1])
            found, found_desc = detect_grey(crop, self.config, scale=detection_scale(grey.shape, self.config),
                                            max_features=budget)
            if found_desc is not None:
                uv.append(found + (x0, y0))
                descriptors.append(found_desc.astype(key.descriptors.dtype, copy=False))
        features = self._features(raw, np.concatenate(uv), np.concatenate(descriptors))
        self._since_key += 1
        self.partial += 1
        return CameraFeatures(self.camera_id, seq, timestamp_ns, grey.shape[1], grey.shape[0], features,
                              keyframe_seq=self._key.keyframe_seq, reused=int(outside.sum()))

    def _features(self, raw: np.ndarray, uv: np.ndarray, descriptors: np.ndarray | None) -> Features:
        config = self.config
        shortage = few_features_reason(raw, len(uv)) if len(uv) < config.few_features else None
        if descriptors is None:
            descriptors = empty_descriptors(config.detector)
        return Features(uv, descriptors, config.detector, shortage)
