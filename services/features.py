"""The feature stage beside a driver: one camera's frames in, its keypoints and descriptors out.

`FeatureWorker` runs in the driver's process (`camnet driver ... --features`),
on the camera's host, so that detection is spread over the hosts and the
matcher only matches. The driver hands it every frame (`offer`: a few
microseconds, never blocking the camera); its own thread detects
(`camnet.matching.edge.FeatureExtractor`: only where the image changed) and
publishes on ``keys.features(rig, camera)`` (`camnet.bus.features_wire`).

Which frames: the frame set of the matcher needs the same capture instant
from every camera, while each camera's stage is free at its own moments. So
every stage takes the frame nearest to the latest point of a common grid of
capture times (multiples of `period_s` since the epoch), at most one per grid
point: cameras on one clock then pick the same instant. A stage slower than
the period skips grid points (counted as skipped).
"""

from __future__ import annotations

import collections
import logging
import threading
from dataclasses import dataclass

from camnet.bus.features_wire import FeaturesMessage, encode_features
from camnet.bus.frame import Frame
from camnet.bus.node import Tally, guarded
from camnet.matching.edge import CameraFeatures, EdgeConfig, FeatureExtractor
from camnet.matching.features import Detector, Features, MatcherConfig

log = logging.getLogger(__name__)

BUFFERED_FRAMES = 8  # the latest frames kept for the worker to pick from


@dataclass(frozen=True)
class FeatureStageConfig:
    period_s: float = 0.25  # grid of capture times the stage detects at
    matcher: MatcherConfig = MatcherConfig()
    edge: EdgeConfig = EdgeConfig()

    def __post_init__(self) -> None:
        if not self.period_s > 0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")


def to_message(features: CameraFeatures) -> FeaturesMessage:
    f = features.features
    return FeaturesMessage(features.camera_id, features.seq, features.timestamp_ns, features.width,
                           features.height, str(f.detector), features.keyframe_seq, features.reused, f.uv,
                           f.descriptors)


def from_message(message: FeaturesMessage) -> CameraFeatures:
    features = Features(message.uv, message.descriptors, Detector(message.detector))
    return CameraFeatures(message.camera_id, message.seq, message.timestamp_ns, message.width, message.height,
                          features, keyframe_seq=message.keyframe_seq, reused=message.reused)


class FeatureWorker:
    """Detects and publishes one camera's features on its own thread while the context lasts."""

    def __init__(self, publisher, camera_id: str, config: FeatureStageConfig = FeatureStageConfig()) -> None:
        self.publisher = publisher
        self.config = config
        self.extractor = FeatureExtractor(camera_id, config.matcher, config.edge)
        self.failures = Tally(log)
        self.published = 0
        self.skipped = 0  # grid points passed while detecting
        self.last_detect_s = 0.0
        self._frames: collections.deque[Frame] = collections.deque(maxlen=BUFFERED_FRAMES)
        self._arrived = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"features-{camera_id}", daemon=True)
        self._period_ns = round(config.period_s * 1e9)

    def __enter__(self) -> FeatureWorker:
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        with self._arrived:
            self._arrived.notify()
        self._thread.join()

    def offer(self, frame: Frame) -> None:
        """A new frame of the camera (called by the driver's loop)."""
        with self._arrived:
            self._frames.append(frame)
            self._arrived.notify()

    def _next_frame(self, after_grid_ns: int) -> tuple[Frame, int] | None:
        """The buffered frame nearest the latest grid point after `after_grid_ns`, and that point."""
        with self._arrived:
            while not self._stop.is_set():
                if self._frames:
                    grid_ns = self._frames[-1].timestamp_ns // self._period_ns * self._period_ns
                    if grid_ns > after_grid_ns:
                        frame = min(self._frames, key=lambda f: abs(f.timestamp_ns - grid_ns))
                        self._frames.clear()
                        return frame, grid_ns
                self._arrived.wait(0.5)
        return None

    def _run(self) -> None:
        import time

        detect = guarded(self._detect_and_publish, self.failures, "detecting features")
        last_grid_ns = -1
        while (chosen := self._next_frame(last_grid_ns)) is not None:
            frame, grid_ns = chosen
            if last_grid_ns >= 0:
                self.skipped += max(0, (grid_ns - last_grid_ns) // self._period_ns - 1)
            last_grid_ns = grid_ns
            start_s = time.perf_counter()
            detect(frame)
            self.last_detect_s = time.perf_counter() - start_s

    def _detect_and_publish(self, frame: Frame) -> None:
        features = self.extractor.extract(frame.image, seq=frame.seq, timestamp_ns=frame.timestamp_ns)
        self.publisher.put(encode_features(to_message(features)))
        self.published += 1


class FeatureNode:
    """A camera's feature stage as a node of its own: the camera's frames from the bus in, its features out.

    For a camera whose driver cannot host the stage (another process, another
    host near the camera): it subscribes to ``keys.frame(rig, camera)`` and
    publishes what `FeatureWorker` detects on ``keys.features(rig, camera)``.
    `run` until `stop` is set (or SIGTERM, Ctrl-C).
    """

    def __init__(self, session, rig: str, camera_id: str, config: FeatureStageConfig = FeatureStageConfig(), *,
                 stats_period_s: float = 1.0) -> None:
        from camnet.bus.receiver import FrameReceiver

        self.session, self.rig, self.camera_id = session, rig, camera_id
        self.config = config
        self.stats_period_s = stats_period_s
        self.stop = threading.Event()
        self.receiver = FrameReceiver({camera_id: None})  # another camera's frames are refused from their header
        self.worker: FeatureWorker | None = None

    def _on_frame(self, sample) -> None:
        frame = self.receiver.accept(sample.payload.to_bytes())
        if frame is not None and self.worker is not None:
            self.worker.offer(frame)

    def _activity(self):
        from camnet.bus.stats import Activity

        counts = self.receiver.counts().get(self.camera_id)
        worker = self.worker
        published = worker.published if worker is not None else 0
        detail = (f"{published} feature sets, detect {1e3 * worker.last_detect_s:.0f} ms"
                  if worker is not None else "starting")
        return Activity(fps=0.0, frames=counts.received if counts else 0,
                        dropped=worker.skipped if worker is not None else 0, detail=detail)

    def run(self) -> int:
        import zenoh

        from camnet.bus import keys
        from camnet.bus.node import Presence, stop_on_signals

        publisher = self.session.declare_publisher(keys.features(self.rig, self.camera_id),
                                                   congestion_control=zenoh.CongestionControl.DROP)
        failures = Tally(log)
        presence = Presence(self.session, rig=self.rig, kind="features", node_id=self.camera_id,
                            report=self._activity, tallies=(self.receiver.malformed, failures),
                            period_s=self.stats_period_s)
        with FeatureWorker(publisher, self.camera_id, self.config) as worker, presence:
            self.worker = worker
            subscriber = self.session.declare_subscriber(keys.frame(self.rig, self.camera_id),
                                                         guarded(self._on_frame, failures, "receiving a frame"))
            log.info("detecting the features of camera %r of rig %r (%s), publishing %s", self.camera_id, self.rig,
                     self.config.matcher.detector, keys.features(self.rig, self.camera_id))
            try:
                with stop_on_signals(self.stop):
                    while not self.stop.wait(0.2):
                        presence.publish_if_due()
            finally:
                subscriber.undeclare()
        return 0
