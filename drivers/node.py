"""The driver node: read one camera, publish its frames, liveliness and statistics.

Frames go out with congestion control DROP: a slow subscriber or link loses
frames (seen as sequence gaps) instead of stalling the camera. Raw frames
are written by the camera straight into a message buffer that is reused
frame after frame (`Camera.read_into`, `camnet.bus.frame.FrameBuffer`), so
the pixels are not copied into a new message before `put`, and the camera
hands back only seq and timestamp: a `Frame` is built only for `on_frame`.
They can go out through Zenoh
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
READ_TIMEOUT_S = 0.5  # the longest a read blocks: how soon the node sees a stop or reports statistics


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
        # Kept as long as the node, not just the run: its shared memory must outlive the last frames
        # put, which subscribers map only when they arrive.
        self.frames_out: FramePublisher | None = None

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
                self._publish_frames(publisher.put, presence.publish_if_due, max_frames)
            finally:
                if queryable is not None:
                    queryable.undeclare()
        return 0

    def _publish_frames(self, put: Callable[[bytes | bytearray], None], publish_stats_if_due: Callable[[], None],
                        max_frames: int) -> None:
        """Read and put frames until stopped, the source ends, or `max_frames` (0: no limit).

        A raw frame's pixels go into the reused buffer and the camera returns
        only (seq, timestamp_ns): per frame, the loop stamps and puts the
        buffer, nothing more (at 30 fps on a loaded host each line of it runs
        with cold caches, so it is kept short). The first frame, or one the
        buffer cannot carry, comes as a Frame and makes the buffer for the next.
        """
        camera, stop, on_frame = self.camera, self.stop, self.on_frame
        raw = self.compression is Compression.NONE
        buffer: FrameBuffer | None = None
        while not stop.is_set():
            try:
                got = camera.read_into(buffer, timeout_s=READ_TIMEOUT_S) if buffer is not None \
                    else camera.read(timeout_s=READ_TIMEOUT_S)
            except ReadTimeout:
                got = None
            except EndOfStream as exc:
                log.info("camera %s: %s", self.camera_id, exc)
                break
            if isinstance(got, tuple):
                put(buffer.stamp(*got))
                if on_frame is not None:
                    on_frame(buffer.frame(*got))
                self.frames_sent += 1
            elif got is not None:
                if raw:
                    buffer = FrameBuffer.like(got)  # the first frame, or one of another size: the next goes in place
                put(encode_frame(got, compression=self.compression))
                if on_frame is not None:
                    on_frame(got)
                self.frames_sent += 1
            publish_stats_if_due()
            if max_frames and self.frames_sent >= max_frames:
                break


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
