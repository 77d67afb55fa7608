"""The live policy: what a live rig solves, and when a solve may replace the last good calibration.

Pure checks of one solve against its observations, with no state: the live
calibrator's Tracker (camnet.live.tracker) judges every solve by them
(`policy_check`), and `camnet calibrate` judges its solve by the same
`SoundnessLimits` (`soundness_check`: all but the live limit on the scale's
sigma, camnet.live.judged_solve), so that a file solved offline is
refused or trimmed as the live calibrator would, for what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camnet.errors import in_words
from camnet.live.judged_solve import Refusal
from camnet.live.moved_cameras import MoveRule
from camnet.live.newest_first import START_TRACKS
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.model.two_view import FOCAL_RANGE_REL
from camnet.solve import Options

# What a live rig estimates by default: focal lengths, poses and the pair's
# small misalignment. Principal points and distortion stay as given (image
# centre and none when nothing is given; the reported sigmas include what a
# guessed principal point may cost). Live tracks of a simulated rig do not
# determine the principal points, and freeing k1, k2 beside the pair's yaw
# widens the focal sigmas several times and biases every focal length alike
# (docs/benchmarks.md, "The live network"). Lenses with
# visible distortion need their dist given, or
# `--free f,k1,k2,stereo_rotation,stereo_direction`. A fisheye camera's four
# coefficients move unless given (`fisheye`, camnet.solve.free_rule): they are its lens.
LIVE_FREE = frozenset({"f", "fisheye", "stereo_rotation", "stereo_direction"})


@dataclass(frozen=True)
class SoundnessLimits:
    """When a solve is wrong, not merely uncertain: what the live calibrator and `camnet calibrate` both refuse.

    A solution is sound when it converged, its reprojection RMS is at most
    `max_rms_px`, every focal length it estimated lies within
    `focal_range_rel` image widths (two_view.FOCAL_RANGE_REL: 10-170
    degrees across), every camera but the stereo pair keeps at least
    `min_inlier_share` of its observations as inliers and it holds every
    camera of the observations that its report does not name as left out
    (with the reason): a partial calibration is published, its missing
    cameras named.
    """

    max_rms_px: float = 3.0
    # A camera placed wrong fits its two-view tracks anyway and loses most of the others as outliers,
    # where a camera placed right keeps most of its own (docs/benchmarks.md, "The surround rig, live").
    min_inlier_share: float = 0.5
    focal_range_rel: tuple[float, float] = FOCAL_RANGE_REL


@dataclass(frozen=True)
class LiveConfig:
    """How a live rig solves and when it trusts a solution: a sound one (`limits`) whose scale is known to
    `max_scale_rel` (1 sigma)."""

    options: Options = Options(free=LIVE_FREE)
    # The second opinion (camnet.solve.halves, two cold solves) is asked again at most this often, seconds:
    # between, the calibrations go on with the last one's widening.
    halves_interval_s: float = 60.0
    move_rule: MoveRule = MoveRule()
    limits: SoundnessLimits = SoundnessLimits()
    max_scale_rel: float = 0.05
    # A factory-calibrated stereo head (the rig file's stereo.R, stereo.t): the right camera's
    # pose in the left's frame, x_right = R x_left + t. Every solve without a good calibration
    # to start from starts from it, so that a free set without the pair's axes holds it.
    stereo_pose: tuple[np.ndarray, np.ndarray] | None = None
    # A cold solve of a pool of at least twice as many starts on its newest this many tracks
    # (camnet.live.newest_first: the oldest tracks of a long pool are the falsest).
    cold_start_tracks: int = START_TRACKS


# A refusal for the scale's sigma being null: its reason says what to give (e.g. the stereo cameras' K).
SCALE_UNDETERMINED = "the scale is not determined"


def judge(cal: Calibration, obs: Observations, config: LiveConfig) -> str:
    """Why `cal` must not replace a good calibration, or "" if it may."""
    return judge_rig(cal, config.limits, max_scale_rel=config.max_scale_rel) or judge_cameras(cal, obs, config.limits)


def judge_rig(cal: Calibration, limits: SoundnessLimits, *, max_scale_rel: float = math.inf) -> str:
    """`judge`'s checks of the rig as a whole (convergence, RMS, scale): why they refuse `cal`, or "".

    max_scale_rel: the most the scale's relative sigma may be; infinite, a scale the solve determines.
    """
    if cal.report is None or not cal.report.converged:
        return f"not converged ({cal.report.reason if cal.report is not None else 'unknown'})"
    if not cal.rms_reprojection_px <= limits.max_rms_px:
        return f"reprojection RMS {cal.rms_reprojection_px:.2f} px > {limits.max_rms_px} px"
    scale = cal.uncertainty.scale_rel if cal.uncertainty is not None else None
    if scale is None or scale.value is None:
        return f"{SCALE_UNDETERMINED}: {scale.reason if scale is not None else 'no uncertainty computed'}"
    if not scale.value <= max_scale_rel:
        return f"scale uncertain ({scale.value} > {max_scale_rel})"
    return ""


def judge_cameras(cal: Calibration, obs: Observations, limits: SoundnessLimits) -> str:
    """`judge`'s checks of the cameras (focal lengths, inliers, every camera placed or said why not), or ""."""
    absurd = absurd_focals(cal, obs, limits)
    if absurd:
        # A start gone wrong can converge to such a rig at a low RMS and a small scale sigma.
        low, high = limits.focal_range_rel
        said = ", ".join(f"{c} {f:.0f} px" for c, f in absurd.items())
        return f"focal lengths outside {low}-{high} image widths: {said}"
    few = misplaced(cal, obs, limits)
    if few:
        kept = ", ".join(f"{c} {100 * s:.0f}%" for c, s in few.items())
        keep, their = ("keeps", "its") if len(few) == 1 else ("keep", "their")
        return (f"{in_words(sorted(few), noun='camera')} {keep} too few of {their} observations as inliers ({kept}, "
                f"less than {100 * limits.min_inlier_share:.0f}%): placed wrong, or {their} tracks are")
    # A camera the solve could not place (it shares too little yet, or no pose agrees) is named with its
    # reason in the report and the calibration of the others stands; one missing without a reason does not.
    unexplained = set(obs.camera_ids) - {c.id for c in cal.cameras} - set(cal.report.cameras_left_out)
    if unexplained:
        return f"{in_words(sorted(unexplained), noun='camera')} not calibrated, and the solve does not say why"
    return ""


