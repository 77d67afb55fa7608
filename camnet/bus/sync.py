"""Synchronized frame sets from frames that arrive camera by camera.

Plain logic with no threads, no bus and no clock of its own (the caller
passes `now_s`, any monotonic seconds), so it can be tested step by step; the
matcher node wraps it in a lock.

Frames of one capture instant carry capture timestamps within `tolerance_ns`
of each other (equal for triggered cameras). The reference of a set is a
frame of the first required camera (the left stereo camera); a set holds,
for each camera, its buffered frame nearest to the reference within the
tolerance, and each frame's offset from the reference (its stamp minus the
reference's). Cameras that are not triggered together (`free_run`) expose
anywhere within a frame period of each other: each camera's frame nearest to
the reference is then accepted within half that camera's frame period (the
median interval of its recent stamps; the tolerance until it has enough), so
that one frame at most is near enough. A set is ready when every camera has
one, or, once `max_wait_s` has passed since its last frame arrived, when the
required cameras have one: a late or silent camera is then left out of that
set (counted). `pop` never waits: it returns the newest ready set or None.

Each camera keeps its latest `frames_per_camera` frames, and any that arrived
within `KEEP_WAITS` times `max_wait_s`, up to `max_frames_per_camera`: a set
that waits for a silent camera must still be there when its wait is over,
however fast the others deliver. A frame that leaves without being part of a
set is counted as dropped: pushed out by newer ones (the consumer is slower
than the cameras), superseded by a newer set, or arriving after a set at or
after its capture time was already given out.
Sets go forward in time and no frame is ever in two sets.
"""

from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from camnet.bus.frame import Frame


@dataclass(frozen=True)
class FrameSet:
    """Frames of one capture instant, by camera id (in the synchronizer's camera order)."""

    timestamp_ns: int  # capture time of the reference frame
    frames: dict[str, Frame]
    missing: tuple[str, ...] = ()  # cameras left out because they were late or silent
    # Per camera in the set, its frame's capture stamp minus the reference frame's (ns).
    offsets_ns: dict[str, int] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return not self.missing


@dataclass(frozen=True)
class SyncCounts:
    """Counters since start."""

    received: int
    complete_sets: int
    partial_sets: int
    dropped: int  # frames never given out in a set
    missing: dict[str, int] = field(default_factory=dict)  # partial sets that lacked each camera
    future: int = 0  # frames dropped for a capture time ahead of their camera's clock


@dataclass
class _Buffered:
    frame: Frame
    arrived_s: float


KEEP_WAITS = 1.5  # frames are kept this many max_wait_s after they arrive (pop runs a little late)
PERIOD_STAMPS = 17  # a free-running camera's period: the median interval of its latest this many stamps,
PERIOD_MIN_INTERVALS = 3  # known from this many intervals on (a median of three outvotes one lost frame)


