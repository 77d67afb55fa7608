"""The calibrator node: observations in, a metric calibration out, kept current.

Every observations message (the matcher's pooled tracks, latest value only,
a `camnet.io.messages.ObservationsMessage`) is handed to the live policy
(`camnet.live.tracker`), which solves it warm from the last good calibration
and says whether the result may replace it. Good calibrations are published
on the rig's calibration key (a `camnet.io.messages.CalibrationMessage`, with
the stage times of `camnet.bus.latency`), answered to late joiners by a
queryable, and written atomically to a state file from which a restarted
calibrator resumes.

With ``lockstep`` (`camnet.bus.lockstep`) every observations message is
acknowledged once it has been solved and its result published, so that a
lockstep replay sends the next frame set only then.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from camnet.bus import heap, keys, latency, lockstep
from camnet.bus.moved import moved_attachment, parse_forgotten_attachment
from camnet.bus.node import Presence, Tally, guarded, stop_on_signals
from camnet.bus.session import declare_liveliness
from camnet.bus.source import SourcedPublisher, declare_calibrator
from camnet.bus.stats import Activity, RateMeter
from camnet.errors import InputError
from camnet.io.formats import MAX_TRACKS, write_json_atomic
from camnet.io.messages import (
    CalibrationMessage,
    MessageError,
    ObservationsMessage,
    calibration_message_to_doc,
    decode_observations_message,
    encode_calibration_message,
    load_calibration_message,
    observations_message_to_doc,
)
from camnet.io.rig import Rig
from camnet.io.rig_match import calibration_mismatch, observations_mismatch
from camnet.live.policy import LiveConfig
from camnet.live.tracker import Outcome, Tracker
from camnet.model.accuracy import scale_sigma_rel
from camnet.model.calibration import Calibration
from camnet.solve.report.verdict import judge

log = logging.getLogger(__name__)

NODE_KIND = "calibrator"
# An observations message is at most this large: MAX_TRACKS tracks of 16 cameras take about 12 MB.
# A larger one is dropped unread: it would hold the node, and a gigabyte of memory, for a minute or more
# (docs/benchmarks.md, "Evidence behind the nodes' choices").
MAX_MESSAGE_BYTES = 32 * 2**20
SUBSAMPLE_SEED = 0  # a larger set is solved on MAX_TRACKS of its tracks, the same ones every time
WARNING_PERIOD_S = 30.0  # a solve that is not kept is warned about at most this often per outcome, else logged


@dataclass(frozen=True)
class CalibratorConfig:
    """The calibrator node: the live policy, where it keeps its state, how often it reports."""

    live: LiveConfig = LiveConfig()
    state_path: Path | None = None
    # Where the observations behind the last calibration published are written when the node stops.
    observations_path: Path | None = None
    stats_period_s: float = 1.0


class LatestMessage:
    """A one-slot mailbox: the newest payload (with its attachment) wins, superseded ones are counted."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._payload: bytes | None = None
        self._received_ns = 0
        self._attachment: bytes | None = None
        self.superseded = 0

    def put(self, payload: bytes, attachment: bytes | None = None) -> None:
        received_ns = latency.now_ns()
        with self._ready:
            if self._payload is not None:
                self.superseded += 1
            self._payload, self._received_ns, self._attachment = payload, received_ns, attachment
            self._ready.notify()

    def take(self, *, timeout_s: float) -> tuple[bytes, int, bytes | None] | None:
        """(payload, when it was put: Unix epoch, ns, its attachment), or None when nothing came within
        `timeout_s`."""
        with self._ready:
            if not self._ready.wait_for(lambda: self._payload is not None, timeout=timeout_s):
                return None
            payload, self._payload = self._payload, None
            return payload, self._received_ns, self._attachment


def untrusted_state(path: Path) -> str | None:
    """Why the state file `path` may hold a calibration someone else wrote (one line, with the fix), or None:
    it is owned by another user than the one running the calibrator, or others than its owner may write it."""
    import os
    import pwd
    import stat

    def user(uid: int) -> str:
        try:
            return pwd.getpwuid(uid).pw_name
        except KeyError:
            return f"uid {uid}"

    try:
        status = path.stat()
    except OSError:
        return None  # absent: nothing to resume
    me = os.geteuid()
    if status.st_uid != me:
        return (f"{path}: owned by {user(status.st_uid)}, not by {user(me)} who runs the calibrator, so it is not "
                f"resumed; remove it, or make it {user(me)}'s: chown {user(me)} {path}")
    writable = [who for who, bit in (("its group", stat.S_IWGRP), ("others", stat.S_IWOTH)) if status.st_mode & bit]
    if writable:
        return (f"{path}: writable by {' and '.join(writable)}, so anyone may have written it and it is not "
                f"resumed; make it its owner's alone: chmod go-w {path}")
    return None


