"""The feature stage beside a driver: one camera's frames in, its keypoints and descriptors out.

`FeatureWorker` runs in the driver's process (`camnet driver ... --features`),
on the camera's host, so that detection is spread over the hosts and the
matcher only matches. The driver hands it every frame (`offer`: a few
microseconds, never blocking the camera); its own thread detects
(`camnet.matching.edge.FeatureExtractor`: only where the image changed) and
publishes on ``keys.features(rig, camera)`` (`camnet.bus.features_wire`),
each message stating the stage's session as its source (`camnet.bus.source`),
while its liveliness token declares it the camera's stage (`declare_stage`).

Which frames: the frame set of the matcher needs the same capture instant
from every camera, while each camera's stage is free at its own moments. So
every stage takes the frame nearest to the latest point of a common grid of
capture times (multiples of `period_s` since the epoch), at most one per grid
point: cameras on one clock then pick the same instant. A stage slower than
the period skips grid points (counted as skipped).

How often: detecting a frame set the matcher has no time for is wasted (on
a loaded rig most of the host's CPU went so). With a `MatcherPace`, fed
the matcher's statistics, a stage detects only on every 2**k-th grid point,
the smallest k that offers at most `PACE_HEADROOM` times the frame sets the
matcher matched per second. Every stage hears the same reports and takes
the same k; and a coarser grid's points are points of every finer one, so
stages that differ for a moment still meet on the coarser one.
"""

from __future__ import annotations

import collections
import collections.abc
import logging
import threading
from dataclasses import dataclass

from camnet.bus.features_wire import FeaturesMessage, encode_features
from camnet.bus.frame import Frame
from camnet.bus.node import Tally, guarded, name_os_thread
from camnet.bus.stats import NodeStats
from camnet.matching.edge import CameraFeatures, EdgeConfig, FeatureExtractor
from camnet.matching.features import Detector, Features, MatcherConfig

log = logging.getLogger(__name__)

BUFFERED_FRAMES = 8  # the latest frames kept for the worker to pick from
PACE_WINDOW_S = 10.0  # the matcher's rate is measured over this much of its reports; a new pace holds as long
PACE_HEADROOM = 2.0  # offer at most this many times the frame sets matched: room to find out it can take more
MAX_PACE_LEVEL = 3  # at most 2**3 grid periods between the frame sets detected


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


def pace_level(offered_per_s: float, matched_per_s: float, *, max_level: int = MAX_PACE_LEVEL) -> int:
    """The smallest k (at most `max_level`) for which `offered_per_s` / 2**k frame sets per second are
    at most `PACE_HEADROOM` times the `matched_per_s` of the matcher."""
    for level in range(max_level + 1):
        if offered_per_s / (1 << level) <= PACE_HEADROOM * matched_per_s:
            return level
    return max_level


class MatcherPace:
    """The level k of a feature grid of `period_s` (detect every 2**k-th point) from the matcher's reports.

    The level is a function of the reports alone, not of when they arrived: it is decided at the
    first report of each window of `window_s` of the reports' stamps (windows aligned to the epoch),
    from the frame sets matched per second over the window before, by a pace that heard all of
    that window. So every stage that has listened for two windows takes the same level at the
    same report, and a level holds for a whole window (what the matcher matches at a new pace has
    to show before the next decision). It is 0 (every grid point) until the first decision, and
    again when the matcher starts anew (its count goes down). Thread-safe.
    """

    def __init__(self, period_s: float, *, window_s: float = PACE_WINDOW_S, max_level: int = MAX_PACE_LEVEL) -> None:
        self.offered_per_s = 1.0 / period_s
        self.max_level = max_level
        self.level = 0
        self.changes = 0
        self._window_ns = round(window_s * 1e9)
        self._reports: collections.deque[tuple[int, int]] = collections.deque()  # (timestamp_ns, frame sets)
        self._heard_since_ns: int | None = None  # the stamp of the first report heard (since the matcher started)
        self._lock = threading.Lock()

    def on_sample(self, sample) -> None:
        """A Zenoh sample of the matcher's statistics (``keys.node_stats(rig, "matcher", "matcher")``)."""
        self.on_stats(NodeStats.from_json(sample.payload.to_bytes()))

    def on_stats(self, stats: NodeStats) -> None:
        with self._lock:
            reports, window_ns = self._reports, self._window_ns
            if reports and stats.frames < reports[-1][1]:
                reports.clear()
                self.level, self._heard_since_ns = 0, None
            elif reports and stats.timestamp_ns <= reports[-1][0]:
                return  # one heard before (a late copy)
            if self._heard_since_ns is None:
                self._heard_since_ns = stats.timestamp_ns
            window = stats.timestamp_ns // window_ns
            decide = bool(reports) and window > reports[-1][0] // window_ns
            reports.append((stats.timestamp_ns, stats.frames))
            while reports[0][0] < (window - 1) * window_ns:
                reports.popleft()
            (first_ns, first), (last_ns, last) = reports[0], reports[-1]
            if not decide or self._heard_since_ns >= (window - 1) * window_ns or last_ns - first_ns < window_ns // 2:
                return  # within a window, not heard from the start of the one before, or the matcher was silent
            matched_per_s = (last - first) / ((last_ns - first_ns) / 1e9)
            level = pace_level(self.offered_per_s, matched_per_s, max_level=self.max_level)
            if level != self.level:
                log.info("feature pace: every %d grid point(s); the matcher matched %.2f frame sets/s",
                         1 << level, matched_per_s)
                self.level = level
                self.changes += 1


