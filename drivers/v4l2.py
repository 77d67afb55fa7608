"""V4L2 (USB) cameras, video files and image sequences, through cv2.VideoCapture.

`source` is a device path (/dev/video0) or index, a video file, or a glob
pattern of image files (sorted by name). Files and sequences are paced at the
configured fps (else the file's own, else 30) and stamped with the host clock
at the frame's due time; devices are stamped when the frame is grabbed.
"""

from __future__ import annotations

import glob
import logging
import time
from pathlib import Path

import cv2
import numpy as np

from camnet.frame import Frame
from camnet.rig import CameraEntry, Rig, V4l2Config
from drivers.base import CameraInfo, DeviceError, EndOfStream, ReadTimeout

log = logging.getLogger(__name__)

_DEFAULT_FILE_FPS = 30.0


def create(entry: CameraEntry, rig: Rig) -> V4l2Camera:
    return V4l2Camera(entry.id, entry.config)


def _is_pattern(source: str) -> bool:
    return any(ch in source for ch in "*?[")


def _to_encoding(image: np.ndarray, encoding: str) -> np.ndarray:
    if image.dtype != np.uint8:
        # 16-bit files: keep the most significant byte; camnet's v4l2 outputs are 8-bit.
        image = (image >> 8).astype(np.uint8) if image.dtype == np.uint16 else \
            image.astype(np.uint8)
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if encoding == "mono8":
        return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


class V4l2Camera:
    def __init__(self, camera_id: str, config: V4l2Config) -> None:
        self.camera_id = camera_id
        self.config = config
        self._capture = None
        self._files: list[str] = []
        self._index = 0
        self._seq = 0
        self._dropped = 0
        self._is_device = False
        self._fps = 0.0
        self._start_mono_ns = 0
        self._start_wall_ns = 0
        self._info: CameraInfo | None = None
        # The frame read while opening (to learn the size), handed out first.
        self._pending: np.ndarray | None = None

    @property
    def info(self) -> CameraInfo:
        if self._info is None:
            raise DeviceError(f"camera {self.camera_id!r}: not open")
        return self._info

    @property
    def dropped(self) -> int:
        return self._dropped

    def __enter__(self) -> V4l2Camera:
        source = self.config.source
        if _is_pattern(source):
            self._files = sorted(glob.glob(source))
            if not self._files:
                raise DeviceError(f"camera {self.camera_id!r}: no image matches {source!r}")
            first = self._read_file(self._files[0])
            self._fps = self.config.fps or _DEFAULT_FILE_FPS
            description = f"image sequence {source} ({len(self._files)} images)"
        else:
            first = self._open_capture(source)
            description = f"{'device' if self._is_device else 'video file'} {source}"
        self._start_mono_ns = time.monotonic_ns()
        self._start_wall_ns = time.time_ns()
        self._info = CameraInfo(camera_id=self.camera_id, driver="v4l2", width=first.shape[1],
                                height=first.shape[0], encoding=self.config.encoding,
                                fps=self._fps, description=description)
        return self

    def _open_capture(self, source: str) -> np.ndarray:
        self._is_device = source.startswith("/dev/") or source.isdigit()
        if not self._is_device and not Path(source).is_file():
            raise DeviceError(f"camera {self.camera_id!r}: {source!r} is neither a device, a "
                              "file nor a glob pattern")
        target = int(source) if source.isdigit() else source
        backend = cv2.CAP_V4L2 if self._is_device else cv2.CAP_ANY
        capture = cv2.VideoCapture(target, backend)
        if not capture.isOpened():
            raise DeviceError(f"camera {self.camera_id!r}: cannot open {source!r}; check that it "
                              "exists, that you may read it (group 'video') and that no other "
                              "program holds it")
        if self._is_device:
            cfg = self.config
            if cfg.fourcc:
                capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*cfg.fourcc))
            if cfg.width:
                capture.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
            if cfg.height:
                capture.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)
            if cfg.fps:
                capture.set(cv2.CAP_PROP_FPS, cfg.fps)
        self._capture = capture
        self._fps = self.config.fps or capture.get(cv2.CAP_PROP_FPS) or _DEFAULT_FILE_FPS
        ok, first = capture.read()
        if not ok:
            capture.release()
            raise DeviceError(f"camera {self.camera_id!r}: {source!r} opened but gives no frame")
        self._pending = first
        return first

    def _read_file(self, path: str) -> np.ndarray:
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise DeviceError(f"camera {self.camera_id!r}: cannot read image {path!r}")
        return image

    def __exit__(self, *exc_info: object) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def _next_image(self) -> np.ndarray:
        if self._files:
            if self._index >= len(self._files):
                if not self.config.loop:
                    raise EndOfStream(f"end of image sequence {self.config.source}")
                self._index = 0
            image = self._read_file(self._files[self._index])
            self._index += 1
            return image
        pending, self._pending = self._pending, None
        if pending is not None:
            return pending
        ok, image = self._capture.read()
        if ok:
            return image
        if self._is_device:
            raise ReadTimeout(f"camera {self.camera_id!r}: device gave no frame")
        if not self.config.loop:
            raise EndOfStream(f"end of video {self.config.source}")
        self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
        ok, image = self._capture.read()
        if not ok:
            raise EndOfStream(f"video {self.config.source} cannot be rewound")
        return image

    def read(self, *, timeout_s: float = 1.0) -> Frame:
        if self._info is None:
            raise DeviceError(f"camera {self.camera_id!r}: read() before open")
        if self._is_device:
            image = self._next_image()
            timestamp_ns = time.time_ns()
        else:
            period_ns = 1e9 / self._fps
            due_ns = self._start_mono_ns + int(self._seq * period_ns)
            wait_s = (due_ns - time.monotonic_ns()) / 1e9
            if wait_s > timeout_s:
                time.sleep(timeout_s)
                raise ReadTimeout("next file frame not due yet")
            if wait_s > 0:
                time.sleep(wait_s)
            image = self._next_image()
            timestamp_ns = self._start_wall_ns + int(self._seq * period_ns)
        frame = Frame(camera_id=self.camera_id, seq=self._seq, timestamp_ns=timestamp_ns,
                      encoding=self.config.encoding,
                      image=np.ascontiguousarray(_to_encoding(image, self.config.encoding)))
        self._seq += 1
        return frame
