"""V4L2 (USB) cameras, video files and image sequences, through cv2.VideoCapture.

`source` is a device path (/dev/video0) or index, a video file, or a glob
pattern of image files (sorted by name). Files and sequences are paced at the
configured fps (else the file's own, else 30) and stamped with the host clock
at the frame's due time; devices are stamped when the frame is grabbed.

Files of one rig share one clock from their first frame: given a start
instant (`files_start_ns`, Unix epoch ns; `camnet up` picks one for the run
and gives it to every v4l2 driver it starts, a restarted one included, as
`camnet driver --files-start-ns`), a video file or an image sequence without
a timestamps file stamps frame i with that start + i/fps and publishes it at
that wall time, whenever its driver started; without it, the start is the
driver's own. A driver that opens after the start (started late, or started
again after it died) begins at the frame due when it opens, published at
once, skipping those before, rather than replaying them in a burst: the
matcher's frame sets only go forward in time, so frames past would be of no
use to it, and the driver is at once in step with the others. A video file
is sought to that frame (modulo its frame count when it loops); one that does
not loop and whose end is past ends at once.

A recorded image sequence with a `timestamps` file keeps its capture times,
so that frames of several cameras recorded together form the same frame
sets when replayed by separate drivers. The file has one line
``YYYY-MM-DD HH:MM:SS.fffffffff`` (UTC, KITTI's format) per frame index,
line n for frame n; an image's frame index is the last number in its file
name. Frames are stamped with those times (the recorded clock, not the
host's: drivers started at different instants still agree) and published at
the recorded pace times `speed` (or at a fixed `fps`), measured from the
first frame index of the pass (`frame_range`, by default the first image's),
so that cameras holding different frames of one recording stay in step. A
looping sequence adds one pass length to every stamp per pass. A sequence's
own pass length is its frame-index span plus one, times its frame period (the
median interval of its timestamps file); every looping sequence of a rig
takes the longest of those of the rig's looping sequences (`rig_pass_ns`),
since each timestamps file has a median of its own and passes of different
lengths would carry cameras apart by their difference every pass, out of
every frame set. Cameras that loop together need the same `frame_range`.
"""

from __future__ import annotations

import glob
import logging
import os
import re
import time
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
from camnet.drivers.base import DeviceError, DeviceInfo, EndOfStream, ReadTimeout

from camnet.bus.frame import Frame, FrameBuffer
from camnet.io.rig import CameraEntry, Rig, V4l2Config, is_image_pattern

log = logging.getLogger(__name__)

_DEFAULT_FILE_FPS = 30.0
_STAMP = re.compile(r"(\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2})(?:\.(\d{1,9}))?")


def create(entry: CameraEntry, rig: Rig, *, files_start_ns: int | None = None) -> V4l2Camera:
    """`files_start_ns`: the rig's start instant for files and sequences without timestamps (module docstring)."""
    return V4l2Camera(entry.id, entry.config, rig_pass_ns=rig_pass_ns(rig), files_start_ns=files_start_ns)


def rig_pass_ns(rig: Rig) -> int | None:
    """The pass length (ns) of every looping stamped sequence of `rig`: the longest of their own, among
    those whose images and timestamps this host has (None: none). A sequence this host cannot read is left
    to its own driver, which says what is wrong with it."""
    passes = []
    for entry in rig.cameras:
        config = entry.config
        if entry.driver != "v4l2" or not config.loop or config.timestamps is None:
            continue
        try:
            stamps = parse_timestamps(Path(config.timestamps).read_text(), source=config.timestamps)
            files = sorted(glob.glob(config.source))
            passes.append(stamped_sequence(files, stamps, frame_range=config.frame_range,
                                           source=config.timestamps).pass_ns)
        except (OSError, ValueError):
            continue
    return max(passes, default=None)


