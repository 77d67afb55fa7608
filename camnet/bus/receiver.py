"""Receiving frames: decode, count malformed ones, detect sequence gaps.

A node must survive anything on the wire: a malformed frame is counted under
its `FrameError.kind`, logged once per kind, and dropped; good frames keep
flowing. Gaps in a camera's sequence numbers count as dropped frames.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from dataclasses import dataclass

from camnet.bus.frame import Frame, FrameError, decode_frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraCounts:
    """Per-camera counters: frames accepted, frames missing from the sequence, restarts."""

    received: int
    dropped: int
    restarts: int
    last_seq: int


@dataclass
class _Track:
    received: int = 0
    dropped: int = 0
    restarts: int = 0
    last_seq: int = -1


class FrameReceiver:
    """Thread-safe decoder with counters; feed it payloads with `accept`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._malformed: dict[str, int] = {}
        self._tracks: dict[str, _Track] = {}

    def accept(self, payload: bytes | bytearray | memoryview) -> Frame | None:
        """The decoded frame, or None if it was malformed (then counted)."""
        try:
            frame = decode_frame(payload)
        except FrameError as exc:
            with self._lock:
                first = exc.kind not in self._malformed
                self._malformed[exc.kind] = self._malformed.get(exc.kind, 0) + 1
            if first:
                # Once per kind: a flood of bad frames must not flood the log.
                log.warning("dropping malformed frame (%s); further ones of this kind are "
                            "only counted", exc)
            return None
        self._count(frame)
        return frame

    def _count(self, frame: Frame) -> None:
        with self._lock:
            track = self._tracks.setdefault(frame.camera_id, _Track())
            if track.last_seq >= 0:
                if frame.seq > track.last_seq + 1:
                    track.dropped += frame.seq - track.last_seq - 1
                elif frame.seq <= track.last_seq:
                    # The driver restarted (or frames came out of order): start counting anew.
                    track.restarts += 1
            track.received += 1
            track.last_seq = frame.seq

    @property
    def malformed(self) -> dict[str, int]:
        """Malformed frames seen, by FrameError.kind."""
        with self._lock:
            return dict(self._malformed)

    @property
    def malformed_total(self) -> int:
        with self._lock:
            return sum(self._malformed.values())

    def counts(self) -> dict[str, CameraCounts]:
        """Counters per camera id."""
        with self._lock:
            return {cid: CameraCounts(t.received, t.dropped, t.restarts, t.last_seq)
                    for cid, t in self._tracks.items()}


class FrameQueue:
    """Latest-value delivery: a bounded queue of decoded frames that drops the oldest.

    Pass `on_sample` as a Zenoh subscriber callback; it decodes (through a
    FrameReceiver, which counts malformed frames and gaps) in Zenoh's thread
    and never blocks it. A slow consumer loses the oldest frames, counted in
    `overflowed`, instead of growing a backlog.
    """

    def __init__(self, receiver: FrameReceiver | None = None, *, capacity: int = 2) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1")
        self.receiver = receiver or FrameReceiver()
        self._frames: deque[Frame] = deque()
        self._capacity = capacity
        self._ready = threading.Condition()
        self.overflowed = 0

    def on_sample(self, sample) -> None:
        frame = self.receiver.accept(sample.payload.to_bytes())
        if frame is None:
            return
        with self._ready:
            if len(self._frames) == self._capacity:
                self._frames.popleft()
                self.overflowed += 1
            self._frames.append(frame)
            self._ready.notify()

    def get(self, *, timeout_s: float) -> Frame | None:
        """The oldest queued frame, waiting up to `timeout_s`; None if none came."""
        with self._ready:
            if not self._ready.wait_for(lambda: self._frames, timeout=timeout_s):
                return None
            return self._frames.popleft()


def subscribe_frames(session, key_expr: str, *, capacity: int = 2):
    """(subscriber, FrameQueue) for frames on `key_expr` (see camnet.bus.keys.frame/all_frames)."""
    queue = FrameQueue(capacity=capacity)
    return session.declare_subscriber(key_expr, queue.on_sample), queue
