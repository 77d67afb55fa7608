"""The calibrator node: observations in, a metric calibration out, kept current.

Every observations message (the matcher's pooled tracks, latest value only)
is solved by the engine, warm-started from the last good calibration. A
solve that fails or looks degenerate never replaces a good calibration; it
is counted and reported. Good calibrations are published on the rig's
calibration key, answered to late joiners by a queryable, and written
atomically to a state file from which a restarted calibrator resumes.

A moved camera (see camnet.change) is detected on the tracks that arrived
since the last solve; its older observations are then ignored (they
describe the old pose) and its pose is solved afresh. If a stereo camera, or
most of the rig, moved, the metric frame itself is gone: the calibrator
starts over from the new tracks alone.

With ``lockstep`` (`camnet.lockstep`) every observations message is
acknowledged once it has been solved and its result published, so that a
lockstep replay sends the next frame set only then.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from camnet import keys, lockstep
from camnet.bus import declare_liveliness
from camnet.calibrate import Options, calibrate
from camnet.camera import Camera
from camnet.change import MoveRule, drop_before, moved_cameras, new_track_errors
from camnet.errors import CamnetError, InputError
from camnet.formats import (
    Calibration,
    Observations,
    calibration_to_doc,
    load_json,
    parse_calibration,
    parse_observations,
    write_json_atomic,
)
from camnet.stats import NodeStats, RateMeter

log = logging.getLogger(__name__)

NODE_KIND = "calibrator"

# What a live rig estimates by default: focal lengths, poses and the pair's
# small misalignment. Principal points and distortion stay as given (image
# centre and none when nothing is given; the reported sigmas include what a
# guessed principal point may cost). On the simulated rigs' live tracks
# (thousands of points, 0.25 px RMS) the principal points are not determined
# (sigmas of thousands of pixels) and freeing k1, k2 beside the pair's yaw
# costs a factor of 5 in focal sigma and biased every focal length alike by
# 0.25%; with this set the focal errors stay within 0.15%. Lenses with
# visible distortion need their dist given, or
# `--free f,k1,k2,stereo_rotation,stereo_direction`.
LIVE_FREE = frozenset({"f", "stereo_rotation", "stereo_direction"})


@dataclass(frozen=True)
class CalibratorConfig:
    """How the calibrator solves and when it trusts a solution.

    A solution is good when it converged, its reprojection RMS is at most
    `max_rms_px`, its scale is known to `max_scale_rel` (1 sigma) and it holds
    every camera of the observations.
    """

    options: Options = Options(free=LIVE_FREE)
    state_path: Path | None = None
    move_rule: MoveRule = MoveRule()
    max_rms_px: float = 3.0
    max_scale_rel: float = 0.05
    stats_period_s: float = 1.0
    # A factory-calibrated stereo head (the rig file's stereo.R, stereo.t): the right camera's
    # pose in the left's frame, x_right = R x_left + t. Every solve without a good calibration
    # to start from starts from it, so that a free set without the pair's axes holds it.
    stereo_pose: tuple[np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class Outcome:
    """What one update did. `status` is "good", "rejected" or "failed"."""

    status: str
    reason: str
    calibration: Calibration | None = None
    moved: tuple[str, ...] = ()
    warm: bool = False
    solve_s: float = 0.0


def judge(cal: Calibration, obs: Observations, config: CalibratorConfig) -> str:
    """Why `cal` must not replace a good calibration, or "" if it may."""
    diagnostics = cal.extra.get("diagnostics", {})
    if not diagnostics.get("converged", False):
        return f"not converged ({diagnostics.get('reason', 'unknown')})"
    if not cal.rms_reprojection_px <= config.max_rms_px:
        return f"reprojection RMS {cal.rms_reprojection_px:.2f} px > {config.max_rms_px} px"
    scale_rel = cal.extra.get("uncertainty", {}).get("scale_rel")
    if scale_rel is None or not scale_rel <= config.max_scale_rel:
        return f"scale uncertain ({scale_rel} > {config.max_scale_rel})"
    missing = set(obs.camera_ids) - {c.id for c in cal.cameras}
    if missing:
        return f"cameras {sorted(missing)} not calibrated"
    return ""


@dataclass
class Tracker:
    """The calibrator's state between observations messages: no I/O, no bus.

    Track ids from one matcher increase with time, so the tracks newer than
    the last solve are those with larger ids. A matcher restart (a new
    `source`, or ids going back) makes the old points meaningless: the warm
    start then keeps the cameras only.
    """

    config: CalibratorConfig
    good: Calibration | None = None
    solves: int = 0
    counts: dict[str, int] = field(default_factory=lambda: {"good": 0, "rejected": 0, "failed": 0})
    _source: object = None
    _last_max_id: int = -1
    _cutoffs: dict[str, int] = field(default_factory=dict)
    _reset: set[str] = field(default_factory=set)
    _points_valid: bool = False

    def update(self, obs: Observations, *, source: object = None) -> Outcome:
        t0 = time.perf_counter()
        self.solves += 1
        max_id = int(obs.track_ids.max()) if len(obs.track_ids) else -1
        if source != self._source or max_id < self._last_max_id:
            if self._last_max_id >= 0:
                log.info("observations from a new matcher session: old points and cut-offs dropped")
            self._source, self._cutoffs, self._last_max_id = source, {}, -1
            self._points_valid = False
        moved = self._detect_moves(obs)
        self._last_max_id = max(self._last_max_id, max_id)
        solve_obs = drop_before(obs, self._cutoffs) if self._cutoffs else obs
        outcome = self._solve(solve_obs, moved)
        outcome = replace(outcome, solve_s=time.perf_counter() - t0)
        self.counts[outcome.status] += 1
        if outcome.status == "good":
            self.good = outcome.calibration
            self._reset.clear()
            self._points_valid = True
        return outcome

    def _detect_moves(self, obs: Observations) -> tuple[str, ...]:
        if self.good is None or not self._points_valid:
            return ()
        rows = np.flatnonzero(obs.track_ids > self._last_max_id)
        if not len(rows):
            return ()
        try:
            errors = new_track_errors(self.good, obs, rows)
        except (KeyError, ValueError) as exc:
            log.warning("cannot check for moved cameras: %s", exc)
            return ()
        reference = {cam_id: stats.get("rms_px")
                     for cam_id, stats in self.good.extra.get("diagnostics", {}).get("cameras", {}).items()}
        moved = [c for c in moved_cameras(errors, reference, self.config.move_rule) if c not in self._reset]
        if not moved:
            return ()
        first_new = int(obs.track_ids[rows].min())
        stereo = {obs.stereo.left, obs.stereo.right}
        if stereo & set(moved) or 2 * len(moved) > len(obs.cameras):
            log.warning("cameras %s moved, the stereo pair among them or most of the rig: "
                        "calibrating afresh from the new tracks", moved)
            self._cutoffs = {cam_id: first_new for cam_id in obs.camera_ids}
            self._reset = set(obs.camera_ids)
        else:
            log.warning("camera(s) %s moved: re-calibrating them from the new tracks", moved)
            for cam_id in moved:
                self._cutoffs[cam_id] = first_new
            self._reset |= set(moved)
        return tuple(moved)

    def _initial(self) -> Calibration | None:
        """The warm start: the last good calibration (its points only while they mean the same tracks)."""
        if self.good is None or len(self._reset) == len(self.good.cameras):
            return None
        if self._points_valid:
            return self.good
        return replace(self.good, point_ids=np.empty(0, dtype=np.int64), points=np.empty((0, 3)))

    def _solve(self, obs: Observations, moved: tuple[str, ...]) -> Outcome:
        initial = self._initial()
        cold = None if self.config.stereo_pose is None else stereo_head(obs, *self.config.stereo_pose)
        attempts = [initial, cold] if initial is not None else [cold]
        reason = ""
        for start in attempts:
            try:
                reset = self._reset if start is not None else ()
                cal = calibrate(obs, self.config.options, initial=start, reset_cameras=reset).calibration
            except CamnetError as exc:
                reason = f"solve failed: {exc}"
                status = "failed"
                continue
            reason = judge(cal, obs, self.config)
            if not reason:
                return Outcome("good", "", cal, moved, warm=start is not None)
            status = "rejected"
        return Outcome(status, reason, None, moved, warm=False)


def stereo_head(obs: Observations, R: np.ndarray, t: np.ndarray) -> Calibration | None:
    """The stereo pair alone, with its known pose and the observations' K and dist: a solve's start.

    None when the observations carry no K for a stereo camera (the rig file
    requires one wherever it gives the pose).
    """
    cameras = []
    for cam_id, (R_cam, t_cam) in ((obs.stereo.left, (np.eye(3), np.zeros(3))), (obs.stereo.right, (R, t))):
        info = obs.cameras[obs.index_of(cam_id)]
        if info.K is None:
            return None
        dist = np.zeros(5) if info.dist is None else info.dist
        cameras.append(Camera(cam_id, info.width, info.height, info.K, dist, R_cam, t_cam))
    return Calibration(cameras=cameras, point_ids=np.empty(0, dtype=np.int64), points=np.empty((0, 3)),
                       rms_reprojection_px=float("nan"), world_frame=obs.stereo.left)


class LatestMessage:
    """A one-slot mailbox: the newest payload wins, superseded ones are counted."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._payload: bytes | None = None
        self.superseded = 0

    def put(self, payload: bytes) -> None:
        with self._ready:
            if self._payload is not None:
                self.superseded += 1
            self._payload = payload
            self._ready.notify()

    def take(self, *, timeout_s: float) -> bytes | None:
        with self._ready:
            if not self._ready.wait_for(lambda: self._payload is not None, timeout=timeout_s):
                return None
            payload, self._payload = self._payload, None
            return payload


