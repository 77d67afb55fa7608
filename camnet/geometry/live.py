"""Live calibration policy: when a solve may replace the last good one, and the state between solves.

No I/O and no bus: the calibrator node feeds observations in and publishes
what comes out. Each observations message (the matcher's pooled tracks) is
solved warm from the last good calibration; a moved camera (see
`camnet.geometry.change`) is detected on the tracks that arrived since, its
older observations are dropped and its pose solved afresh; if a stereo
camera, or most of the rig, moved, the metric frame itself is gone and the
solve starts over from the new tracks alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from camnet.geometry.calibrate import Options
from camnet.geometry.change import MoveRule, drop_before, moved_cameras, new_track_errors
from camnet.geometry.judged_solve import Refusal, Status, solve_judged
from camnet.geometry.model import Calibration, Camera, Observations
from camnet.geometry.newest_first import START_TRACKS, solve_newest_first
from camnet.geometry.two_view import FOCAL_RANGE_REL

log = logging.getLogger(__name__)

# What a live rig estimates by default: focal lengths, poses and the pair's
# small misalignment. Principal points and distortion stay as given (image
# centre and none when nothing is given; the reported sigmas include what a
# guessed principal point may cost). On the simulated rigs' live tracks
# (thousands of points, 0.25 px RMS) the principal points are not determined
# (sigmas of thousands of pixels) and freeing k1, k2 beside the pair's yaw
# costs a factor of 5 in focal sigma and biased every focal length alike by
# 0.25%; with this set the focal errors stay within 0.15%. Lenses with
# visible distortion need their dist given, or
# `--free f,k1,k2,stereo_rotation,stereo_direction`. A fisheye camera's four
# coefficients move unless given (`fisheye`, camnet.geometry.free_rule): they are its lens.
LIVE_FREE = frozenset({"f", "fisheye", "stereo_rotation", "stereo_direction"})


@dataclass(frozen=True)
class LiveConfig:
    """How a live rig solves and when it trusts a solution.

    A solution is good when it converged, its reprojection RMS is at most
    `max_rms_px`, its scale is known to `max_scale_rel` (1 sigma), every focal
    length it estimated lies within `two_view.FOCAL_RANGE_REL` image widths
    (10-170 degrees across), every camera but the stereo pair keeps at least
    `min_inlier_share` of its observations as inliers and it holds every
    camera of the observations that its report does not name as left out
    (with the reason): a partial calibration is published, its missing
    cameras named.
    """

    options: Options = Options(free=LIVE_FREE)
    move_rule: MoveRule = MoveRule()
    max_rms_px: float = 3.0
    max_scale_rel: float = 0.05
    # A camera placed wrong fits its two-view tracks anyway and loses most of the others as outliers:
    # on the surround rig 8-28% kept for cameras 0.5-1.7 m off, 80-99% for every camera placed right.
    min_inlier_share: float = 0.5
    # A factory-calibrated stereo head (the rig file's stereo.R, stereo.t): the right camera's
    # pose in the left's frame, x_right = R x_left + t. Every solve without a good calibration
    # to start from starts from it, so that a free set without the pair's axes holds it.
    stereo_pose: tuple[np.ndarray, np.ndarray] | None = None
    # A cold solve of a pool of at least twice as many starts on its newest this many tracks
    # (camnet.geometry.newest_first: the oldest tracks of a long pool are the falsest).
    cold_start_tracks: int = START_TRACKS


@dataclass(frozen=True)
class Outcome:
    """What one update did."""

    status: Status
    reason: str
    calibration: Calibration | None = None
    moved: tuple[str, ...] = ()
    warm: bool = False
    solve_s: float = 0.0


def judge(cal: Calibration, obs: Observations, config: LiveConfig) -> str:
    """Why `cal` must not replace a good calibration, or "" if it may."""
    whole = judge_rig(cal, config)
    if whole:
        return whole
    absurd = absurd_focals(cal, obs)
    if absurd:
        # A start gone wrong can converge to such a rig at a low RMS and a small scale sigma.
        return (f"focal lengths outside {FOCAL_RANGE_REL[0]}-{FOCAL_RANGE_REL[1]} image widths: "
                f"{', '.join(f'{c} {f:.0f} px' for c, f in absurd.items())}")
    few = misplaced(cal, obs, config)
    if few:
        kept = ", ".join(f"{c} {100 * s:.0f}%" for c, s in few.items())
        return (f"cameras {sorted(few)} keep too few of their observations as inliers ({kept}, less than "
                f"{100 * config.min_inlier_share:.0f}%): placed wrong, or their tracks are")
    # A camera the solve could not place (it shares too little yet, or no pose agrees) is named with its
    # reason in the report and the calibration of the others stands; one missing without a reason does not.
    unexplained = set(obs.camera_ids) - {c.id for c in cal.cameras} - set(cal.report.cameras_left_out)
    if unexplained:
        return f"cameras {sorted(unexplained)} not calibrated, and the solve does not say why"
    return ""


def judge_rig(cal: Calibration, config: LiveConfig) -> str:
    """`judge`'s checks of the rig as a whole (convergence, RMS, scale): why they refuse `cal`, or ""."""
    if cal.report is None or not cal.report.converged:
        return f"not converged ({cal.report.reason if cal.report is not None else 'unknown'})"
    if not cal.rms_reprojection_px <= config.max_rms_px:
        return f"reprojection RMS {cal.rms_reprojection_px:.2f} px > {config.max_rms_px} px"
    scale_rel = cal.uncertainty.scale_rel.value if cal.uncertainty is not None else None
    if scale_rel is None or not scale_rel <= config.max_scale_rel:
        return f"scale uncertain ({scale_rel} > {config.max_scale_rel})"
    return ""