class FrameSynchronizer:
    """Forms frame sets of `camera_ids`; `required` cameras must be in every set."""

    def __init__(self, camera_ids: Sequence[str], *, required: Sequence[str], tolerance_ns: int,
                 max_wait_s: float, frames_per_camera: int = 4, max_frames_per_camera: int = 64,
                 future_tolerance_s: float = 2.0, free_run: bool = False) -> None:
        self.camera_ids = tuple(camera_ids)
        self.required = tuple(required)
        if len(set(self.camera_ids)) != len(self.camera_ids):
            raise ValueError(f"duplicate camera ids: {self.camera_ids}")
        if not self.required or not set(self.required) <= set(self.camera_ids):
            raise ValueError(f"required cameras {self.required} must be among {self.camera_ids}")
        if tolerance_ns < 0 or max_wait_s < 0 or frames_per_camera < 1 or future_tolerance_s < 0:
            raise ValueError("tolerance_ns, max_wait_s and future_tolerance_s must be >= 0, frames_per_camera >= 1")
        if max_frames_per_camera < frames_per_camera:
            raise ValueError("max_frames_per_camera must be >= frames_per_camera")
        self.tolerance_ns = int(tolerance_ns)
        self.max_wait_s = float(max_wait_s)
        self.frames_per_camera = int(frames_per_camera)
        self.max_frames_per_camera = int(max_frames_per_camera)
        self.future_tolerance_ns = round(future_tolerance_s * 1e9)
        self.free_run = bool(free_run)
        self._stamps_ns = {c: deque(maxlen=PERIOD_STAMPS) for c in self.camera_ids}  # latest, for the periods
        self._period_ns: dict[str, int | None] = {c: None for c in self.camera_ids}
        # Per camera, its last accepted frame's capture time minus its arrival time (ns):
        # how far its capture clock is from the arrival clock.
        self._clock_offset_ns: dict[str, int] = {}
        self._future = 0
        self._buffers: dict[str, list[_Buffered]] = {c: [] for c in self.camera_ids}
        # Frames at or before this capture time can no longer be in a set.
        self._floor_ns: dict[str, int] = {c: -1 for c in self.camera_ids}
        self._received = 0
        self._complete = 0
        self._partial = 0
        self._dropped = 0
        self._missing = {c: 0 for c in self.camera_ids}

    def add(self, frame: Frame, *, now_s: float) -> bool:
        """Buffer `frame` (arrived at `now_s`); False if it came too late to be used (counted)."""
        buffer = self._buffers.get(frame.camera_id)
        if buffer is None:
            raise ValueError(f"camera {frame.camera_id!r} is not one of {self.camera_ids}")
        self._received += 1
        offset_ns = frame.timestamp_ns - round(now_s * 1e9)
        if self._ahead(offset_ns):
            self._future += 1
            return False
        self._clock_offset_ns[frame.camera_id] = offset_ns
        if self.free_run:
            self._stamps_ns[frame.camera_id].append(frame.timestamp_ns)
            self._period_ns[frame.camera_id] = median_interval_ns(self._stamps_ns[frame.camera_id])
        if frame.timestamp_ns <= self._floor_ns[frame.camera_id]:
            self._dropped += 1
            return False
        keys = [b.frame.timestamp_ns for b in buffer]
        buffer.insert(bisect.bisect_right(keys, frame.timestamp_ns), _Buffered(frame, now_s))
        keep_since_s = now_s - KEEP_WAITS * self.max_wait_s
        while len(buffer) > self.max_frames_per_camera or (
            len(buffer) > self.frames_per_camera and buffer[0].arrived_s < keep_since_s
        ):
            del buffer[0]
            self._dropped += 1
        return True

    def _ahead(self, offset_ns: int) -> bool:
        """Whether a frame whose capture clock reads `offset_ns` ahead of its arrival is in the future:
        ahead of every camera's clock (at its last accepted frame) by more than the tolerance."""
        if not self._clock_offset_ns:
            return False
        return offset_ns > max(self._clock_offset_ns.values()) + self.future_tolerance_ns

    def pop(self, *, now_s: float) -> FrameSet | None:
        """The newest ready frame set (removed with every older frame), or None."""
        for ref in reversed(self._buffers[self.required[0]]):
            chosen = self._nearest(ref.frame.timestamp_ns)
            if not all(c in chosen for c in self.required):
                continue
            complete = len(chosen) == len(self.camera_ids)
            waited_s = now_s - max(b.arrived_s for b in chosen.values())
            if complete or waited_s >= self.max_wait_s:
                return self._take(ref.frame.timestamp_ns, chosen)
        return None

    def _within(self, camera_id: str, offset_ns: int) -> bool:
        """Whether a frame of `camera_id` `offset_ns` from the reference may be in its set."""
        period_ns = self._period_ns[camera_id]
        if period_ns is None:
            return abs(offset_ns) <= self.tolerance_ns
        return 2 * abs(offset_ns) <= period_ns

    def _nearest(self, reference_ns: int) -> dict[str, _Buffered]:
        chosen = {}
        for camera_id, buffer in self._buffers.items():
            best = min(buffer, key=lambda b: abs(b.frame.timestamp_ns - reference_ns), default=None)
            if best is not None and self._within(camera_id, best.frame.timestamp_ns - reference_ns):
                chosen[camera_id] = best
        return chosen

    def _take(self, reference_ns: int, chosen: dict[str, _Buffered]) -> FrameSet:
        for camera_id, buffer in self._buffers.items():
            used = chosen.get(camera_id)
            floor = max(reference_ns, used.frame.timestamp_ns if used else reference_ns)
            self._floor_ns[camera_id] = max(self._floor_ns[camera_id], floor)
            kept = [b for b in buffer if b.frame.timestamp_ns > floor]
            self._dropped += len(buffer) - len(kept) - (used is not None)
            self._buffers[camera_id] = kept
        missing = tuple(c for c in self.camera_ids if c not in chosen)
        if missing:
            self._partial += 1
            for camera_id in missing:
                self._missing[camera_id] += 1
        else:
            self._complete += 1
        frames = {c: chosen[c].frame for c in self.camera_ids if c in chosen}
        offsets_ns = {c: f.timestamp_ns - reference_ns for c, f in frames.items()}
        return FrameSet(timestamp_ns=reference_ns, frames=frames, missing=missing, offsets_ns=offsets_ns)

    @property
    def counts(self) -> SyncCounts:
        return SyncCounts(received=self._received, complete_sets=self._complete,
                          partial_sets=self._partial, dropped=self._dropped,
                          missing=dict(self._missing), future=self._future)

    @property
    def buffered(self) -> int:
        """Frames waiting in the buffers now."""
        return sum(len(b) for b in self._buffers.values())


def median_interval_ns(stamps_ns) -> int | None:
    """The median interval between distinct capture stamps (ns, in any order); None if fewer than
    PERIOD_MIN_INTERVALS."""
    stamps = sorted(set(stamps_ns))
    intervals = np.diff(stamps)
    if len(intervals) < PERIOD_MIN_INTERVALS:
        return None
    return round(float(np.median(intervals)))