def absurd_focals(cal: Calibration, obs: Observations, limits: SoundnessLimits) -> dict[str, float]:
    """The cameras whose estimated focal length (px) lies outside `limits.focal_range_rel` image widths."""
    held = {c.id for c in obs.cameras if c.K is not None and "K" in c.fixed}
    low, high = limits.focal_range_rel
    return {c.id: float(c.K[0, 0]) for c in cal.cameras
            if c.id not in held and not low * c.width <= c.K[0, 0] <= high * c.width}


def policy_check(cal: Calibration, obs: Observations, config: LiveConfig) -> Refusal:
    """`judge`'s answer as `judged_solve` takes it: where the rig as a whole passes (`judge_rig`), the
    cameras placed wrong (`refused_cameras`), which a solve without them may leave out."""
    return _refusal(cal, obs, config.limits, config.max_scale_rel)


def soundness_check(cal: Calibration, obs: Observations, limits: SoundnessLimits = SoundnessLimits()) -> Refusal:
    """`policy_check` with no limit on the scale's sigma (one it determines still): what `camnet calibrate`
    refuses (a solve that is wrong), while it reports a large scale sigma as it is."""
    return _refusal(cal, obs, limits, math.inf)


def _refusal(cal: Calibration, obs: Observations, limits: SoundnessLimits, max_scale_rel: float) -> Refusal:
    rig = judge_rig(cal, limits, max_scale_rel=max_scale_rel)
    reason = rig or judge_cameras(cal, obs, limits)
    return Refusal(reason, refused_cameras(cal, obs, limits) if reason and not rig else {})


def refused_cameras(cal: Calibration, obs: Observations, limits: SoundnessLimits) -> dict[str, str]:
    """The cameras but the stereo pair that `judge` refuses `cal` for (a focal length out of range, too few
    inliers), each with why: placed wrong, while the others may stand."""
    pair = (obs.stereo.left, obs.stereo.right)
    low, high = limits.focal_range_rel
    refused = {c: (f"focal length {f:.0f} px, outside {low}-{high} image widths: placed wrong, or its tracks are")
               for c, f in absurd_focals(cal, obs, limits).items() if c not in pair}
    for c, share in misplaced(cal, obs, limits).items():
        refused.setdefault(c, f"keeps only {100 * share:.0f}% of its observations as inliers (less than "
                              f"{100 * limits.min_inlier_share:.0f}%): placed wrong, or its tracks are")
    return refused


def misplaced(cal: Calibration, obs: Observations, limits: SoundnessLimits) -> dict[str, float]:
    """The cameras but the stereo pair that keep less than `limits.min_inlier_share` of their observations as
    inliers, with the share kept: placed wrong, or their tracks are."""
    total = np.bincount(obs.cam_index, minlength=len(obs.cameras))
    stats = cal.report.cameras if cal.report is not None else {}
    # The pair is held by its baseline (and, held parallel or to a factory pose, may lose more).
    others = [c.id for c in cal.cameras if c.id in stats and c.id not in (obs.stereo.left, obs.stereo.right)]
    share = {c: stats[c].inliers / max(int(total[obs.index_of(c)]), 1) for c in others}
    return {c: s for c, s in share.items() if s < limits.min_inlier_share}
