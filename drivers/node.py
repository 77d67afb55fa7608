"""The driver node: read one camera, publish its frames, liveliness and statistics.

Frames go out with congestion control DROP: a slow subscriber or link loses
frames (seen as sequence gaps) instead of stalling the camera. Raw frames
are written by the camera straight into a message buffer that is reused
frame after frame (`camnet.bus.frame.FrameBuffer`), so the pixels are not
copied into a new message before `put`. They can go out through Zenoh
shared memory instead of as bytes (`shared_memory`,
`camnet.drivers.frame_publisher`): less CPU, but off by default, since it
lost frames under load where bytes did not. A camera that
knows the rig's ground truth (a simulated one) also publishes it on the
groundtruth key and answers queries on it. `on_frame`, when given, sees every
frame published (the feature stage beside the driver takes its frames so).
`run_together` runs the nodes of several cameras in one process (a camera
host), each on its own thread.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

from camnet.drivers.base import Camera, EndOfStream, ReadTimeout
from camnet.drivers.frame_publisher import FramePublisher

from camnet.bus import keys
from camnet.bus.frame import Compression, Frame, FrameBuffer, encode_frame
from camnet.bus.node import Presence, name_os_thread, stop_on_signals
from camnet.bus.stats import Activity
from camnet.io.rig import Rig

log = logging.getLogger(__name__)

NODE_KIND = "driver"
RATE_WINDOW_S = 2.0  # the reported fps: frames sent over about the last two seconds


class DriverNode:
    def __init__(self, session, rig: Rig, camera: Camera, *, compression: Compression = Compression.NONE,
                 stats_period_s: float = 1.0, on_frame: Callable[[Frame], None] | None = None,
                 shared_memory: bool = False) -> None:
        self.session = session
        self.rig = rig
        self.camera = camera
        self.camera_id = camera.camera_id
        self.compression = compression
        self.stats_period_s = stats_period_s
        self.on_frame = on_frame
        self.shared_memory = shared_memory
        self.stop = threading.Event()
        self.frames_sent = 0
        # (monotonic s, frames sent) at each report: the rate comes from counts, not from a clock
        # read per frame.
        self._counts: deque[tuple[float, int]] = deque()
        self._buffer: FrameBuffer | None = None  # raw frames only; made from the first frame
        # Kept as long as the node, not just the run: its shared memory must outlive the last frames
        # put, which subscribers map only when they arrive.
        self.frames_out: FramePublisher | None = None

    def _read(self) -> Frame:
        """The camera's next frame, into the reused message buffer when there is one."""
        return self.camera.read(timeout_s=0.5, out=None if self._buffer is None else self._buffer.pixels)

    def _message(self, frame: Frame) -> bytes | bytearray:
        """The wire bytes of `frame`: sealed in place when the camera wrote it into the buffer."""
        if self.compression is not Compression.NONE:
            return encode_frame(frame, compression=self.compression)
        if self._buffer is not None and self._buffer.holds(frame):
            return self._buffer.seal(frame)
        self._buffer = FrameBuffer.like(frame)  # the first frame, or one of another size: the next goes in place
        return encode_frame(frame)

    def _offer(self, frame: Frame) -> None:
        """Hand `frame` to `on_frame`, its pixels copied if they are in the buffer (the next frame overwrites it)."""
        if self._buffer is not None and self._buffer.holds(frame):
            frame = Frame(frame.camera_id, frame.seq, frame.timestamp_ns, frame.encoding, frame.image.copy())
        self.on_frame(frame)

    def _publish_groundtruth(self):
        if self.camera.groundtruth is None:
            return None
        payload = json.dumps(self.camera.groundtruth).encode()
        key = keys.groundtruth(self.rig.name)
        self.session.put(key, payload)
        return self.session.declare_queryable(key, lambda query: query.reply(key, payload))

    def _fps(self) -> float:
        """Frames sent per second since the oldest report of the last `RATE_WINDOW_S` seconds."""
        now_s = time.monotonic()
        self._counts.append((now_s, self.frames_sent))
        while len(self._counts) > 2 and self._counts[1][0] <= now_s - RATE_WINDOW_S:
            self._counts.popleft()
        then_s, frames = self._counts[0]
        return (self.frames_sent - frames) / (now_s - then_s) if now_s > then_s else 0.0

    def _activity(self) -> Activity:
        info = self.camera.info
        return Activity(fps=round(self._fps(), 2), frames=self.frames_sent, dropped=self.camera.dropped,
                        detail=f"{info.driver} {info.width}x{info.height} {info.encoding}")

    def run(self, *, max_frames: int = 0) -> int:
        """Publish until stopped, the source ends, or `max_frames` frames (0: no limit)."""
        import zenoh

        self.frames_out = publisher = FramePublisher(self.session.declare_publisher(
            keys.frame(self.rig.name, self.camera_id),
            congestion_control=zenoh.CongestionControl.DROP), shared_memory=self.shared_memory)
        presence = Presence(self.session, rig=self.rig.name, kind=NODE_KIND, node_id=self.camera_id,
                            report=self._activity, period_s=self.stats_period_s, counted="frames sent",
                            dropped="dropped by the camera")
        with stop_on_signals(self.stop), self.camera, presence:
            queryable = self._publish_groundtruth()
            log.info("camera %s: publishing %s", self.camera_id, keys.frame(self.rig.name, self.camera_id))
            self._counts.append((time.monotonic(), self.frames_sent))
            try:
                while not self.stop.is_set():
                    try:
                        frame = self._read()
                    except ReadTimeout:
                        frame = None
                    except EndOfStream as exc:
                        log.info("camera %s: %s", self.camera_id, exc)
                        break
                    if frame is not None:
                        publisher.put(self._message(frame))
                        if self.on_frame is not None:
                            self._offer(frame)
                        self.frames_sent += 1
                    presence.publish_if_due()
                    if max_frames and self.frames_sent >= max_frames:
                        break
            finally:
                if queryable is not None:
                    queryable.undeclare()
        return 0


def run_together(nodes: Sequence[DriverNode], *, max_frames: int = 0) -> int:
    """Run `nodes` on a thread each until SIGTERM or Ctrl-C, or until every one has ended.

    A node that fails stops the others, and its error is raised here once they have stopped: the
    process then ends as a one-camera driver would (and a supervisor restarts the whole host).
    """
    stop = threading.Event()
    errors: list[BaseException] = []

    def run_one(node: DriverNode) -> None:
        name_os_thread(threading.current_thread().name)
        try:
            node.run(max_frames=max_frames)
        except BaseException as exc:  # noqa: BLE001 (raised again in the main thread below)
            errors.append(exc)
            stop.set()

    threads = [threading.Thread(target=run_one, args=(node,), name=f"driver-{node.camera_id}") for node in nodes]
    with stop_on_signals(stop):
        for thread in threads:
            thread.start()
        while any(thread.is_alive() for thread in threads) and not stop.wait(0.2):
            pass
        for node in nodes:
            node.stop.set()
        for thread in threads:
            thread.join()
    if errors:
        raise errors[0]
    return 0
