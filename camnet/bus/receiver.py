"""Receiving frames: decode, count malformed ones, detect sequence gaps.

A node must survive anything on the wire: a malformed frame is counted under
its `FrameError.kind` (logged once per kind) and dropped; good frames keep
flowing. Gaps in a camera's sequence numbers count as dropped frames.

A frame whose capture time lies (0, 2**63, an hour off among a camera's
frames) is counted under `off_clock`, and kept: far (more than
`OFF_CLOCK_S`) both from this host's clock and from the camera's clock as
its previous frame showed it (capture time minus arrival time, from the last
frame not counted). So a camera host whose clock is wrong, or a replay of
frames recorded long ago, is not counted once its first frame is in, and
frame sets, which need only the cameras to agree with each other
(`camnet.bus.sync`, which drops frames ahead of every camera's clock), still
form; a frame that disagrees with both is counted, for the operator to look.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

from camnet.bus.frame import Frame, FrameError, FrameHeader, decode_frame, decode_header
from camnet.bus.node import Tally
from camnet.bus.stats import RateMeter

log = logging.getLogger(__name__)

OFF_CLOCK_S = 60.0  # a capture time further than this from this host's clock and the camera's is counted


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
    arrived_s: float = 0.0  # monotonic time of the last accepted frame
    offset_ns: int | None = None  # capture time minus arrival time of the last frame not off the clocks
    meter: RateMeter = field(default_factory=RateMeter)


class FrameReceiver:
    """Thread-safe decoder with counters; feed it payloads with `accept`.

    sizes: (width, height) per camera id that this receiver takes: a frame of
    another camera or another size is refused from its header, before its
    pixels are decoded (counted as "unknown-camera" or "wrong-size"). None
    takes any camera of any size.
    """

    def __init__(self, sizes: Mapping[str, tuple[int, int] | None] | None = None) -> None:
        self._lock = threading.Lock()
        self.malformed = Tally(log)  # malformed frames, by FrameError.kind
        self.off_clock = Tally(log)  # frames kept whose capture time is far from this host's clock and the camera's
        self._tracks: dict[str, _Track] = {}
        self._sizes = None if sizes is None else dict(sizes)

    def _admit(self, header: FrameHeader) -> None:
        if self._sizes is None:
            return
        if header.camera_id not in self._sizes:
            raise FrameError("unknown-camera", f"camera {header.camera_id!r} is not one of {sorted(self._sizes)}")
        size = self._sizes[header.camera_id]
        if size is not None and (header.width, header.height) != size:
            raise FrameError("wrong-size", f"camera {header.camera_id!r} sends {header.width}x{header.height}, "
                             f"the rig says {size[0]}x{size[1]}")

    def accept(self, payload: bytes | bytearray | memoryview) -> Frame | None:
        """The decoded frame, or None if it was malformed or not admitted (then counted)."""
        try:
            self._admit(decode_header(payload))
            frame = decode_frame(payload)
        except FrameError as exc:
            self.malformed.count(exc.kind, "dropping malformed frame (%s)", exc)
            return None
        off_s = self._count(frame)
        if off_s is not None:
            self.off_clock.count("capture time off the clocks", "camera %r stamps a frame %.0f s %s this host's "
                                 "clock, and far from its previous frames' stamps; kept, but check the clocks of the "
                                 "camera's host and of this one", frame.camera_id, abs(off_s),
                                 "ahead of" if off_s > 0 else "behind")
        return frame

    def _count(self, frame: Frame) -> float | None:
        """Count `frame`; its capture time's seconds from this host's clock when far from it and from the
        camera's clock (then counted as off the clocks), else None."""
        offset_ns = frame.timestamp_ns - time.time_ns()
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
            track.arrived_s = time.monotonic()
            track.meter.tick(track.arrived_s)
            far = abs(offset_ns) > OFF_CLOCK_S * 1e9
            if far and track.offset_ns is not None and abs(offset_ns - track.offset_ns) > OFF_CLOCK_S * 1e9:
                return offset_ns / 1e9
            track.offset_ns = offset_ns
            return None

    def arrivals(self) -> dict[str, tuple[float, float]]:
        """(seconds since its last frame, frames per second as received) per camera id."""
        now_s = time.monotonic()
        with self._lock:
            return {cid: (now_s - t.arrived_s, t.meter.rate(now_s)) for cid, t in self._tracks.items()}

    def counts(self) -> dict[str, CameraCounts]:
        """Counters per camera id."""
        with self._lock:
            return {cid: CameraCounts(t.received, t.dropped, t.restarts, t.last_seq)
                    for cid, t in self._tracks.items()}