def load_state(path: Path | None) -> Calibration | None:
    """The persisted calibration, or None. A damaged file is kept aside, never overwritten."""
    if path is None or not path.exists():
        return None
    try:
        return parse_calibration(load_json(path))
    except InputError as exc:
        aside = path.with_name(path.name + f".damaged-{time.time_ns()}")
        path.rename(aside)
        log.warning("%s: cannot resume from it (%s); moved it to %s", path, exc, aside)
        return None


class CalibratorNode:
    """Zenoh side of the calibrator: subscribe, solve on a worker, publish, persist, answer."""

    def __init__(self, session, rig_name: str, config: CalibratorConfig = CalibratorConfig(), *,
                 viewer=None, lockstep: bool = False) -> None:
        self.session = session
        self.lockstep = lockstep
        self.rig_name = keys.validate_id(rig_name, what="rig")
        self.config = config
        self.viewer = viewer
        self.tracker = Tracker(config)
        self.mailbox = LatestMessage()
        self.malformed: dict[str, int] = {}
        self._unexpected: set[str] = set()
        self.latest_doc: bytes | None = None
        self._meter = RateMeter(window_s=30.0)
        self._lock = threading.Lock()

    # ------------------------------------------------------------ bus callbacks

    def _on_observations(self, sample) -> None:
        self.mailbox.put(sample.payload.to_bytes())

    def _on_query(self, query) -> None:
        with self._lock:
            payload = self.latest_doc
        if payload is not None:
            query.reply(keys.calibration(self.rig_name), payload)

    # ------------------------------------------------------------ work

    def _count_malformed(self, kind: str, message: str) -> None:
        first = kind not in self.malformed
        self.malformed[kind] = self.malformed.get(kind, 0) + 1
        if first:
            log.warning("dropping malformed observations (%s); further ones of this kind are only counted", message)

    def _parse(self, payload: bytes) -> tuple[Observations, dict] | None:
        try:
            doc = json.loads(payload)
        except ValueError as exc:
            self._count_malformed("json", f"not JSON: {exc}")
            return None
        try:
            return parse_observations(doc), doc
        except InputError as exc:
            self._count_malformed(str(exc).split(":", 1)[0], str(exc))
            return None

    def _publish(self, publisher, cal: Calibration, doc_in: dict, outcome: Outcome) -> None:
        doc = calibration_to_doc(cal)
        doc.update({"rig": self.rig_name, "solve": self.tracker.solves, "status": "good",
                    "warm_start": outcome.warm, "moved": list(outcome.moved), "solved_ns": time.time_ns()})
        for key in ("latest_capture_ns", "frame_sets"):
            if key in doc_in:
                doc[key] = doc_in[key]
        payload = json.dumps(doc, allow_nan=False).encode()
        if self.config.state_path is not None:
            write_json_atomic(self.config.state_path, doc)
        with self._lock:
            self.latest_doc = payload
        publisher.put(payload)

    def handle(self, payload: bytes, publisher) -> Outcome | None:
        """Solve one observations message and publish what came of it."""
        parsed = self._parse(payload)
        if parsed is None:
            return None
        obs, doc = parsed
        try:
            outcome = self.tracker.update(obs, source=doc.get("pool_id"))
        except Exception as exc:  # noqa: BLE001 (a bug met by one message must not stop the node)
            self.tracker.counts["failed"] += 1
            if type(exc).__name__ not in self._unexpected:
                self._unexpected.add(type(exc).__name__)
                log.exception("solve %d: the solver failed unexpectedly; such failures are counted "
                              "as failed solves from now on", self.tracker.solves)
            return None
        self._meter.tick()
        if outcome.status == "good":
            self._publish(publisher, outcome.calibration, doc, outcome)
            cal = outcome.calibration
            log.info("solve %d: good (%s, %.2f s): %d cameras, %d points, rms %.3f px, scale sigma %.3f%%",
                     self.tracker.solves, "warm" if outcome.warm else "cold", outcome.solve_s,
                     len(cal.cameras), len(cal.points), cal.rms_reprojection_px,
                     100 * cal.extra.get("uncertainty", {}).get("scale_rel", float("nan")))
        else:
            log.warning("solve %d: %s, the last good calibration stays: %s", self.tracker.solves,
                        outcome.status, outcome.reason)
        if self.viewer is not None:
            self.viewer.solved(outcome, obs, doc)
        return outcome

    def _stats(self) -> NodeStats:
        counts = self.tracker.counts
        good = self.tracker.good
        detail = (f"good {counts['good']}, rejected {counts['rejected']}, failed {counts['failed']}, "
                  f"malformed {sum(self.malformed.values())}")
        if good is not None:
            detail += f"; rms {good.rms_reprojection_px:.2f} px, {len(good.points)} points"
        return NodeStats(rig=self.rig_name, kind=NODE_KIND, node_id=NODE_KIND,
                         fps=round(self._meter.rate(), 3), frames=self.tracker.solves,
                         dropped=self.mailbox.superseded, timestamp_ns=time.time_ns(), detail=detail)

    def run(self, stop: threading.Event) -> None:
        """Serve until `stop` is set."""
        rig = self.rig_name
        publisher = self.session.declare_publisher(keys.calibration(rig))
        stats_publisher = self.session.declare_publisher(keys.node_stats(rig, NODE_KIND, NODE_KIND))
        resumed = load_state(self.config.state_path)
        if resumed is not None:
            self.tracker.good = resumed
            with self._lock:
                self.latest_doc = json.dumps(calibration_to_doc(resumed), allow_nan=False).encode()
            publisher.put(self.latest_doc)
            log.info("resumed from %s (%d cameras)", self.config.state_path, len(resumed.cameras))
        queryable = self.session.declare_queryable(keys.calibration(rig), self._on_query)
        subscriber = self.session.declare_subscriber(keys.observations(rig), self._on_observations)
        frames = (self.session.declare_subscriber(keys.all_frames(rig), self.viewer.on_frame)
                  if self.viewer is not None else None)
        ack_publisher = ack_token = None
        if self.lockstep:
            import zenoh

            ack_publisher = self.session.declare_publisher(keys.lockstep_ack(rig, NODE_KIND),
                                                           congestion_control=zenoh.CongestionControl.BLOCK)
            ack_token = declare_liveliness(self.session, keys.lockstep_ack(rig, NODE_KIND))
        token = declare_liveliness(self.session, keys.node(rig, NODE_KIND, NODE_KIND))
        next_stats = 0.0
        try:
            while not stop.is_set():
                payload = self.mailbox.take(timeout_s=0.2)
                if payload is not None:
                    outcome = self.handle(payload, publisher)
                    if ack_publisher is not None:
                        status = outcome.status if outcome is not None else "not solved"
                        ack_publisher.put(lockstep.Ack.for_observations(payload, status=status).to_json())
                if time.monotonic() >= next_stats:
                    stats_publisher.put(self._stats().to_json())
                    next_stats = time.monotonic() + self.config.stats_period_s
        finally:
            stats_publisher.put(self._stats().to_json())
            subscriber.undeclare()
            if frames is not None:
                frames.undeclare()
            queryable.undeclare()
            if ack_token is not None:
                ack_token.undeclare()
            token.undeclare()


