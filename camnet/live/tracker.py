"""The live calibrator's state between solves: what it solves next, and from where.

No I/O and no bus: the calibrator node feeds observations in and publishes
what comes out. Each observations message (the matcher's pooled tracks) is
solved warm from the last good calibration; a moved camera (see
`camnet.live.moved_cameras`) is detected on the tracks that arrived since, its
older observations are dropped and its pose solved afresh. Only evidence a
static rig cannot produce declares a move (`MoveRule`): its views off its pose
while its neighbours' stay on theirs, explained by one new placement, over
several frame sets; until then it is a suspicion, and the camera keeps its
pose, its evidence, and the matcher its views. If a stereo
camera, or most of the rig, moved, the metric frame itself is gone and the
solve starts over from the new tracks alone. Whether a solve may replace the
last good one is the live policy's (camnet.live.policy).

A matcher that says which cameras' views it forgot (`camnet.bus.moved`) is
heard: a camera found moved here is left out, by name, until the matcher's
pool holds its views afresh (those since the move were judged against its
old epipolar geometry, and the few kept can fit a wrong pose well:
docs/benchmarks.md, "A moved camera"), then placed again from those alone;
one the matcher found moved first is placed again from its views since.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial

import cv2
import numpy as np

from camnet.errors import in_words
from camnet.live.held_world import held_floor, scale_apart
from camnet.live.judged_solve import Judged, Status, solve_judged
from camnet.live.moved_cameras import MoveEvidence, drop_before, move_evidence, off_their_pose
from camnet.live.newest_first import solve_newest_first
from camnet.live.policy import LiveConfig, policy_check
from camnet.model.calibration import Calibration, HalvesCheck, LensShift, PairPoseCheck
from camnet.model.camera import Camera
from camnet.model.observations import Observations
from camnet.solve import Options, calibrate, solved_from
from camnet.solve.halves import with_check_carried, with_halves_check
from camnet.solve.lens_check import with_lens_carried, with_lens_check
from camnet.solve.pair_check import with_pair_check, with_pairs_carried

log = logging.getLogger(__name__)

# A second opinion is asked afresh once this share of the pool is newer than the last one saw: in between, the
# last one's half-differences are carried (a check costs two cold solves of half the pool).
HALVES_TURNOVER = 0.5
# A pool grown to this many times the one the last check saw is asked afresh, however recent the check: a
# rig's first pools are a few frame sets, whose halves are weak and whose check says little of the pool after.
HALVES_GROWTH = 2.0
# Each half of a live check keeps at most this many tracks: a check of a long pool holds up the calibrations
# no longer than a cold solve of this size.
HALVES_MAX_TRACKS = 600
# A suspected move's newest views, off its pose or on, count where there are this many (the fewest a pose needs).
NEWEST_MIN_VIEWS = 6
MOVED_RMS_FACTOR = 2.0  # a moved camera placed again fits its new views within this times its RMS before
NOT_FORGOTTEN_YET = ("moved, not placed again yet (the matcher has not pooled its views afresh: those since the move "
                     "were judged against its old geometry, and the few kept may fit a wrong pose); its new tracks "
                     "will place it (if it stays so, restart the matcher)")


@dataclass(frozen=True)
class Outcome:
    """What one update did."""

    status: Status
    reason: str
    calibration: Calibration | None = None
    moved: tuple[str, ...] = ()
    told: tuple[str, ...] = ()  # of `moved`, those the matcher found moved (and forgot) itself
    warm: bool = False
    solve_s: float = 0.0


@dataclass
class Tracker:
    """The calibrator's state between observations messages: no I/O, no bus.

    Track ids from one matcher increase with time, so the tracks newer than
    the last solve are those with larger ids. A matcher restart (a new
    `source`, or ids going back) makes the old points meaningless: the warm
    start then keeps the cameras only.
    """

    config: LiveConfig
    good: Calibration | None = None
    solves: int = 0
    counts: dict[Status, int] = field(default_factory=lambda: {status: 0 for status in Status})
    _source: object = None
    _last_max_id: int = -1
    _cutoffs: dict[str, int] = field(default_factory=dict)
    _reset: set[str] = field(default_factory=set)
    _points_valid: bool = False
    # Moved cameras (not the stereo pair) not yet placed again: as last calibrated, with their RMS (px) then.
    _pending: dict[str, tuple[Camera, float | None]] = field(default_factory=dict)
    # The matcher's word (`camnet.bus.moved`): per camera, the first track id it pooled since forgetting its
    # views; None while its messages say nothing of it.
    _forgotten: dict[str, int] | None = None
    # Moved cameras (found here) whose views the matcher has not forgotten since: left out, not placed again.
    _awaiting: set[str] = field(default_factory=set)
    # The last second opinion (camnet.solve.halves) and the newest track id it saw.
    _halves: HalvesCheck | None = None
    _halves_max_id: int = -1
    _halves_tracks: int = 0  # the pool's tracks it saw
    _halves_at_s: float = -np.inf
    _pairs: tuple[PairPoseCheck, ...] = ()  # the pair checks made with the last second opinion
    _lens: Mapping[str, LensShift] | None = None  # and the lens check (camnet.solve.lens_check)
    # Per camera, how many suspected moves were not confirmed (`_not_confirmed`).
    not_confirmed: dict[str, int] = field(default_factory=dict)
    # Suspected moves (`_persisted`): per camera, the first track id of its views off its pose, and how many frame
    # sets' newest views have said so.
    _suspects: dict[str, tuple[int, int]] = field(default_factory=dict)
    _frame_sets: int | None = None  # the count of frame sets pooled, as the last observations said

    @property
    def _options(self) -> Options:
        """The options of every solve here: the second opinion is asked once a good solve stands (`_second_opinion`)."""
        return replace(self.config.options, halves=False)

    def update(self, obs: Observations, *, source: object = None, forgotten: Mapping[str, int] | None = None,
               frame_sets: int | None = None) -> Outcome:
        """Solve `obs` (from matcher session `source`; `forgotten`: the matcher's first track id pooled since
        it forgot each camera's views, None where it does not say; `frame_sets`: how many frame sets its pool
        holds, None where it does not say) warm from the last good calibration."""
        t0 = time.perf_counter()
        self.solves += 1
        max_id = int(obs.track_ids.max()) if len(obs.track_ids) else -1
        if source != self._source or max_id < self._last_max_id:
            if self._last_max_id >= 0:
                log.info("observations from a new matcher session: old points and cut-offs dropped")
            self._source, self._cutoffs, self._last_max_id = source, {}, -1
            self._points_valid, self._forgotten, self._awaiting = False, None, set()
            self._suspects, self._frame_sets = {}, None
        told = self._told(obs, forgotten)
        before_moves = self._move_state()
        found = self._detect_moves(obs, awaits=forgotten is not None, frame_sets=frame_sets)
        moved = tuple(sorted({*found, *told}))
        self._last_max_id = max(self._last_max_id, max_id)
        self._frame_sets = frame_sets
        solve_obs = drop_before(obs, self._cutoffs) if self._cutoffs else obs
        outcome = self._solve(solve_obs, moved)
        apart = self._scale_apart(obs, outcome, found, moved)
        if apart:
            outcome = Outcome(Status.REJECTED, apart, None, moved)
        if found and outcome.status != Status.GOOD:
            # The moves found here placed nothing better than the last good calibration: its evidence stays.
            log.warning("camera(s) %s taken for moved, but no solve without their views before stands (%s): "
                        "their evidence kept", list(found), outcome.reason)
            self._cutoffs, self._reset, self._pending, self._awaiting = before_moves
            for cam_id in found:
                self.not_confirmed[cam_id] = self.not_confirmed.get(cam_id, 0) + 1
            moved = told
            solve_obs = drop_before(obs, self._cutoffs) if self._cutoffs else obs
            outcome = self._solve(solve_obs, moved)
            if apart and outcome.calibration is not None:
                said = f"{in_words(list(found), noun='camera')} moved, not placed again: {apart}"
                outcome = replace(outcome, calibration=outcome.calibration.warned(said))
        outcome = replace(outcome, told=told, solve_s=time.perf_counter() - t0)
        self.counts[outcome.status] += 1
        if outcome.status == Status.GOOD:
            checked = self._second_opinion(solve_obs, outcome.calibration, warm=outcome.warm)
            outcome = replace(outcome, calibration=self._world_held(checked, moved),
                              solve_s=time.perf_counter() - t0)
            self.good = outcome.calibration
            # A moved camera left out stays to be placed again (by the checked warm path, with its lens).
            placed = {c.id for c in self.good.cameras}
            self._pending = {c: moved_from for c, moved_from in self._pending.items() if c not in placed}
            self._reset = set(self._pending)
            self._points_valid = True
        return outcome

    def _second_opinion(self, obs: Observations, cal: Calibration, *, warm: bool) -> Calibration:
        """`cal` with the halves check and the pair check (camnet.solve.pair_check): asked afresh where at least
        HALVES_TURNOVER of the pool is newer than the last check saw (the first time, and after a move) and
        `halves_interval_s` have passed since or the pool has grown HALVES_GROWTH times, else the last checks
        carried over. Asked afresh, a `warm` solve is first solved on with the free rule tried again
        (`_freed_again`)."""
        if not self.config.options.halves:
            return cal
        turnover = float(np.mean(obs.track_ids > self._halves_max_id)) if len(obs.track_ids) else 0.0
        recent = time.monotonic() - self._halves_at_s < self.config.halves_interval_s
        grown = len(obs.track_ids) >= HALVES_GROWTH * self._halves_tracks
        if self._halves is not None and (turnover < HALVES_TURNOVER or (recent and not grown)):
            return with_lens_carried(with_pairs_carried(with_check_carried(cal, self._halves), self._pairs),
                                     self._lens)
        if warm:
            cal = self._freed_again(obs, cal)
        cold = self._options
        cal = with_halves_check(obs, cal, lambda half: calibrate(half, cold).calibration,
                                truncation_px=cold.truncation_px(cal.rms_reprojection_px),
                                max_half_tracks=HALVES_MAX_TRACKS, polish=lambda half, start: solved_from(
                                    half, cold, start))
        cal = with_lens_check(obs, with_pair_check(obs, cal), self.config.options, solved_from)
        self._halves, self._halves_max_id = cal.report.halves, int(obs.track_ids.max())
        self._halves_tracks = len(obs.track_ids)
        self._pairs, self._lens = cal.report.pair_checks, cal.report.lens_shifts
        self._halves_at_s = time.monotonic()
        return cal

    def _scale_apart(self, obs: Observations, outcome: Outcome, found: tuple[str, ...],
                     moved: tuple[str, ...]) -> str:
        """Why a good solve after a stereo camera was found moved cannot stand (camnet.live.held_world.scale_apart:
        its scale, from the pair's known distance, against the cameras that stayed), "" where it can."""
        if outcome.status != Status.GOOD or self.good is None or not {obs.stereo.left, obs.stereo.right} & set(found):
            return ""
        return scale_apart(self.good, outcome.calibration, self._still(obs.camera_ids, moved))

    def _still(self, cameras: Sequence[str], moved: tuple[str, ...]) -> set[str]:
        """Of `cameras`, those that stayed put: not `moved` by this update, nor still to be placed after a move."""
        return set(cameras) - set(moved) - set(self._pending)

    def _world_held(self, cal: Calibration, moved: tuple[str, ...]) -> Calibration:
        """`cal` with the last good calibration's floor frame held, carried through the cameras that stayed
        (camnet.live.held_world), where its floor has not moved beyond its sigmas; set anew and said so where it
        has."""
        if self.good is None or cal.floor_frame is None:
            return cal
        frame, said = held_floor(self.good, cal, self._still([c.id for c in cal.cameras], moved))
        if not said:
            unseen = cal.floor_frame.reason if frame.found and not cal.floor_frame.found else ""
            if unseen and cal.report is not None:  # held through a solve that saw no floor: its warning is moot
                cal = replace(cal, report=replace(cal.report, warnings=tuple(
                    w for w in cal.report.warnings if w != unseen)))
            return replace(cal, floor_frame=frame)
        log.info("%s", said)
        return replace(cal, floor_frame=frame).warned(said)

    def _waiting(self, obs: Observations) -> dict[str, str]:
        """The cameras of `obs` left out until the matcher has forgotten their views, with why."""
        return {c: NOT_FORGOTTEN_YET for c in sorted(self._awaiting) if c in obs.camera_ids}

    def _freed_again(self, obs: Observations, cal: Calibration) -> Calibration:
        """`cal` solved on with the automatic rule tried again (Options.free_again), where that is good: a warm
        solve keeps the free set of the first, and a pool that has grown since may determine more of a lens."""
        if self.config.options.free != "auto":
            return cal
        waiting = self._waiting(obs)
        again = solve_judged(obs, cal, options=replace(self._options, free_again=True),
                             check=partial(policy_check, config=self.config), leave_out=waiting)
        return again.calibration if again.status == Status.GOOD else cal

    def _move_state(self) -> tuple[dict[str, int], set[str], dict[str, tuple[Camera, float | None]], set[str]]:
        """Copies of what a move found changes: the cut-offs, the cameras reset, pending and awaited."""
        return dict(self._cutoffs), set(self._reset), dict(self._pending), set(self._awaiting)

    def _told(self, obs: Observations, forgotten: Mapping[str, int] | None) -> tuple[str, ...]:
        """The cameras the matcher forgot since its last message: each is placed again from the tracks it pooled
        since (its cut-off), no longer awaited; those not yet known moved here are returned, taken for moved.
        A stereo camera's move is left to `_detect_moves` (the metric frame goes with it); a matcher's first
        message only gives cut-offs (what it forgot before, a calibration resumed may already hold)."""
        if forgotten is None:
            return ()
        known, self._forgotten = self._forgotten, dict(forgotten)
        news = {c: first for c, first in forgotten.items() if (known or {}).get(c) != first
                and c in obs.camera_ids and c not in {obs.stereo.left, obs.stereo.right}}
        calibrated = {c.id: c for c in self.good.cameras} if self.good is not None and known is not None else {}
        stats = self.good.report.cameras if self.good is not None and self.good.report is not None else {}
        told = []
        for cam_id, first in news.items():
            self._cutoffs[cam_id] = first
            self._awaiting.discard(cam_id)
            if cam_id in calibrated and cam_id not in self._reset:
                self._pending[cam_id] = (calibrated[cam_id], stats[cam_id].rms_px if cam_id in stats else None)
                self._reset.add(cam_id)
                told.append(cam_id)
        if told:
            log.warning("camera(s) %s moved (the matcher found them off their pairs' geometry): re-calibrating "
                        "them from the tracks it pooled since", told)
        return tuple(sorted(told))

    def _detect_moves(self, obs: Observations, *, awaits: bool = False,
                      frame_sets: int | None = None) -> tuple[str, ...]:
        """The cameras the tracks since the last solve (and those since a suspected move began) find moved
        (`MoveRule`, over `frame_sets`: `_persisted`); with `awaits`, one not the stereo pair's is left out until
        the matcher says it forgot its views (`_told`)."""
        if self.good is None or not self._points_valid:
            return ()
        rows = np.flatnonzero(obs.track_ids > self._last_max_id)
        if not len(rows):
            return ()
        stats = self.good.report.cameras if self.good.report is not None else {}
        reference = {cam_id: camera.rms_px for cam_id, camera in stats.items()}
        rule = self.config.move_rule
        first_new = int(obs.track_ids[rows].min())
        since = {c: first for c, (first, _) in self._suspects.items()}
        judged = np.flatnonzero(obs.track_ids >= min([first_new, *since.values()]))
        try:
            evidence = move_evidence(self.good, obs, judged, reference, rule, since=since, newest_from=first_new,
                                     partners={obs.stereo.left: obs.stereo.right, obs.stereo.right: obs.stereo.left})
        except (KeyError, ValueError, cv2.error) as exc:
            log.warning("cannot check for moved cameras: %s", exc)
            return ()
        moved = []
        for cam_id, e in sorted(evidence.items()):
            if cam_id in self._reset:
                continue
            newest_on = e.newest_views >= NEWEST_MIN_VIEWS and not e.newest_off_px > e.limit_px
            if cam_id in self._suspects and newest_on or not e.moved and (e.off_pose or cam_id in self._suspects):
                self._not_confirmed(cam_id, e)
            elif e.moved and self._persisted(cam_id, e, frame_sets):
                moved.append(cam_id)
        if not moved:
            return ()
        stereo = {obs.stereo.left, obs.stereo.right}
        if stereo & set(moved) or 2 * len(moved) > len(obs.cameras):
            log.warning("cameras %s moved, the stereo pair among them or most of the rig: "
                        "calibrating afresh from the new tracks", moved)
            # From where the first of them left its pose: a suspected move's tracks since are of the new rig.
            since = min(evidence[cam_id].first_track_id for cam_id in moved)
            self._cutoffs = {cam_id: since for cam_id in obs.camera_ids}
            self._reset, self._pending = set(obs.camera_ids), {}
        else:
            log.warning("camera(s) %s moved: re-calibrating them from the new tracks", moved)
            calibrated = {c.id: c for c in self.good.cameras}
            for cam_id in moved:
                self._pending[cam_id] = (calibrated[cam_id], reference.get(cam_id))
                # Not `first_new`: the tracks pooled since the last solve may begin before the move.
                self._cutoffs[cam_id] = evidence[cam_id].first_track_id
            self._reset |= set(moved)
            if awaits:
                self._awaiting |= set(moved)
        for cam_id in moved:
            self._suspects.pop(cam_id, None)
        return tuple(moved)

    def _persisted(self, cam_id: str, evidence: MoveEvidence, frame_sets: int | None) -> bool:
        """Whether a camera whose views say it moved (`MoveEvidence.moved`) has said so in the newest views of
        as many frame sets as `MoveRule.frame_sets` asks: a suspicion begins where it has not yet. Observations
        that do not say how many frame sets they pool are judged on one message."""
        if frame_sets is None:
            return True
        added = max(frame_sets - self._frame_sets, 1) if self._frame_sets is not None else 1
        if cam_id not in self._suspects:
            self._suspects[cam_id] = (evidence.first_track_id, 0)
            log.info("camera %s suspected moved: its views lie a median %.1f px off its pose; a move once they "
                     "do over %d frame sets", cam_id, evidence.off_pose_px, self.config.move_rule.frame_sets)
        first, seen = self._suspects[cam_id]
        if evidence.newest_views >= NEWEST_MIN_VIEWS:  # the newest frame sets' views are off it too
            seen += added
        self._suspects[cam_id] = (first, seen)
        return seen >= self.config.move_rule.frame_sets

    def _not_confirmed(self, cam_id: str, evidence: MoveEvidence) -> None:
        """A camera off its pose where no one new placement explains its views, or one suspected whose views lie
        on its pose again: no move. Its pose and evidence stay, and the matcher keeps its views."""
        self._suspects.pop(cam_id, None)
        self.not_confirmed[cam_id] = self.not_confirmed.get(cam_id, 0) + 1
        if evidence.off_pose:
            log.info("camera %s suspected moved, not confirmed: its views lie a median %.1f px off its pose, and "
                     "%.1f px off the one new placement that fits them best", cam_id, evidence.off_pose_px,
                     evidence.replaced_px)
        else:
            log.info("camera %s suspected moved, not confirmed: its views lie on its pose again", cam_id)

    def _moved_unplaced(self, obs: Observations, warm: Judged) -> dict[str, str]:
        """The moved cameras the warm solve that places them again did not place, each with why: all of
        them where it failed, those its good solution holds off their new tracks' views (a camera solved
        back at its old pose) where it passed; {} where none moved, or the stereo pair did."""
        moved = sorted(self._reset & set(obs.camera_ids))
        if not moved or {obs.stereo.left, obs.stereo.right} & self._reset:
            return {}
        if warm.status == Status.FAILED:
            why = warm.reason.removeprefix("solve failed: ")
            return {cam_id: f"moved, not placed again yet ({why}); its new tracks will place it" for cam_id in moved}
        if warm.status != Status.GOOD:
            return {}
        rule, stats = self.config.move_rule, warm.calibration.report.cameras
        before = {c: self._pending[c][1] if c in self._pending else None for c in moved}
        limits = {c: rule.limit_px(before[c]) for c in moved}
        off = off_their_pose(warm.calibration, obs, {c: self._cutoffs[c] for c in moved if c in self._cutoffs},
                             limits, min_observations=rule.min_observations,
                             neighbour_limits_px={c: rule.neighbour_share * rule.limit_px(s.rms_px)
                                                  for c, s in stats.items()})
        unplaced = {c: f"moved, not placed again yet (its views since the move lie a median {px:.1f} px off the "
                    f"pose solved for it, more than {limits[c]:.1f}); its new tracks will place it"
                    for c, px in off.items()}
        for c in moved:
            rms_px = stats[c].rms_px if c in stats else None
            # Placed wrong, its new views fit the pose worse than its old ones fitted the old, while its sigma
            # can still look small: the RMS tells (docs/benchmarks.md, "Evidence behind the solver's thresholds").
            if c not in unplaced and rms_px is not None and before[c] and rms_px > MOVED_RMS_FACTOR * before[c]:
                unplaced[c] = (f"moved, not placed again yet (its views since the move fit the pose solved at RMS "
                               f"{rms_px:.2f} px, over {MOVED_RMS_FACTOR:g} times its {before[c]:.2f} px before); "
                               "its new tracks will place it")
        return unplaced

    def _lens_held(self, obs: Observations) -> Observations:
        """`obs` with the lens of each moved camera (K, dist) held as last calibrated, while it is placed again.

        A bump moves a camera, not its lens. Placed on its few new tracks with its focal length free, it could
        trade distance for focal length (a dolly zoom; docs/benchmarks.md, "Evidence behind the solver's
        thresholds").
        """
        calibrated = {c: camera for c, (camera, _) in self._pending.items() if c in self._reset}
        return replace(obs, cameras=tuple(
            replace(info, K=calibrated[info.id].K, dist=calibrated[info.id].dist, fixed=info.fixed | {"K", "dist"})
            if info.id in calibrated and info.model == calibrated[info.id].model else info for info in obs.cameras))

    def _lens_freed(self, obs: Observations, placed: Judged,
                    waiting: Mapping[str, str]) -> tuple[Calibration | None, dict[str, str]]:
        """`placed` (good, moved cameras placed again with their lens held, `_lens_held`) solved on with every
        lens free; (that calibration, {}) where it is good and still places them on their new views, else
        (None, the moved cameras with why).

        Held, a lens counts as known exactly and the sigmas are too small (docs/benchmarks.md, "A moved
        camera").
        """
        held = {c for c, (camera, _) in self._pending.items() if c in self._reset and camera.model
                == obs.cameras[obs.index_of(c)].model} & {c.id for c in placed.calibration.cameras}
        if not held:
            return placed.calibration, {}
        free = solve_judged(obs, placed.calibration, options=self._options,
                            check=partial(policy_check, config=self.config), leave_out=waiting)
        unplaced = self._moved_unplaced(obs, free)
        if free.status == Status.GOOD and not set(unplaced) - set(waiting):
            return free.calibration, {}
        why = free.reason if free.status != Status.GOOD else "its views since the move lie off the pose then solved"
        return None, {c: f"moved, not placed again yet (placed with its lens as calibrated, but with its lens free: "
                         f"{why}); its new tracks will place it" for c in sorted(held)}

    def _initial(self) -> Calibration | None:
        """The warm start: the last good calibration (its points only while they mean the same tracks)."""
        if self.good is None or len(self._reset) == len(self.good.cameras):
            return None
        start = self.good
        # A moved camera left out of the last good one starts from its lens (its pose is solved afresh).
        absent = [camera for c, (camera, _) in self._pending.items() if c not in {k.id for k in start.cameras}]
        if absent:
            start = replace(start, cameras=(*start.cameras, *absent))
        if self._points_valid:
            return start
        return replace(start, point_ids=np.empty(0, dtype=np.int64), points=np.empty((0, 3)))

    def _solve(self, obs: Observations, moved: tuple[str, ...]) -> Outcome:
        initial = self._initial()
        cold = None if self.config.stereo_pose is None else stereo_head(obs, *self.config.stereo_pose)
        check = partial(policy_check, config=self.config)
        waiting = self._waiting(obs)
        if initial is not None:
            warm = solve_judged(self._lens_held(obs), initial, options=self._options, check=check,
                                reset=self._reset, leave_out=waiting)
            unplaced = {**self._moved_unplaced(obs, warm), **waiting}
            if warm.status == Status.GOOD and not set(unplaced) - set(waiting):
                freed, unplaced_free = self._lens_freed(obs, warm, waiting)
                if freed is not None:
                    return Outcome(Status.GOOD, "", freed, moved, warm=True)
                unplaced |= unplaced_free
            if unplaced:
                # A moved camera that its few new tracks cannot place yet must not send the rest cold (a cold
                # solve places it from those few, and can place it far off within a few sigmas), nor stand
                # where its new views say it is not. The others are solved warm and it is named, until its new
                # tracks place it (docs/benchmarks.md, "Evidence behind the solver's thresholds").
                rest = solve_judged(obs, initial, options=self._options, check=check, reset=(),
                                    leave_out=unplaced)
                if rest.status == Status.GOOD:
                    return Outcome(Status.GOOD, "", rest.calibration, moved, warm=True)
        # Not good warm (a camera taken for moved that fails, say): the pool is solved cold, a long one
        # on its newest tracks first.
        judged = solve_newest_first(obs, self._options, check, start=cold,
                                    start_tracks=self.config.cold_start_tracks, leave_out=waiting)
        if judged.status == Status.GOOD:
            return Outcome(Status.GOOD, "", judged.calibration, moved, warm=cold is not None)
        return Outcome(judged.status, judged.reason, None, moved, warm=False)


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
        dist = np.zeros(info.model.dist_size) if info.dist is None else info.dist
        cameras.append(Camera(cam_id, info.width, info.height, info.K, dist, R_cam, t_cam, info.model))
    return Calibration(cameras=tuple(cameras), point_ids=np.empty(0, dtype=np.int64), points=np.empty((0, 3)),
                       rms_reprojection_px=float("nan"), world_frame=obs.stereo.left)
