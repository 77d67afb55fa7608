"""The replay node: a recorded session's frames back on the bus, as the drivers sent them.

Frames go out on the live drivers' keys with their recorded bytes unchanged
(so seq and capture timestamps are the recorded ones), each camera with a
liveliness token and statistics like a driver's; a recorded ground truth is
put and answered to queries as the sim driver does. Observations and
calibrations are left to the live matcher and calibrator unless asked for.

Order is the file's log-time order (ties: file order), the same on every
run. At `rate` r > 0, message k is due (t_k - t_0) / r after the start, where
t is the capture timestamp moved onto the recorder's clock (one offset per
channel, set by its first message and again if a source's clock jumps by more
than `RESYNC_NS`, e.g. a driver restart); frames then go out with congestion
control DROP, as a driver's. At rate 0 (as fast as possible) they go out with
BLOCK: as fast as the subscribers take them, no frame dropped on the bus.

With `lockstep` (camnet.bus.lockstep) the frames are grouped into steps, one
capture instant each (`StepGrouper`), and each step goes out only when the
matcher and the calibrator have finished with the previous one: what they
compute no longer depends on how fast they are.

This is a service rather than a driver: one process replays every camera of
the session in one global order, which a per-camera `camnet.drivers.base.Camera`
cannot express, and it shares the session layout with the recorder.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from camnet.bus import keys, lockstep
from camnet.bus.frame import FrameError, FrameHeader
from camnet.bus.node import Presence, Tally, guarded, stop_on_signals
from camnet.bus.source import declare_stage
from camnet.bus.stats import Activity, RateMeter
from camnet.errors import CamnetError, InputError
from camnet.io import session_file as sf

log = logging.getLogger(__name__)

NODE_KIND = "driver"  # to the rest of the rig, a replayed camera is a driver
RESYNC_NS = 2_000_000_000
LOCKSTEP_NODES = ("matcher", "calibrator")  # who acknowledges, in pipeline order


@dataclass(frozen=True)
class ReplayOptions:
    """`rate` 1.0 is the recorded pace, 0 as fast as the subscribers keep up."""

    rate: float = 1.0
    rig: str | None = None  # publish under this rig name (default: the recorded one)
    include_results: bool = False  # also replay recorded observations and calibrations
    wait_s: float = 10.0  # how long to wait for subscribers of the frames before starting
    stats_period_s: float = 1.0
    lockstep: bool = False  # one step at a time, each acknowledged by the matcher and the calibrator
    step_tolerance_ms: float = 5.0  # lockstep: frames of one step have capture times this close
    ack_timeout_s: float = 120.0  # lockstep: give up when a node has not acknowledged for this long

    def __post_init__(self) -> None:
        if not self.rate >= 0:
            raise InputError(f"rate: must be >= 0, got {self.rate}")
        if self.lockstep and self.rate != 0:
            raise InputError(f"rate: a lockstep replay goes as fast as the pipeline acknowledges, got {self.rate}")
        if self.lockstep and self.include_results:
            raise InputError("include_results: a lockstep replay feeds the live matcher and calibrator; "
                             "recorded results on their keys would be solved as if they were theirs")
        if not self.step_tolerance_ms >= 0 or not self.ack_timeout_s > 0:
            raise InputError("step_tolerance_ms must be >= 0 and ack_timeout_s > 0")
        if self.rig is not None:
            keys.validate_id(self.rig, what="rig")


@dataclass(frozen=True)
class ReplaySummary:
    rig: str
    frames: dict[str, int]
    messages: int
    total_frames: int
    duration_s: float
    damage: str | None
    malformed: dict[str, int] = field(default_factory=dict)
    lockstep: dict[str, int] | None = None  # steps, observations, and the calibrator's statuses

    def lines(self) -> list[str]:
        frames = sum(self.frames.values())
        rows = [f"replayed {frames}/{self.total_frames} frames of {len(self.frames)} camera(s) "
                f"({self.messages} messages) on rig {self.rig} in {self.duration_s:.1f} s"]
        rows += [f"  {camera_id:<16}{n:>8}" for camera_id, n in sorted(self.frames.items())]
        if self.malformed:
            rows.append("malformed frames (not published): " + ", ".join(
                f"{kind} {n}" for kind, n in sorted(self.malformed.items())))
        if self.lockstep is not None:
            rows.append("lockstep: " + ", ".join(f"{k} {n}" for k, n in self.lockstep.items()))
        if self.damage:
            rows.append(f"stopped at damage: {self.damage}")
        return rows


class Pacer:
    """When each message is due, in seconds of `time.monotonic()`; never earlier than the last."""

    def __init__(self, rate: float) -> None:
        self.rate = rate
        self._offsets: dict[str, int] = {}
        self._origin: tuple[int, float] | None = None
        self._last_due_s = 0.0

    def due_s(self, topic: str, log_time_ns: int, publish_time_ns: int) -> float:
        offset = self._offsets.get(topic)
        if offset is None or abs(publish_time_ns + offset - log_time_ns) > RESYNC_NS:
            # Map this source's clock (a camera's, maybe) onto the recorder's.
            offset = self._offsets[topic] = log_time_ns - publish_time_ns
        t_ns = publish_time_ns + offset
        if self._origin is None:
            self._origin = (t_ns, time.monotonic())
        origin_ns, origin_s = self._origin
        due = origin_s + (t_ns - origin_ns) / 1e9 / self.rate if self.rate > 0 else origin_s
        self._last_due_s = max(due, self._last_due_s)
        return self._last_due_s


@dataclass
class FrameGroup:
    """The frames of one capture instant, in log-time order: (topic, bytes, header)."""

    capture_ns: int
    frames: list[tuple[str, bytes, FrameHeader]] = field(default_factory=list)

    def has(self, topic: str) -> bool:
        return any(t == topic for t, _, _ in self.frames)


class StepGrouper:
    """Frames, fed in log-time order, grouped into lockstep steps: one capture instant each.

    A frame joins the oldest open step whose capture time (its first frame's)
    is within `tolerance_ns` of its own and that has no frame of its camera
    (topic) yet; otherwise it opens a new step. Steps leave oldest first: once
    the oldest holds every one of `n_cameras`, or when more than `window`
    steps are open (a camera missed an instant). A pure function of the input:
    the same file gives the same steps.
    """

    def __init__(self, n_cameras: int, *, tolerance_ns: int, window: int = 4) -> None:
        self.n_cameras = n_cameras
        self.tolerance_ns = tolerance_ns
        self.window = window
        self._open: list[FrameGroup] = []

    def add(self, topic: str, data: bytes, header: FrameHeader) -> list[FrameGroup]:
        """Add one frame; the steps now complete, oldest first."""
        group = next((g for g in self._open if abs(header.timestamp_ns - g.capture_ns) <= self.tolerance_ns
                      and not g.has(topic)), None)
        if group is None:
            group = FrameGroup(header.timestamp_ns)
            self._open.append(group)
        group.frames.append((topic, data, header))
        done = []
        while self._open and (len(self._open[0].frames) >= self.n_cameras or len(self._open) > self.window):
            done.append(self._open.pop(0))
        return done

    def flush(self) -> list[FrameGroup]:
        """The steps still open, at the end of the session."""
        done, self._open = self._open, []
        return done


@dataclass
class _Camera:
    """One replayed camera: to the rig, a driver node."""

    publisher: object
    presence: Presence
    malformed: Tally  # recorded frames not published, by FrameError.kind
    meter: RateMeter = field(default_factory=RateMeter)
    frames: int = 0


class Replayer:
    def __init__(self, session, session_file: sf.SessionFile, *,
                 options: ReplayOptions = ReplayOptions()) -> None:
        self.session = session
        self.file = session_file
        self.options = options
        self.stop = threading.Event()
        self.recorded_rig = session_file.rigs[0]
        self.rig = options.rig or self.recorded_rig
        self.failures = Tally(log)  # callbacks that raised, and malformed acknowledgements, by kind
        self._groundtruth: bytes | None = None
        self._acks = lockstep.AckBox()
        self._last_capture_ns = 0
        self._lockstep_counts: dict[str, int] | None = {"steps": 0, "observations": 0} if options.lockstep else None

    def _routes(self) -> dict[str, str]:
        """Recorded topic -> key to publish on, for what is replayed."""
        src, dst = self.recorded_rig, self.rig
        routes = {keys.frame(src, cam): keys.frame(dst, cam)
                  for cam in (keys.parse_frame(t)[1] for t in self.file.frame_topics())}
        routes[keys.groundtruth(src)] = keys.groundtruth(dst)
        # A feature stage's messages go out at their recorded pace, as the frames do.
        for topic in self.file.topics:
            try:
                _, camera_id = keys.parse_features(topic)
            except InputError:
                continue
            routes[topic] = keys.features(dst, camera_id)
        if self.options.include_results:
            routes[keys.observations(src)] = keys.observations(dst)
            routes[keys.calibration(src)] = keys.calibration(dst)
        return {topic: key for topic, key in routes.items() if topic in self.file.topics}

    def _declare_cameras(self, stack: contextlib.ExitStack) -> dict[str, _Camera]:
        """The replayed cameras by topic, each on the bus (as a driver) until `stack` closes."""
        import zenoh

        congestion = (zenoh.CongestionControl.DROP if self.options.rate > 0 and not self.options.lockstep
                      else zenoh.CongestionControl.BLOCK)
        cameras = {}
        for topic in self.file.frame_topics():
            camera_id = keys.parse_frame(topic)[1]
            malformed = Tally(log)
            presence = Presence(self.session, rig=self.rig, kind=NODE_KIND, node_id=camera_id,
                                report=lambda topic=topic: self._activity(cameras[topic]),
                                tallies=(malformed,), period_s=self.options.stats_period_s,
                                status_period_s=None)  # camnet replay prints its own progress
            cameras[topic] = _Camera(
                publisher=self.session.declare_publisher(keys.frame(self.rig, camera_id),
                                                         congestion_control=congestion),
                presence=stack.enter_context(presence), malformed=malformed)
        return cameras

    def _activity(self, camera: _Camera) -> Activity:
        return Activity(fps=round(camera.meter.rate(), 2), frames=camera.frames, dropped=0,
                        detail=f"replay {self.file.path.name}")

    def _wait_for_subscribers(self, cameras: dict[str, _Camera]) -> None:
        deadline = time.monotonic() + self.options.wait_s
        while not self.stop.is_set() and time.monotonic() < deadline:
            if all(c.publisher.matching_status.matching for c in cameras.values()):
                return
            time.sleep(0.02)
        waiting = [keys.parse_frame(t)[1] for t, c in cameras.items()
                   if not c.publisher.matching_status.matching]
        if waiting:
            log.warning("no subscriber for the frames of %s after %.1f s; replaying anyway",
                        ", ".join(waiting), self.options.wait_s)

    def _wait_for_lockstep_nodes(self) -> None:
        """Return once every lockstep node has declared its token; CamnetError after `wait_s`."""
        deadline = time.monotonic() + self.options.wait_s
        while True:
            missing = [kind for kind in LOCKSTEP_NODES
                       if not [r for r in self.session.liveliness().get(keys.lockstep_ack(self.rig, kind),
                                                                         timeout=1.0) if r.ok]]
            if not missing or self.stop.is_set():
                return
            if time.monotonic() >= deadline:
                raise CamnetError(f"lockstep: no {' and no '.join(missing)} in lockstep on rig {self.rig} after "
                                  f"{self.options.wait_s:.0f} s; start them with --lockstep (or raise --wait-s)")
            time.sleep(0.1)

    def _on_ack(self, sample) -> None:
        kind = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            self._acks.add(kind, lockstep.Ack.parse(sample.payload.to_bytes()))
        except InputError as exc:
            self.failures.count("malformed ack", "ignoring a malformed lockstep acknowledgement on %s (%s)",
                                sample.key_expr, exc)

    def _await_ack(self, kind: str, wanted, what: str) -> lockstep.Ack | None:
        ack = self._acks.wait(kind, wanted, timeout_s=self.options.ack_timeout_s, stop=self.stop)
        if ack is None and not self.stop.is_set():
            raise CamnetError(f"lockstep: the {kind} did not acknowledge {what} within "
                              f"{self.options.ack_timeout_s:.0f} s (rig {self.rig}); is it still running?")
        return ack

    def _play_step(self, step_publisher, cameras: dict[str, _Camera], group: FrameGroup | None) -> None:
        """Publish one step (None: the final, empty one) and wait until the pipeline is done with it."""
        counts = self._lockstep_counts
        frames = {}
        for topic, data, header in group.frames if group is not None else ():
            self._put_frame(cameras[topic], data)
            frames[header.camera_id] = header.seq
        capture_ns = group.capture_ns if group is not None else self._last_capture_ns
        self._last_capture_ns = capture_ns
        step = lockstep.Step(counts["steps"], capture_ns, frames, final=group is None)
        step_publisher.put(step.to_json())
        counts["steps"] += 1
        matched = self._await_ack("matcher", lambda a: a.step == step.step, f"step {step.step}")
        if matched is None or matched.pool_id is None:
            return
        counts["observations"] += 1
        solved = self._await_ack("calibrator", lambda a: (a.pool_id, a.frame_sets) ==
                                 (matched.pool_id, matched.frame_sets),
                                 f"the observations of step {step.step}")
        if solved is not None:
            counts[solved.status] = counts.get(solved.status, 0) + 1

    def _put_frame(self, camera: _Camera, data: bytes) -> None:
        camera.publisher.put(data)
        camera.frames += 1
        camera.meter.tick()

    def _on_groundtruth_query(self, query) -> None:
        payload = self._groundtruth
        if payload is not None:
            query.reply(keys.groundtruth(self.rig), payload)

    def _sleep_until(self, due_s: float) -> None:
        while not self.stop.is_set():
            wait_s = due_s - time.monotonic()
            if wait_s <= 0:
                return
            time.sleep(min(wait_s, 0.1))

    def summary(self, cameras: dict[str, _Camera], messages: int, started_s: float) -> ReplaySummary:
        damage = self.file.damage.describe(self.file.path) if self.file.damage else None
        total = sum(self.file.message_counts.get(t, 0) for t in self.file.frame_topics())
        malformed: dict[str, int] = {}
        for camera in cameras.values():
            for kind, n in camera.malformed.counts.items():
                malformed[kind] = malformed.get(kind, 0) + n
        return ReplaySummary(
            rig=self.rig, frames={keys.parse_frame(t)[1]: c.frames for t, c in cameras.items()},
            messages=messages, total_frames=total, duration_s=time.monotonic() - started_s,
            damage=damage, malformed=malformed,
            lockstep=dict(self._lockstep_counts) if self._lockstep_counts is not None else None)

    def _replay_one(self, message: sf.SessionMessage, cameras: dict[str, _Camera], others: dict[str, object],
                    grouper: StepGrouper | None, step_publisher, pacer: Pacer) -> int:
        """Publish one recorded message, or in lockstep add it to its step and play the steps it
        completes; 1 if it was replayed, 0 if it was malformed."""
        topic = message.topic
        camera = cameras.get(topic)
        if camera is None:
            self._sleep_until(pacer.due_s(topic, message.log_time_ns, message.publish_time_ns))
            if topic == keys.groundtruth(self.recorded_rig):
                self._groundtruth = message.data
            others[topic].put(message.data)
            return 1
        try:
            header = sf.frame_header(message.data)
        except FrameError as exc:
            camera.malformed.count(exc.kind, "skipping a malformed recorded frame on %s (%s)", topic, exc)
            return 0
        if grouper is not None:
            for group in grouper.add(topic, message.data, header):
                self._play_step(step_publisher, cameras, group)
        else:
            self._sleep_until(pacer.due_s(topic, message.log_time_ns, message.publish_time_ns))
            self._put_frame(camera, message.data)
        return 1

    def run(self, *, on_progress: Callable[[ReplaySummary], None] | None = None,
            progress_period_s: float = 1.0) -> ReplaySummary:
        """Replay the session once, or until stopped (stop event, SIGTERM, Ctrl-C); the summary."""
        import zenoh

        routes = self._routes()
        messages = 0
        with contextlib.ExitStack() as stack:
            stack.enter_context(stop_on_signals(self.stop))
            cameras = self._declare_cameras(stack)
            others = {topic: self.session.declare_publisher(key) for topic, key in routes.items()
                      if topic not in cameras}
            for topic in others:  # a recorded feature stage is declared, as the live one was
                if routes[topic].endswith("/features"):
                    stage = declare_stage(self.session, self.rig, keys.parse_features(routes[topic])[1])
                    stack.callback(stage.undeclare)
            if keys.groundtruth(self.recorded_rig) in routes:
                stack.callback(self.session.declare_queryable(
                    keys.groundtruth(self.rig),
                    guarded(self._on_groundtruth_query, self.failures, "answering a query")).undeclare)
            grouper = step_publisher = None
            if self.options.lockstep:
                grouper = StepGrouper(len(cameras), tolerance_ns=round(self.options.step_tolerance_ms * 1e6))
                step_publisher = self.session.declare_publisher(keys.lockstep_step(self.rig),
                                                                congestion_control=zenoh.CongestionControl.BLOCK)
                stack.callback(self.session.declare_subscriber(
                    keys.all_lockstep_acks(self.rig),
                    guarded(self._on_ack, self.failures, "receiving an acknowledgement")).undeclare)
            pacer = Pacer(self.options.rate)
            started_s = time.monotonic()
            self._wait_for_subscribers(cameras)
            if grouper is not None:
                self._wait_for_lockstep_nodes()
            started_s = time.monotonic()
            next_progress_s = started_s + progress_period_s
            for message in self.file.messages():
                if self.stop.is_set():
                    break
                if message.topic not in routes:
                    continue
                messages += self._replay_one(message, cameras, others, grouper, step_publisher, pacer)
                for camera in cameras.values():
                    camera.presence.publish_if_due()
                if on_progress is not None and time.monotonic() >= next_progress_s:
                    on_progress(self.summary(cameras, messages, started_s))
                    next_progress_s = time.monotonic() + progress_period_s
            if grouper is not None and not self.stop.is_set():
                for group in [*grouper.flush(), None]:
                    self._play_step(step_publisher, cameras, group)
        return self.summary(cameras, messages, started_s)