def load_state(path: Path | None, rig: Rig | None = None) -> CalibrationMessage | None:
    """The persisted calibration message, or None. A damaged file, or one of another rig than `rig`, is kept
    aside, never overwritten; one another user owns or may write is refused (InputError)."""
    if path is None or not path.exists():
        return None
    problem = untrusted_state(path)
    if problem is not None:
        raise InputError(problem)
    try:
        message = load_calibration_message(path)
    except InputError as exc:
        _set_aside(path, "damaged", str(exc))
        return None
    mismatch = calibration_mismatch(rig, message.calibration) if rig is not None else None
    if mismatch is not None:
        _set_aside(path, "other-rig", f"not a calibration of rig {rig.name!r}: {mismatch}")
        return None
    return message


def _set_aside(path: Path, why: str, reason: str) -> None:
    aside = path.with_name(path.name + f".{why}-{time.time_ns()}")
    path.rename(aside)
    log.warning("%s: cannot resume from it (%s); moved it to %s", path, reason, aside)


class CalibratorNode:
    """Zenoh side of the calibrator: subscribe, solve on a worker, publish, persist, answer."""

    def __init__(self, session, rig_name: str, config: CalibratorConfig = CalibratorConfig(), *,
                 viewer=None, lockstep: bool = False, rig: Rig | None = None) -> None:
        self.session = session
        self.lockstep = lockstep
        self.rig_name = keys.validate_id(rig_name, what="rig")
        # With the rig file, observations and a state file of other cameras, sizes or baseline are refused.
        self.rig = rig
        self.config = config
        self.viewer = viewer
        self.stop = threading.Event()
        self.tracker = Tracker(config.live)
        self.mailbox = LatestMessage()
        self.malformed = Tally(log)  # observations messages that do not parse, by kind
        self.failures = Tally(log)  # handlers that raised, by what and exception type
        self._solve = guarded(self.tracker.update, self.failures, "the solver")
        self.latest_doc: bytes | None = None
        self._meter = RateMeter(window_s=30.0)
        self._lock = threading.Lock()
        self._warned_s: dict[str, float] = {}  # outcome -> when it was last warned about
        # Cameras found moved (the tracker says so in one solve only) not yet named by a published calibration.
        self._moved_untold: set[str] = set()
        self._published_from: ObservationsMessage | None = None  # the observations of the last one published

    # ------------------------------------------------------------ bus callbacks

    def _on_observations(self, sample) -> None:
        payload = sample.payload.to_bytes()
        if len(payload) > MAX_MESSAGE_BYTES:
            self.malformed.count("too large", "dropping an observations message of %d bytes, more than %d",
                                 len(payload), MAX_MESSAGE_BYTES)
            return
        attachment = sample.attachment
        self.mailbox.put(payload, None if attachment is None else attachment.to_bytes())

    def _on_query(self, query) -> None:
        with self._lock:
            payload = self.latest_doc
        if payload is not None:
            query.reply(keys.calibration(self.rig_name), payload)

    # ------------------------------------------------------------ work

    def _decode(self, payload: bytes) -> ObservationsMessage | None:
        """The observations message of `payload`, or None (counted) where it is malformed or of another rig."""
        try:
            message = decode_observations_message(payload, max_tracks=MAX_TRACKS, subsample_seed=SUBSAMPLE_SEED)
        except MessageError as exc:
            self.malformed.count(exc.kind, "dropping malformed observations (%s)", exc)
            return None
        obs = message.observations
        mismatch = observations_mismatch(self.rig, obs) if self.rig is not None else None
        if mismatch is not None:
            self.malformed.count("other rig", "dropping observations that are not of rig %r: %s", self.rig_name,
                                 mismatch)
            return None
        if message.subsampled_from is not None:
            self.malformed.count("subsampled", "solving %d of the %d tracks of an observations message, drawn "
                                 "at random (at most %d per solve)", len(obs.track_ids), message.subsampled_from,
                                 MAX_TRACKS)
        return message

    def _publish(self, publisher, cal: Calibration, source: ObservationsMessage, outcome: Outcome, *,
                 solving_ns: int, received_ns: int | None) -> None:
        matched = source.latency_ns or latency.StageStamps()
        stamps = replace(matched, published_ns=source.published_ns, solving_ns=solving_ns, received_ns=received_ns)
        # The status is the verdict's level (camnet.solve.report.verdict): a poor result is published, never "good".
        message = CalibrationMessage(
            cal, rig=self.rig_name, solve=self.tracker.solves, status=judge(cal).level, warm_start=outcome.warm,
            moved=outcome.moved, solved_ns=latency.now_ns(), latest_capture_ns=source.latest_capture_ns,
            frame_sets=source.frame_sets, latency_ns=stamps)
        payload = encode_calibration_message(message)
        with self._lock:
            self.latest_doc = payload
        # The matcher forgets what it pooled of a moved camera (camnet.bus.moved), told once per move: not
        # the ones it found itself (forgotten again, their new views would be lost).
        publisher.put(payload, attachment=moved_attachment((self._moved_untold | set(outcome.moved))
                                                           - set(outcome.told)))
        self._moved_untold = set()
        self._published_from = source
        # Kept for a restart after it is published: writing it must not delay the rig's consumers.
        if self.config.state_path is not None:  # the rig's layout: not for every user
            write_json_atomic(self.config.state_path, calibration_message_to_doc(message), private=True)

    def handle(self, payload: bytes, publisher, *, received_ns: int | None = None,
               attachment: bytes | None = None) -> Outcome | None:
        """Solve one observations message (received at `received_ns`, Unix epoch; with the matcher's
        `attachment`, `camnet.bus.moved`) and publish what came of it."""
        return self._handle(payload, publisher, received_ns=received_ns, attachment=attachment)[1]

    def _handle(self, payload: bytes, publisher, *, received_ns: int | None,
                attachment: bytes | None) -> tuple[ObservationsMessage | None, Outcome | None]:
        """`handle`, and the message solved (None where it did not decode)."""
        solving_ns = latency.now_ns()
        message = self._decode(payload)
        if message is None:
            return None, None
        obs = message.observations
        try:
            forgotten = parse_forgotten_attachment(attachment)
        except InputError as exc:
            forgotten = None
            self.malformed.count("attachment", "ignoring an observations attachment (%s); is the matcher of "
                                 "another camnet version?", exc)
        outcome = self._solve(obs, source=message.pool_id, forgotten=forgotten, frame_sets=message.frame_sets)
        if outcome is None:
            self.tracker.counts["failed"] += 1
            return message, None
        self._meter.tick()
        if outcome.status == "good":
            self._publish(publisher, outcome.calibration, message, outcome, solving_ns=solving_ns,
                          received_ns=received_ns)
            cal = outcome.calibration
            left_out = cal.report.cameras_left_out if cal.report is not None else {}
            log.info("solve %d: good (%s, %.2f s): %d cameras, %d points, rms %.3f px, scale sigma %.3f%%%s",
                     self.tracker.solves, "warm" if outcome.warm else "cold", outcome.solve_s,
                     len(cal.cameras), len(cal.points), cal.rms_reprojection_px,
                     100 * scale_sigma_rel(cal), "".join(f"; {c} left out: {why}" for c, why in left_out.items()))
        else:
            self._moved_untold |= set(outcome.moved) - set(outcome.told)  # named by the next calibration published
            # A rig that keeps failing must not flood the console: its status line counts every one.
            now_s = time.monotonic()
            loud = now_s - self._warned_s.get(outcome.status, -WARNING_PERIOD_S) >= WARNING_PERIOD_S
            if loud:
                self._warned_s[outcome.status] = now_s
            log.log(logging.WARNING if loud else logging.INFO, "solve %d: %s, the last good calibration stays: "
                    "%s%s", self.tracker.solves, outcome.status, outcome.reason,
                    f" (further ones within {WARNING_PERIOD_S:.0f} s are only counted)" if loud else "")
        if self.viewer is not None:
            self.viewer.solved(outcome, message, solve=self.tracker.solves)
        return message, outcome

    def _activity(self) -> Activity:
        counts = self.tracker.counts
        good = self.tracker.good
        detail = (f"good {counts['good']}, rejected {counts['rejected']}, failed {counts['failed']}, "
                  f"malformed {self.malformed.total}")
        if good is not None:
            detail += f"; rms {good.rms_reprojection_px:.2f} px, {len(good.points)} points"
        return Activity(fps=round(self._meter.rate(), 3), frames=self.tracker.solves,
                        dropped=self.mailbox.superseded, detail=detail)

    def _resume(self, publisher) -> None:
        resumed = load_state(self.config.state_path, self.rig)
        if resumed is None:
            return
        self.tracker.good = resumed.calibration
        # Solves are numbered on from the resumed one, so that a number names one calibration.
        if resumed.solve is not None:
            self.tracker.solves = resumed.solve
        # The persisted message as it was published, its envelope (solve, status, ...) included.
        with self._lock:
            # Said so on the bus (not in the file): a listener tells it from a solve of this run.
            self.latest_doc = encode_calibration_message(replace(resumed, resumed=True))
        publisher.put(self.latest_doc)
        log.info("resumed from %s (%d cameras)", self.config.state_path, len(resumed.calibration.cameras))

    def _write_observations(self) -> None:
        """Write the observations behind the last calibration published (none: nothing), where the config says:
        the message that calibration names, as solved (camnet.io.run_dir.observations_behind reads it)."""
        path, source = self.config.observations_path, self._published_from
        if path is None or source is None:
            return
        try:
            write_json_atomic(path, observations_message_to_doc(source))
        except OSError as exc:
            log.warning("could not write the observations behind the last calibration to %s: %s", path,
                        exc.strerror or exc)

    def run(self) -> None:
        """Serve until `stop` is set (or SIGTERM, Ctrl-C)."""
        rig = self.rig_name
        # Its samples state their source, and its token names that source, so that the nodes reading calibrations
        # (and a supervisor) tell them from any other publisher's; declared before the first one is published.
        publisher = SourcedPublisher(self.session.declare_publisher(keys.calibration(rig)))
        token = declare_calibrator(self.session, rig)
        self._resume(publisher)
        queryable = self.session.declare_queryable(keys.calibration(rig),
                                                   guarded(self._on_query, self.failures, "answering a query"))
        subscriber = self.session.declare_subscriber(keys.observations(rig), self._on_observations)
        frames = (self.session.declare_subscriber(
            keys.all_frames(rig), guarded(self.viewer.on_frame, self.failures, "showing a frame"))
            if self.viewer is not None else None)
        ack_publisher = ack_token = None
        if self.lockstep:
            import zenoh

            ack_publisher = self.session.declare_publisher(keys.lockstep_ack(rig, NODE_KIND),
                                                           congestion_control=zenoh.CongestionControl.BLOCK)
            ack_token = declare_liveliness(self.session, keys.lockstep_ack(rig, NODE_KIND))
        presence = Presence(self.session, rig=rig, kind=NODE_KIND, node_id=NODE_KIND, report=self._activity,
                            tallies=(self.malformed, self.failures), period_s=self.config.stats_period_s,
                            counted="solves", dropped="observations superseded while solving",
                            trim_heap_period_s=heap.TRIM_PERIOD_S)
        try:
            with stop_on_signals(self.stop), presence:
                while not self.stop.is_set():
                    taken = self.mailbox.take(timeout_s=0.2)
                    if taken is not None:
                        payload, received_ns, attachment = taken
                        message, outcome = self._handle(payload, publisher, received_ns=received_ns,
                                                        attachment=attachment)
                        if ack_publisher is not None:
                            ack_publisher.put(_ack(message, outcome).to_json())
                    presence.publish_if_due()
        finally:
            subscriber.undeclare()
            self._write_observations()
            if frames is not None:
                frames.undeclare()
            queryable.undeclare()
            if ack_token is not None:
                ack_token.undeclare()
            token.undeclare()


