"""A session recorded by caliscope: one video per camera and the capture time of every frame.

``cam_<n>.mp4`` holds camera ``cam_<n>``'s frames in order, and
``timestamps.csv`` (``sync_index,cam_id,frame_time``) one capture time per
camera and sync index, in seconds on the recording host's clock (an
arbitrary origin). Frame k of a video is that camera's k-th sync index, so
frame k of every video is one instant, to within how far the free-running
cameras' exposures lie apart.
"""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np

from camnet.errors import InputError


def read_frame_times(path: str | Path) -> dict[str, np.ndarray]:
    """Camera id (``cam_<n>``) -> capture time of each of its frames in order, int64 ns on the recording's clock."""
    rows: dict[str, dict[int, float]] = {}
    try:
        with open(path, newline="") as f:
            for line, row in enumerate(csv.DictReader(f), start=2):
                try:
                    rows.setdefault(f"cam_{int(row['cam_id'])}", {})[int(row["sync_index"])] = float(row["frame_time"])
                except (KeyError, TypeError, ValueError):
                    raise InputError(f"{path}:{line}: expected sync_index,cam_id,frame_time numbers") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    out = {}
    for camera, times in sorted(rows.items()):
        indices = sorted(times)
        if indices != list(range(indices[0], indices[0] + len(indices))):
            raise InputError(f"{path}: {camera}'s sync indices have gaps; frame k of its video would be ambiguous")
        out[camera] = np.array([round(times[i] * 1e9) for i in indices], dtype=np.int64)
    return out


def read_video(path: str | Path) -> list[np.ndarray]:
    """Every frame of a video file, in order, as OpenCV decodes it (BGR uint8)."""
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise InputError(f"{path}: cannot open as a video")
    frames = []
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(frame)
    finally:
        capture.release()
    if not frames:
        raise InputError(f"{path}: no frame decoded")
    return frames
