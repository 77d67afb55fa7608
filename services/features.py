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
