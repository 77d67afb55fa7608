"""The matcher node: a rig's frames in, pooled multi-view tracks out (camnet.observations/1).

Zenoh's callback threads only decode frames and hand them to a
`camnet.bus.sync.FrameSynchronizer` (under a lock), which keeps the latest few
frames per camera and counts what it drops. `MatcherNode.run` is the worker:
it takes the newest ready frame set and hands it to the rig's
`camnet.matching.engine.MatchingEngine` (the engine `camnet match` runs too),
which detects, matches, chains tracks and pools them; when the pool changed
it publishes the pool on ``keys.observations(rig)`` (by default at once, or
at most once per publish period), as a `camnet.io.messages.ObservationsMessage`,
whose fields say what it carries beside the contract's keys.

With ``lockstep`` the node takes its frames from a lockstep replay
(`camnet.bus.lockstep`): each announced step's frames form at most one frame
set, waiting for late cameras and the publish period follow the replayed
capture times, not the wall clock, and every step is acknowledged.

A camera whose feature stage runs beside its driver (`camnet driver
--features`) publishes keypoints and descriptors on ``keys.features``, taken
only from the stage declared for the camera (others are counted as foreign and
ignored); once they arrive, the matcher stops receiving its frames
(`matcher_frames`, until its stage stops) and its features join the frame sets
in place of frames.
The engine detects the frames of the other cameras, in a thread pool over the
cores (OpenCV releases the GIL), and matches every pair until the rig's
calibration (``keys.calibration``, also asked of the calibrator at start,
taken only from the rig's calibrator: `matcher_calibration`) arrives, then the
view graph's pairs.

Cameras are listed with the sizes of their frames (or of the rig file before
the first frame) and what the rig file's `intrinsics` section knows of them
(K, dist, fixed); nothing else is passed on, not even a simulated camera's
ground truth. The latest message also answers queries on the same key.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

from camnet.services.features import from_message
from camnet.services.matcher_calibration import CalibrationInbox, pool_attachment
from camnet.services.matcher_config import MatcherNodeConfig, rig_options, rig_stereo
from camnet.services.matcher_frames import FrameSubscriptions

from camnet.bus import heap, keys, latency, lockstep
from camnet.bus.features_wire import FeaturesError, FeaturesMessage, decode_features
from camnet.bus.frame import Frame
from camnet.bus.node import Presence, Tally, guarded, stop_on_signals
from camnet.bus.receiver import FrameReceiver
from camnet.bus.session import declare_liveliness
from camnet.bus.source import sample_source
from camnet.bus.stats import Activity, CameraSeen, RateMeter
from camnet.bus.sync import FrameSet, FrameSynchronizer, SyncCounts
from camnet.errors import InputError
from camnet.io.messages import ObservationsMessage
from camnet.io.observations_encoder import ObservationsEncoder
from camnet.io.rig import Rig, camera_info, configured_size
from camnet.matching.edge import CameraFeatures
from camnet.matching.engine import CameraImage, MatchingEngine
from camnet.matching.pool import PoolUpdate

__all__ = ["MatcherNode", "MatcherNodeConfig", "rig_options", "rig_stereo"]  # the options live in matcher_config
log = logging.getLogger(__name__)

NODE_KIND = "matcher"
NODE_ID = "matcher"
WARNING_PERIOD_S = 30.0  # at most one warning of frames dropped per this many seconds
NO_SET_WARNING_S = 10.0  # frames arrive but no frame set forms for this long: say why
MIN_SILENCE_S = 1.0  # a camera silent this long (and longer than a set waits) is reported missing
LOCKSTEP_FRAME_WAIT_S = 10.0  # a step's frames are on their way when it is announced
# The view graph is renewed from the newest calibration at most this often: a static rig's overlaps barely
# change, and parsing a large rig's calibration and renewing its view graph costs a good part of a frame set's
# CPU, with a calibration about every set. While it leaves a camera out, which is matched with every camera
# at several times a set's usual cost, at most every 2 s (docs/benchmarks.md, "Sixteen cameras across hosts",
# "The matcher").
VIEW_GRAPH_PERIOD_S, PARTIAL_VIEW_GRAPH_PERIOD_S = 10.0, 2.0


class HealthWatch:
    """When the worker warns: of frames dropped for slow matching at most once per `WARNING_PERIOD_S`, and of
    no frame set for `NO_SET_WARNING_S` once per stretch without sets (the statistics show it going on)."""

    def __init__(self, now_s: float) -> None:
        self.last_set_s = now_s
        self._dropped = 0  # frames dropped by the last warning
        self._dropped_warned_s = -WARNING_PERIOD_S
        self._said_no_set = False

    def frame_set_done(self, now_s: float) -> None:
        self.last_set_s, self._said_no_set = now_s, False

    def dropped_since_warning(self, dropped: int, now_s: float) -> int:
        """Frames dropped since the last warning (of `dropped` since start) when a warning is due now, else 0."""
        if dropped <= self._dropped or now_s - self._dropped_warned_s < WARNING_PERIOD_S:
            return 0
        since, self._dropped, self._dropped_warned_s = dropped - self._dropped, dropped, now_s
        return since

    def silent_s(self, now_s: float) -> float | None:
        """Seconds without a frame set when a warning is due now, else None."""
        if self._said_no_set or now_s - self.last_set_s < NO_SET_WARNING_S:
            return None
        self._said_no_set = True
        return now_s - self.last_set_s


class MatcherNode:
    """Matches the frames of `rig` published on `session`; `run` until `stop` is set."""

    def __init__(self, session, rig: Rig, *, config: MatcherNodeConfig | None = None) -> None:
        self.session, self.rig = session, rig
        self.config = config = MatcherNodeConfig() if config is None else config
        self.stereo = rig_stereo(rig)
        self.camera_ids = tuple(c.id for c in rig.cameras)
        self.stop = threading.Event()
        sizes = {c: configured_size(rig, c) for c in self.camera_ids}
        self._workers = ThreadPoolExecutor(max_workers=max(1, min(len(self.camera_ids), os.cpu_count() or 1)),
                                           thread_name_prefix="detect")
        # A camera the rig file gives no size joins the pool with its first frame.
        self.engine = MatchingEngine([camera_info(rig, c, *(sizes[c] or (0, 0))) for c in self.camera_ids],
                                     self.stereo, config.engine_config(), executor=self._workers)
        self.receiver = FrameReceiver(sizes)  # frames of other cameras or sizes are refused from their header
        self._ready = threading.Condition()
        self._sync = FrameSynchronizer(self.camera_ids, required=(self.stereo.left, self.stereo.right),
                                       tolerance_ns=round(config.sync_tolerance_ms * 1e6),
                                       max_wait_s=config.max_wait_s, frames_per_camera=config.frames_per_camera,
                                       free_run=config.sync_free_run)
        self._inbox = lockstep.StepInbox() if config.lockstep else None
        self.rejected = Tally(log)  # frames decoded but not usable, and malformed steps, by kind
        self.failures = Tally(log)  # handlers that raised (matching a frame set, say), by what and type
        self.few_features = Tally(log)  # images with too few keypoints, by camera
        # Well-formed features from another publisher than the camera's stage, by camera; calibrations from
        # another publisher than the rig's calibrator.
        self.foreign = Tally(log)
        handler = guarded(self.on_sample, self.failures, "receiving a frame")
        self.frames = FrameSubscriptions(  # whose frames to receive; the worker (un)declares
            self.camera_ids, declare_all=lambda: session.declare_subscriber(keys.all_frames(rig.name), handler),
            declare_one=lambda camera_id: session.declare_subscriber(keys.frame(rig.name, camera_id), handler))
        self.calibration = CalibrationInbox(rig.name, rejected=self.rejected, foreign=self.foreign)  # for the worker
        self._view_graph_s = float("-inf")  # monotonic time the view graph last took a calibration
        self._process_safely = guarded(self.process, self.failures, "matching a frame set")
        self._update_frames = guarded(self.frames.update, self.failures, "subscribing to frames")
        self.latest_capture_ns = 0
        self._stamps: dict[str, int] = {}  # the newest pooled frame set's way through (camnet.bus.latency)
        self.published = 0
        self._dirty = False
        self._latest_document: bytes | None = None
        self._encoder = ObservationsEncoder()
        self._next_publish_s = float("-inf")  # on the wall clock, or the capture clock in lockstep
        self._rate = RateMeter(window_s=10.0)
        self._health = HealthWatch(time.monotonic())

    # ------------------------------------------------------------ Zenoh's threads

    def on_sample(self, sample) -> None:
        """Subscriber callback: decode, check, hand over; nothing heavy, never raises."""
        key = str(sample.key_expr)
        if self.frames.sends_features(key.rsplit("/", 2)[-2]):
            return  # its features come from its own stage: not worth decoding (received while switching)
        frame = self.receiver.accept(sample.payload.to_bytes())
        if frame is None:
            return
        kind = self._check(frame, str(sample.key_expr))
        if kind is not None:
            self.rejected.count(kind, "dropping a frame of camera %r (%s; rig %r has cameras %s)", frame.camera_id,
                                kind, self.rig.name, ", ".join(self.camera_ids))
        if self._inbox is not None:
            self._inbox.add_frame(frame.camera_id, frame.seq, frame if kind is None else None)
            return
        if kind is not None:
            return
        with self._ready:
            self._sync.add(frame, now_s=time.monotonic())
            self._ready.notify()

    def on_features(self, sample) -> None:
        """Subscriber callback of a camera's feature stage: decode, check, hand over; never raises."""
        key = str(sample.key_expr)
        try:
            message = decode_features(sample.payload.to_bytes())
        except FeaturesError as exc:
            self.rejected.count(f"features {exc.kind}", "dropping malformed features on %s (%s)", key, exc)
            return
        kind = why = None
        key_camera = key.split("/")[-2]
        if message.camera_id not in self.camera_ids:
            kind, why = "unknown-camera", f"not a camera of rig {self.rig.name!r}: {', '.join(self.camera_ids)}"
        elif key_camera != message.camera_id:
            kind, why = "camera-mismatch", f"on the key of camera {key_camera!r}"
        elif message.detector != str(self.config.detector):
            kind = "detector-mismatch"
            why = f"detected with {message.detector}, this matcher uses {self.config.detector}"
        if kind is not None:
            self.rejected.count(f"features {kind}", "dropping the features of camera %r (%s)", message.camera_id, why)
            return
        source = sample_source(sample)
        why = self.frames.features_arrived(message.camera_id, time.monotonic(), source)
        if why is not None:
            self.foreign.count(f"foreign features: {message.camera_id}", "ignoring features of camera %r from "
                               "source %s (%s)", message.camera_id, source or "not stated", why)
            return
        with self._ready:
            self._sync.add(message, now_s=time.monotonic())
            self._ready.notify()

    def _take_calibration(self) -> None:
        """Choose pairs with the latest calibration from now on (the first at once, then one per period)."""
        now_s = time.monotonic()
        calibrated = self.engine.view_graph.calibrated
        if calibrated and now_s < self._view_graph_s + (
                VIEW_GRAPH_PERIOD_S if calibrated >= set(self.camera_ids) else PARTIAL_VIEW_GRAPH_PERIOD_S):
            return  # a newer one replaces it in the inbox meanwhile
        calibration = self.calibration.take()
        if calibration is None:
            return
        self._view_graph_s = now_s
        take = guarded(self.engine.take_calibration, self.failures, "taking a calibration")  # counted if it raises
        take(calibration)

    def _check(self, frame: Frame, key: str) -> str | None:
        if frame.camera_id not in self.camera_ids:
            return "unknown-camera"
        try:
            _, key_camera = keys.parse_frame(key)
        except InputError:
            return "bad-key"
        return None if key_camera == frame.camera_id else "camera-mismatch"

    def _on_stage(self, sample) -> None:
        """Liveliness callback of the feature stages' tokens: a camera's stage joins or leaves."""
        import zenoh

        try:
            _, camera_id = keys.parse_features(str(sample.key_expr))
        except InputError:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self.frames.stage_declared(camera_id)
        else:
            self.frames.stage_left(camera_id)

    def _on_step(self, sample) -> None:
        try:
            self._inbox.add_step(lockstep.Step.parse(sample.payload.to_bytes()))
        except InputError as exc:
            self.rejected.count("bad-step", "dropping a malformed lockstep step (%s)", exc)

    def _on_query(self, query) -> None:
        document = self._latest_document
        if document is not None:
            query.reply(keys.observations(self.rig.name), document)

    # ------------------------------------------------------------ the worker

    def next_frame_set(self, *, timeout_s: float) -> FrameSet | None:
        """The newest ready frame set, waiting up to `timeout_s` for one."""
        with self._ready:
            frame_set = self._sync.pop(now_s=time.monotonic())
            if frame_set is None:
                self._ready.wait(timeout_s)
                frame_set = self._sync.pop(now_s=time.monotonic())
            return frame_set

    def step_frame_set(self, step: lockstep.Step) -> FrameSet | None:
        """The frame set of one lockstep step, formed on its capture clock: no wall-clock wait."""
        frames, missing = self._inbox.take_frames(step, timeout_s=LOCKSTEP_FRAME_WAIT_S)
        if missing:
            log.warning("step %d: the frames of %s never came; matching without them", step.step,
                        ", ".join(missing))
        arrived_s = step.capture_ns / 1e9
        with self._ready:
            for camera_id in self.camera_ids:  # rig order, whatever the arrival order
                if camera_id in frames:
                    self._sync.add(frames[camera_id], now_s=arrived_s)
            # Every frame of the step is here: waiting longer for a late camera changes nothing.
            return self._sync.pop(now_s=arrived_s + self.config.max_wait_s)

    def process(self, frame_set: FrameSet) -> PoolUpdate:
        """Forget the cameras the calibrator found moved, take the latest calibration, then match one frame set
        and pool its tracks."""
        taken_ns = latency.now_ns()
        self.engine.forget_moved(self.calibration.take_moved())
        self._take_calibration()
        result = self.engine.process([_engine_item(item) for item in frame_set.frames.values()])
        for camera_id, reason in result.few_features.items():
            self.few_features.count(f"few features: {camera_id}", "camera %r: %s", camera_id, reason)
        self._rate.tick()
        update = result.update
        if (update.added or update.reobserved) and frame_set.timestamp_ns >= self.latest_capture_ns:
            self.latest_capture_ns = frame_set.timestamp_ns
            self._stamps = {"taken": taken_ns, "detected": result.detected_ns, "matched": result.matched_ns,
                            "pooled": result.pooled_ns}
        if update.added or update.reobserved or update.evicted:
            self._dirty = True
        missing = f" (without {', '.join(frame_set.missing)})" if frame_set.missing else ""
        stats = self.engine.stats
        log.info("frame set %d: %d cameras%s, %d of %d pairs, %d tracks (%d seen by 3+), +%d new, pool %d, %.0f ms",
                 stats.frame_sets_matched, len(frame_set.frames), missing, *result.pairs, result.tracks,
                 result.tracks_3plus, update.added, stats.tracks_pooled, 1e3 * result.elapsed_s)
        return update

    def message(self) -> ObservationsMessage:
        """The observations message of the pool now."""
        obs = self.engine.observations()
        # The rig's further known distances, of the cameras pooled so far (one of unknown size joins later).
        baselines = tuple(b for b in self.rig.baselines if {b.a, b.b} <= set(obs.camera_ids))
        return ObservationsMessage(
            replace(obs, baselines=baselines), rig=self.rig.name, pool_id=self.engine.pool_id,
            frame_sets=self.engine.stats.frame_sets_pooled, latest_capture_ns=self.latest_capture_ns,
            latency_ns=latency.StageStamps.from_stages(self._stamps), published_ns=latency.now_ns())

    def sync_counts(self) -> SyncCounts:  # frames received, frame sets formed, frames dropped by synchronization
        with self._ready:
            return self._sync.counts

    def activity(self) -> Activity:
        counts = self.sync_counts()
        malformed = self.receiver.malformed.total + self.rejected.total
        stats = self.engine.stats
        detail = (f"{counts.received} frames in, {stats.tracks_pooled} tracks pooled, {stats.frame_sets_pooled} sets, "
                  f"{stats.pairs[0]} pairs, match {1e3 * stats.last_match_s:.0f} ms, {counts.partial_sets} partial, "
                  f"{malformed} bad frames")
        return Activity(fps=round(self._rate.rate(), 2), frames=stats.frame_sets_matched, dropped=counts.dropped,
                        detail=detail, cameras=self.cameras_seen())

    def cameras_seen(self) -> dict[str, CameraSeen]:
        """Per rig camera: seconds since its last frame (or features, from its own stage) and their rate;
        missing once silent for longer than a frame set waits for it, or two intervals of its features
        (or before its first frame)."""
        arrivals, stages = self.receiver.arrivals(), self.frames.arrivals(time.monotonic())
        seen = {}
        for camera_id in self.camera_ids:
            age_s, fps = arrivals.get(camera_id, (None, 0.0))
            silence_s = max(self.config.max_wait_s, MIN_SILENCE_S)
            if camera_id in stages:  # its frames are not received
                age_s, interval_s = stages[camera_id]
                fps, silence_s = 1 / interval_s if interval_s > 0 else 0.0, max(silence_s, 2 * interval_s)
            missing = age_s is None or age_s > silence_s
            seen[camera_id] = CameraSeen(age_s=None if age_s is None else round(age_s, 3), fps=round(fps, 2),
                                         missing=missing)
        return seen

    def _check_health(self, now_s: float) -> None:
        """Say so when frames are dropped for slow matching, or when no frame set forms."""
        stats, dropped = self.engine.stats, self.sync_counts().dropped
        dropped = self._health.dropped_since_warning(dropped, now_s) if stats.frame_sets_matched else 0
        if dropped:
            log.warning("matching (%.0f ms per frame set) is slower than the cameras: %d frames dropped "
                        "since the last warning; the latest frames are matched", 1e3 * stats.last_match_s, dropped)
        silent_s = self._health.silent_s(now_s)
        if silent_s is not None:
            counts = self.receiver.counts()
            received = ", ".join(f"{c} {counts[c].received if c in counts else 0}" for c in self.camera_ids)
            if self.config.sync_free_run:
                apart = "within half a frame period of each other"
            else:
                apart = (f"within {self.config.sync_tolerance_ms:.1f} ms of each other (cameras not triggered "
                         "together need 'free_run: true' in the rig file's sync section)")
            log.warning("no frame set for %.0f s (frames received: %s); the stereo cameras must publish, "
                        "with capture times %s", silent_s, received, apart)

    def _publish_if_due(self, publisher, clock_s: float, *, force: bool = False) -> bool:
        """Publish the pool if it changed and a publish period has passed on `clock_s` (or `force`)."""
        if not self._dirty or (clock_s < self._next_publish_s and not force):
            return False
        # The bytes of encode_observations_message(self.message()), only the tracks that changed encoded anew.
        self._latest_document = self._encoder.encode(self.message())
        publisher.put(self._latest_document, attachment=pool_attachment(self.engine.pool))
        self.published += 1
        self._dirty = False
        self._next_publish_s = clock_s + self.config.publish_period_s
        return True

    def _live_iteration(self, publisher) -> None:
        self._update_frames(time.monotonic())
        self.calibration.ask_until_answered(time.monotonic())
        frame_set = self.next_frame_set(timeout_s=0.05)
        now_s = time.monotonic()
        if frame_set is not None:
            self._process_safely(frame_set)
            # Waiting for the next set starts now: matching time is not a missing set.
            now_s = time.monotonic()
            self._health.frame_set_done(now_s)
        self._publish_if_due(publisher, now_s)
        self._check_health(now_s)

    def _lockstep_iteration(self, publisher, ack_publisher) -> None:
        step = self._inbox.next_step(timeout_s=0.05)
        if step is None:
            return
        frame_set = self.step_frame_set(step)
        if frame_set is not None:
            self._process_safely(frame_set)
        ack = lockstep.Ack(step=step.step, status="matched" if frame_set is not None else "no frame set")
        if self._publish_if_due(publisher, step.capture_ns / 1e9, force=step.final):
            ack = replace(ack, pool_id=self.engine.pool_id, frame_sets=self.engine.stats.frame_sets_pooled)
        ack_publisher.put(ack.to_json())

    def run(self) -> int:
        """Subscribe, match and publish until `stop` is set (or SIGTERM, Ctrl-C)."""
        import zenoh

        rig = self.rig.name
        publisher = self.session.declare_publisher(keys.observations(rig),
                                                   congestion_control=zenoh.CongestionControl.BLOCK)
        # Live, frames are subscribed to by camera as they switch to features and back (self.frames.update).
        declared = [*([self.session.declare_subscriber(keys.all_frames(rig), guarded(
                        self.on_sample, self.failures, "receiving a frame"))] if self._inbox is not None else []),
                    self.session.declare_subscriber(keys.all_features(rig),
                                                    guarded(self.on_features, self.failures, "receiving features")),
                    self.session.liveliness().declare_subscriber(
                        keys.all_features(rig), guarded(self._on_stage, self.failures, "watching the feature stages"),
                        history=True),
                    # Not in lockstep, whose matching must not depend on when a calibration arrives.
                    *(self.calibration.declare(self.session, self.failures, time.monotonic())
                      if self.config.view_graph and self._inbox is None else ()),
                    self.session.declare_queryable(keys.observations(rig),
                                                   guarded(self._on_query, self.failures, "answering a query"))]
        ack_publisher = None
        if self._inbox is not None:
            declared.append(self.session.declare_subscriber(
                keys.lockstep_step(rig), guarded(self._on_step, self.failures, "receiving a step")))
            ack_publisher = self.session.declare_publisher(keys.lockstep_ack(rig, NODE_KIND),
                                                           congestion_control=zenoh.CongestionControl.BLOCK)
            declared.append(declare_liveliness(self.session, keys.lockstep_ack(rig, NODE_KIND)))
        presence = Presence(self.session, rig=rig, kind=NODE_KIND, node_id=NODE_ID, report=self.activity,
                            tallies=(self.receiver.malformed, self.receiver.off_clock, self.rejected, self.failures,
                                     self.few_features, self.foreign),
                            period_s=self.config.stats_period_s, counted="frame sets matched",
                            dropped="frames dropped", trim_heap_period_s=heap.TRIM_PERIOD_S)
        log.info("matching %s (stereo %s-%s, %s), publishing %s%s", ", ".join(self.camera_ids), self.stereo.left,
                 self.stereo.right, "a parallel head: matched along rows" if self.stereo.parallel else
                 "matched like any pair", keys.observations(rig), " in lockstep" if self._inbox is not None else "")
        try:
            with stop_on_signals(self.stop), presence:
                while not self.stop.is_set():
                    if self._inbox is None:
                        self._live_iteration(publisher)
                    else:
                        self._lockstep_iteration(publisher, ack_publisher)
                    presence.publish_if_due()
        finally:
            for entity in declared:
                entity.undeclare()
            self.frames.close()
            self._workers.shutdown()
        return 0


def _engine_item(item: Frame | FeaturesMessage) -> CameraImage | CameraFeatures:
    """One camera's part of a frame set as the engine takes it: its frame's image, or its stage's features."""
    if isinstance(item, FeaturesMessage):
        return from_message(item)
    return CameraImage(item.camera_id, item.image, seq=item.seq, timestamp_ns=item.timestamp_ns,
                       encoding=item.encoding)