def _ack(message: ObservationsMessage | None, outcome: Outcome | None) -> lockstep.Ack:
    """The lockstep ack of one observations message: the message it names (none where it did not decode),
    and what came of it."""
    status = outcome.status if outcome is not None else "not solved"
    if message is None:
        return lockstep.Ack(status=status)
    return lockstep.Ack(pool_id=message.pool_id, frame_sets=message.frame_sets, status=status)


class RerunView:
    """What the calibrator shows in Rerun: every solve, and with it the latest frame of each camera when
    `viz.FrameSchedule` says it is worth logging (every `frame_period_s` of capture time, 0: every solve).

    Frames are received only to be shown; they are logged at most at the solve rate.
    """

    def __init__(self, rec, *, truth=None, frame_period_s: float | None = None) -> None:
        from camnet import viz
        from camnet.bus.receiver import FrameReceiver

        self.rec = rec
        self.truth = truth
        self._receiver = FrameReceiver()
        self._frames: dict = {}
        self._lock = threading.Lock()
        self._schedule = viz.FrameSchedule(viz.FRAME_PERIOD_S if frame_period_s is None else frame_period_s)

    def on_frame(self, sample) -> None:
        frame = self._receiver.accept(sample.payload.to_bytes())
        if frame is not None:
            with self._lock:
                self._frames[frame.camera_id] = frame

    def solved(self, outcome: Outcome, message: ObservationsMessage, *, solve: int | None = None) -> None:
        """Show the solve of `message`; `solve` is its number as the calibrator publishes it (`solve` of the
        calibration)."""
        from camnet import viz

        obs = message.observations
        time_ns = message.latest_capture_ns or time.time_ns()
        with self._lock:
            frames = list(self._frames.values())
        for frame in frames:
            if self._schedule.take(frame.camera_id, time_ns, moved=frame.camera_id in outcome.moved):
                viz.log_frame(self.rec, frame.camera_id, frame.image, time_ns=time_ns, encoding=frame.encoding)
        if outcome.status == "good":
            viz.log_calibration(self.rec, outcome.calibration, time_ns=time_ns, observations=obs, truth=self.truth,
                                solve_index=solve)
        else:
            viz.log_solve_failure(self.rec, f"{outcome.status}: {outcome.reason}", time_ns=time_ns,
                                  solve_index=solve)