def source_problem(camera_id: str, config: V4l2Config) -> str | None:
    """What makes `config.source` unusable before anything opens it (an absent device, file or folder of
    images, a glob matching nothing, an absent timestamps file), in one line naming the camera, the path
    and what to do; None when it may be opened."""
    source = config.source
    if is_image_pattern(source):
        if not glob.glob(source):
            return _sequence_problem(camera_id, source)
    elif source.isdigit() or source.startswith("/dev/"):
        device = f"/dev/video{source}" if source.isdigit() else source
        if not Path(device).exists():
            return f"camera {camera_id!r}: no device {device} on this host (camnet cameras lists the devices found)"
    elif not Path(source).is_file():
        return f"camera {camera_id!r}: no file {source!r} (paths are relative to the rig file)"
    if config.timestamps is not None and not Path(config.timestamps).is_file():
        return (f"camera {camera_id!r}: no timestamps file {config.timestamps} (paths are relative to the rig "
                "file); put the recording's timestamps there, or leave 'timestamps' out to pace it by 'fps'")
    return None


def _sequence_problem(camera_id: str, pattern: str) -> str:
    """Why the image glob `pattern` matches nothing: its folder is absent, or holds no such image."""
    folder, name = os.path.split(pattern)
    shown = _unescaped(folder)
    if not glob.glob(folder):
        return (f"camera {camera_id!r}: no folder {shown} for its images (paths are relative to the rig file); "
                "put the camera's images there, or set its v4l2 source to where they are")
    return (f"camera {camera_id!r}: no image in {shown} matches {_unescaped(name)!r}; put the camera's images "
            "there, or correct the pattern of its v4l2 source")


def _unescaped(pattern: str) -> str:
    """A path as written, from a glob pattern whose literal part glob.escape wrote (``[[]`` for ``[``)."""
    return re.sub(r"\[([*?[])\]", r"\1", pattern)


def parse_timestamps(text: str, *, source: str) -> np.ndarray:
    """Capture times (int64 ns since the Unix epoch, read as UTC) of a KITTI timestamps file, by line.

    Trailing blank lines are ignored; any other line that is not
    ``YYYY-MM-DD HH:MM:SS[.fffffffff]`` is a ValueError naming `source` and the line.
    """
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    stamps = np.empty(len(lines), dtype=np.int64)
    for n, line in enumerate(lines):
        match = _STAMP.fullmatch(line.strip())
        try:
            if match is None:
                raise ValueError
            whole = datetime.fromisoformat(match[1]).replace(tzinfo=UTC)
        except ValueError:
            raise ValueError(f"{source}:{n + 1}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got {line[:40]!r}") \
                from None
        stamps[n] = int(whole.timestamp()) * 1_000_000_000 + int((match[2] or "0").ljust(9, "0"))
    return stamps


def frame_index(path: str) -> int:
    """The frame index an image file's name gives: the last number in it (``0000000013.png`` -> 13)."""
    numbers = re.findall(r"\d+", Path(path).stem)
    if not numbers:
        raise ValueError(f"{path}: no frame number in the file name")
    return int(numbers[-1])


@dataclass(frozen=True)
class StampedSequence:
    """Image files with their recorded capture times (ns), in frame-index order."""

    files: tuple[str, ...]
    stamps_ns: tuple[int, ...]
    origin_ns: int  # recorded time of the pass's first frame index: the pace is measured from it
    period_ns: int  # the recording's frame period: the median interval of the timestamps file
    pass_ns: int  # added to every stamp per pass of a looping sequence