class RerunView:
    """What the calibrator shows in Rerun: every solve, and the latest frame of each camera with it.

    Frames are received only to be shown; they are logged at the solve rate.
    """

    def __init__(self, rec, *, truth=None) -> None:
        from camnet.receiver import FrameReceiver

        self.rec = rec
        self.truth = truth
        self._receiver = FrameReceiver()
        self._frames: dict = {}
        self._lock = threading.Lock()

    def on_frame(self, sample) -> None:
        frame = self._receiver.accept(sample.payload.to_bytes())
        if frame is not None:
            with self._lock:
                self._frames[frame.camera_id] = frame

    def solved(self, outcome: Outcome, obs: Observations, doc: dict) -> None:
        from camnet import viz

        time_ns = int(doc.get("latest_capture_ns") or time.time_ns())
        with self._lock:
            frames = list(self._frames.values())
        for frame in frames:
            viz.log_frame(self.rec, frame.camera_id, frame.image, time_ns=time_ns, encoding=frame.encoding)
        if outcome.status == "good":
            viz.log_calibration(self.rec, outcome.calibration, time_ns=time_ns, observations=obs, truth=self.truth)
        else:
            viz.log_solve_failure(self.rec, f"{outcome.status}: {outcome.reason}", time_ns=time_ns)
