"""The driver node: read one camera, publish its frames, liveliness and statistics.

Frames go out with congestion control DROP: a slow subscriber or link loses
frames (seen as sequence gaps) instead of stalling the camera. A simulated
camera also publishes the rig's ground truth on the groundtruth key and
answers queries on it.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time

from camnet.drivers.base import Camera, EndOfStream, ReadTimeout

from camnet.bus import keys
from camnet.bus.frame import Compression, encode_frame
from camnet.bus.session import declare_liveliness
from camnet.bus.stats import NodeStats, RateMeter
from camnet.io.rig import Rig

log = logging.getLogger(__name__)

NODE_KIND = "driver"


class DriverNode:
    def __init__(self, session, rig: Rig, camera: Camera, *, compression: str = "none",
                 stats_period_s: float = 1.0) -> None:
        self.session = session
        self.rig = rig
        self.camera = camera
        self.camera_id = camera.camera_id
        self.compression = Compression[compression.upper()]
        self.stats_period_s = stats_period_s
        self.stop = threading.Event()
        self.frames_sent = 0
        self._meter = RateMeter()

    def _install_sigterm(self) -> None:
        if threading.current_thread() is threading.main_thread():
            # docker stop / process managers send SIGTERM: leave cleanly as on Ctrl-C.
            signal.signal(signal.SIGTERM, lambda *_: self.stop.set())

    def _publish_groundtruth(self):
        from camnet.drivers.sim import SimCamera, groundtruth_document

        if not isinstance(self.camera, SimCamera):
            return None
        payload = json.dumps(groundtruth_document(self.rig)).encode()
        key = keys.groundtruth(self.rig.name)
        self.session.put(key, payload)
        return self.session.declare_queryable(key, lambda query: query.reply(key, payload))

    def _stats(self) -> NodeStats:
        info = self.camera.info
        return NodeStats(rig=self.rig.name, kind=NODE_KIND, node_id=self.camera_id,
                         fps=round(self._meter.rate(), 2), frames=self.frames_sent,
                         dropped=self.camera.dropped, timestamp_ns=time.time_ns(),
                         detail=f"{info.driver} {info.width}x{info.height} {info.encoding}")

    def run(self, *, max_frames: int = 0) -> int:
        """Publish until stopped, the source ends, or `max_frames` frames (0: no limit)."""
        import zenoh

        self._install_sigterm()
        rig_name = self.rig.name
        publisher = self.session.declare_publisher(
            keys.frame(rig_name, self.camera_id),
            congestion_control=zenoh.CongestionControl.DROP)
        stats_publisher = self.session.declare_publisher(
            keys.node_stats(rig_name, NODE_KIND, self.camera_id))
        with self.camera:
            token = declare_liveliness(self.session, keys.node(rig_name, NODE_KIND,
                                                               self.camera_id))
            queryable = self._publish_groundtruth()
            log.info("camera %s: publishing %s", self.camera_id,
                     keys.frame(rig_name, self.camera_id))
            next_stats = time.monotonic() + self.stats_period_s
            try:
                while not self.stop.is_set():
                    try:
                        frame = self.camera.read(timeout_s=0.5)
                    except ReadTimeout:
                        frame = None
                    except EndOfStream as exc:
                        log.info("camera %s: %s", self.camera_id, exc)
                        break
                    if frame is not None:
                        publisher.put(encode_frame(frame, compression=self.compression))
                        self.frames_sent += 1
                        self._meter.tick()
                    if time.monotonic() >= next_stats:
                        stats_publisher.put(self._stats().to_json())
                        next_stats = time.monotonic() + self.stats_period_s
                    if max_frames and self.frames_sent >= max_frames:
                        break
            except KeyboardInterrupt:
                log.info("camera %s: interrupted", self.camera_id)
            finally:
                stats_publisher.put(self._stats().to_json())
                if queryable is not None:
                    queryable.undeclare()
                token.undeclare()
        return 0