def stamped_sequence(files: list[str], stamps_ns: np.ndarray, *, frame_range: tuple[int, int] | None,
                     source: str) -> StampedSequence:
    """The images of `files` within `frame_range` (all: None) stamped from `stamps_ns` (line n = frame n).

    ValueError, naming `source`, when an image has no stamp, two images share
    a frame index, the stamps do not increase with the index, or none is left.
    """
    if len(stamps_ns) < 2:
        raise ValueError(f"{source}: needs at least 2 lines to know the frame period")
    by_index: dict[int, str] = {}
    for path in files:
        index = frame_index(path)
        if index in by_index:
            raise ValueError(f"{path}: frame {index} again (also {by_index[index]})")
        by_index[index] = path
    indices = sorted(by_index)
    first, last = frame_range if frame_range is not None else (indices[0], indices[-1])
    kept = [i for i in indices if first <= i <= last]
    if not kept:
        raise ValueError(f"no image within frame_range [{first}, {last}] (frames {indices[0]}-{indices[-1]})")
    if last >= len(stamps_ns):
        raise ValueError(f"{source}: has {len(stamps_ns)} lines, no stamp for frame {last}")
    if len(kept) < len(indices):
        log.info("%d images outside frame_range [%d, %d] skipped", len(indices) - len(kept), first, last)
    stamps = stamps_ns[kept]
    if np.any(np.diff(stamps_ns[first:last + 1]) <= 0):
        raise ValueError(f"{source}: the stamps of frames {first}-{last} do not increase with the frame index")
    period_ns = int(np.median(np.diff(stamps_ns)))
    pass_ns = (last - first + 1) * period_ns
    if pass_ns <= stamps_ns[last] - stamps_ns[first]:
        raise ValueError(f"{source}: frames {first}-{last} span more than {last - first + 1} median frame "
                         "periods; a looping sequence would go back in time")
    return StampedSequence(files=tuple(by_index[i] for i in kept), stamps_ns=tuple(int(t) for t in stamps),
                           origin_ns=int(stamps_ns[first]), period_ns=period_ns, pass_ns=pass_ns)


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
    groundtruth = None  # recorded or live, the scene's truth is not known
    def __init__(self, camera_id: str, config: V4l2Config, *, rig_pass_ns: int | None = None,
                 files_start_ns: int | None = None) -> None:
        self.camera_id = camera_id
        self.config = config
        self._rig_pass_ns = rig_pass_ns  # a looping sequence's pass length, the rig's (module docstring)
        self._files_start_ns = files_start_ns  # the rig's start of frame 0 (Unix epoch ns; module docstring)
        self._capture = None
        self._files: tuple[str, ...] = ()
        self._stamped: StampedSequence | None = None
        self._seq = 0
        self._dropped = 0
        self._is_device = False
        self._fps = 0.0
        self._start_mono_ns = 0
        self._start_wall_ns = 0
        self._info: DeviceInfo | None = None
        # The frame read while opening (to learn the size), handed out first.
        self._pending: np.ndarray | None = None

    @property
    def info(self) -> DeviceInfo:
        if self._info is None:
            raise DeviceError(f"camera {self.camera_id!r}: not open")
        return self._info

    @property
    def dropped(self) -> int:
        return self._dropped

    def __enter__(self) -> V4l2Camera:
        source = self.config.source
        if is_image_pattern(source):
            self._files = tuple(sorted(glob.glob(source)))
            if not self._files:
                raise DeviceError(_sequence_problem(self.camera_id, source))
            self._fps = self.config.fps or _DEFAULT_FILE_FPS
            if self.config.timestamps is not None:
                self._open_stamps()
            first = self._read_file(self._files[0])
            description = f"image sequence {source} ({len(self._files)} images)"
        else:
            first = self._open_capture(source)
            description = f"{'device' if self._is_device else 'video file'} {source}"
        self._start_clock()
        self._info = DeviceInfo(camera_id=self.camera_id, driver="v4l2", width=first.shape[1],
                                height=first.shape[0], encoding=self.config.encoding,
                                fps=self._fps, description=description)
        return self

    def _start_clock(self) -> None:
        """Set when frame 0 is due: at the rig's start for a file or sequence without timestamps when one is
        given, else now; one that opens after it goes on at the frame due now (module docstring)."""
        now_mono_ns, now_wall_ns = time.monotonic_ns(), time.time_ns()
        shared = self._files_start_ns is not None and not self._is_device and self._stamped is None
        self._start_wall_ns = self._files_start_ns if shared else now_wall_ns
        # Due times are waited for on the monotonic clock: its reading at the start.
        self._start_mono_ns = now_mono_ns - (now_wall_ns - self._start_wall_ns)
        due_now = int((now_wall_ns - self._start_wall_ns) * self._fps / 1e9)
        if due_now > 0:
            self._seq = due_now
            self._seek(due_now)

    def _seek(self, seq: int) -> None:
        """Make frame `seq` the next a video file gives (a sequence reads its files by `seq` anyway)."""
        if self._capture is None:
            return
        self._pending = None
        count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT))
        # Past the end of a file that does not loop, reading fails: the end of the video.
        self._capture.set(cv2.CAP_PROP_POS_FRAMES, seq % count if self.config.loop and count > 0 else seq)

    def _open_stamps(self) -> None:
        path = self.config.timestamps
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise DeviceError(f"camera {self.camera_id!r}: cannot read timestamps {path!r} "
                              f"({exc.strerror})") from None
        try:
            stamps = parse_timestamps(text, source=path)
            self._stamped = stamped_sequence(list(self._files), stamps, frame_range=self.config.frame_range,
                                             source=path)
        except ValueError as exc:
            raise DeviceError(f"camera {self.camera_id!r}: {exc}") from None
        if self._rig_pass_ns is not None and self._rig_pass_ns > self._stamped.pass_ns:
            self._stamped = replace(self._stamped, pass_ns=self._rig_pass_ns)
        self._files = self._stamped.files
        if self.config.fps is None:
            self._fps = self.config.speed * 1e9 / self._stamped.period_ns

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
            return self._read_file(self._files[self._seq % len(self._files)])
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
        seq, timestamp_ns, image = self._next(timeout_s)
        return Frame(self.camera_id, seq, timestamp_ns, self.config.encoding, image)

    def read_into(self, buffer: FrameBuffer, *, timeout_s: float = 1.0) -> tuple[int, int] | Frame:
        seq, timestamp_ns, image = self._next(timeout_s)
        return buffer.fill(seq, timestamp_ns, self.config.encoding, image)

    def _next(self, timeout_s: float) -> tuple[int, int, np.ndarray]:
        """(seq, timestamp_ns, image in the camera's encoding) of the next frame, once it is due."""
        if self._info is None:
            raise DeviceError(f"camera {self.camera_id!r}: read() before open")
        if self._is_device:
            image = self._next_image()
            timestamp_ns = time.time_ns()
        else:
            due_ns, timestamp_ns = self._schedule(self._seq)
            wait_s = (self._start_mono_ns + due_ns - time.monotonic_ns()) / 1e9
            if wait_s > timeout_s:
                time.sleep(timeout_s)
                raise ReadTimeout("next file frame not due yet")
            if wait_s > 0:
                time.sleep(wait_s)
            image = self._next_image()
        image = np.ascontiguousarray(_to_encoding(image, self.config.encoding))
        seq, self._seq = self._seq, self._seq + 1
        return seq, timestamp_ns, image

    def _schedule(self, seq: int) -> tuple[int, int]:
        """(when frame `seq` is due, ns after the start; its capture timestamp, ns) for a file or sequence."""
        passes, position = divmod(seq, len(self._files)) if self._files else (0, seq)
        if passes and self._files and not self.config.loop:
            raise EndOfStream(f"end of image sequence {self.config.source}")
        fixed_due_ns = int(seq * 1e9 / self._fps)
        if self._stamped is None:
            return fixed_due_ns, self._start_wall_ns + fixed_due_ns
        stamp_ns = self._stamped.stamps_ns[position] + passes * self._stamped.pass_ns
        if self.config.fps is not None:
            return fixed_due_ns, stamp_ns
        return int((stamp_ns - self._stamped.origin_ns) / self.config.speed), stamp_ns