def absurd_focals(cal: Calibration, obs: Observations) -> dict[str, float]:
    """The cameras whose estimated focal length (px) lies outside `two_view.FOCAL_RANGE_REL` image widths."""
    held = {c.id for c in obs.cameras if c.K is not None and "K" in c.fixed}
    return {c.id: float(c.K[0, 0]) for c in cal.cameras if c.id not in held
            and not FOCAL_RANGE_REL[0] * c.width <= c.K[0, 0] <= FOCAL_RANGE_REL[1] * c.width}


def policy_check(cal: Calibration, obs: Observations, config: LiveConfig) -> Refusal:
    """`judge`'s answer as `judged_solve` takes it: where the rig as a whole passes (`judge_rig`), the
    cameras placed wrong (`refused_cameras`), which a solve without them may leave out."""
    reason = judge(cal, obs, config)
    return Refusal(reason, refused_cameras(cal, obs, config) if reason and not judge_rig(cal, config) else {})


def refused_cameras(cal: Calibration, obs: Observations, config: LiveConfig) -> dict[str, str]:
    """The cameras but the stereo pair that `judge` refuses `cal` for (a focal length out of range, too few
    inliers), each with why: placed wrong, while the others may stand."""
    pair = (obs.stereo.left, obs.stereo.right)
    refused = {c: (f"focal length {f:.0f} px, outside {FOCAL_RANGE_REL[0]}-{FOCAL_RANGE_REL[1]} image widths: "
                   "placed wrong, or its tracks are") for c, f in absurd_focals(cal, obs).items() if c not in pair}
    for c, share in misplaced(cal, obs, config).items():
        refused.setdefault(c, f"keeps only {100 * share:.0f}% of its observations as inliers (less than "
                              f"{100 * config.min_inlier_share:.0f}%): placed wrong, or its tracks are")
    return refused


def misplaced(cal: Calibration, obs: Observations, config: LiveConfig) -> dict[str, float]:
    """The cameras but the stereo pair that keep less than `min_inlier_share` of their observations as
    inliers, with the share kept: placed wrong, or their tracks are."""
    total = np.bincount(obs.cam_index, minlength=len(obs.cameras))
    stats = cal.report.cameras if cal.report is not None else {}
    # The pair is held by its baseline (and, held parallel or to a factory pose, may lose more).
    others = [c.id for c in cal.cameras if c.id in stats and c.id not in (obs.stereo.left, obs.stereo.right)]
    share = {c: stats[c].inliers / max(int(total[obs.index_of(c)]), 1) for c in others}
    return {c: s for c, s in share.items() if s < config.min_inlier_share}


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
        if outcome.status == Status.GOOD:
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
        stats = self.good.report.cameras if self.good.report is not None else {}
        reference = {cam_id: camera.rms_px for cam_id, camera in stats.items()}
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
        check = partial(policy_check, config=self.config)
        if initial is not None:
            warm = solve_judged(obs, initial, options=self.config.options, check=check, reset=self._reset)
            if warm.status == Status.GOOD:
                return Outcome(Status.GOOD, "", warm.calibration, moved, warm=True)
        # Not good warm (a camera taken for moved that fails, say): the pool is solved cold, a long one
        # on its newest tracks first.
        judged = solve_newest_first(obs, self.config.options, check, start=cold,
                                    start_tracks=self.config.cold_start_tracks)
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