def pick_frame(frames: collections.abc.Sequence[Frame], period_ns: int,
               after_grid_ns: int) -> tuple[Frame, int] | None:
    """Of `frames` (oldest first), the one nearest the latest point of the grid of `period_ns`
    (multiples since the epoch) that the newest has reached, and that point; None when that
    point is not after `after_grid_ns`."""
    if not frames:
        return None
    grid_ns = frames[-1].timestamp_ns // period_ns * period_ns
    if grid_ns <= after_grid_ns:
        return None
    return min(frames, key=lambda f: abs(f.timestamp_ns - grid_ns)), grid_ns


class FeatureWorker:
    """Detects and publishes one camera's features on its own thread while the context lasts.

    With `pace`, only on the grid points of its level (`MatcherPace`); without, on every one.
    """

    def __init__(self, publisher, camera_id: str, config: FeatureStageConfig = FeatureStageConfig(), *,
                 pace: MatcherPace | None = None) -> None:
        self.publisher = publisher
        self.config = config
        self.pace = pace
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

    @property
    def period_ns(self) -> int:
        """The grid the stage detects on now: the configured one, coarsened by the pace's level."""
        return self._period_ns << (self.pace.level if self.pace is not None else 0)

    def offer(self, frame: Frame) -> None:
        """A new frame of the camera (called by the driver's loop)."""
        with self._arrived:
            self._frames.append(frame)
            self._arrived.notify()

    def _next_frame(self, after_grid_ns: int) -> tuple[Frame, int] | None:
        """The buffered frame nearest the latest grid point after `after_grid_ns`, and that point."""
        with self._arrived:
            while not self._stop.is_set():
                chosen = pick_frame(self._frames, self.period_ns, after_grid_ns)
                if chosen is not None:
                    self._frames.clear()
                    return chosen
                self._arrived.wait(0.5)
        return None

    def _run(self) -> None:
        import time

        name_os_thread(self._thread.name)
        detect = guarded(self._detect_and_publish, self.failures, "detecting features")
        last_grid_ns = -1
        while (chosen := self._next_frame(last_grid_ns)) is not None:
            frame, grid_ns = chosen
            if last_grid_ns >= 0:
                self.skipped += max(0, (grid_ns - last_grid_ns) // self.period_ns - 1)
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
    publishes what `FeatureWorker` detects on ``keys.features(rig, camera)``, at the matcher's
    pace (`MatcherPace`) unless `pace` is False. `run` until `stop` is set (or SIGTERM, Ctrl-C).
    """

    def __init__(self, session, rig: str, camera_id: str, config: FeatureStageConfig = FeatureStageConfig(), *,
                 stats_period_s: float = 1.0, pace: bool = True) -> None:
        from camnet.bus.receiver import FrameReceiver

        self.session, self.rig, self.camera_id = session, rig, camera_id
        self.config = config
        self.stats_period_s = stats_period_s
        self.stop = threading.Event()
        self.receiver = FrameReceiver({camera_id: None})  # another camera's frames are refused from their header
        self.worker: FeatureWorker | None = None
        self.pace = MatcherPace(config.period_s) if pace else None

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
        from camnet.bus.source import SourcedPublisher, declare_stage

        # Stating its session as the source: the matcher takes the camera's features from this stage only.
        publisher = SourcedPublisher(self.session.declare_publisher(keys.features(self.rig, self.camera_id),
                                                                    congestion_control=zenoh.CongestionControl.DROP))
        failures = Tally(log)
        presence = Presence(self.session, rig=self.rig, kind="features", node_id=self.camera_id,
                            report=self._activity, tallies=(self.receiver.malformed, self.receiver.off_clock, failures),
                            period_s=self.stats_period_s)
        stage = declare_stage(self.session, self.rig, self.camera_id)  # after its publisher: none is missed
        with FeatureWorker(publisher, self.camera_id, self.config, pace=self.pace) as worker, presence:
            self.worker = worker
            subscribers = [self.session.declare_subscriber(keys.frame(self.rig, self.camera_id),
                                                           guarded(self._on_frame, failures, "receiving a frame"))]
            if self.pace is not None:
                subscribers.append(self.session.declare_subscriber(
                    keys.node_stats(self.rig, "matcher", "matcher"),
                    guarded(self.pace.on_sample, failures, "reading the matcher's statistics")))
            log.info("detecting the features of camera %r of rig %r (%s), publishing %s", self.camera_id, self.rig,
                     self.config.matcher.detector, keys.features(self.rig, self.camera_id))
            try:
                with stop_on_signals(self.stop):
                    while not self.stop.wait(0.2):
                        presence.publish_if_due()
            finally:
                for subscriber in subscribers:
                    subscriber.undeclare()
                stage.undeclare()
        return 0
