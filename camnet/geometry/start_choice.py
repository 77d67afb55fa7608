"""A cold solve from the other start where the first went wrong, and which of the two to keep.

The scale pair is placed either as the paper's parallel pair or by its
essential matrix (camnet.geometry.cold_start). Which one fits is decided
from the pair's matches, and no threshold on them decides every rig: a pair
45 degrees apart can pass for parallel when RANSAC's fundamental matrix
fits its matches loosely, and a parallel head toed in by two degrees is
better started as parallel. So where a solve from the chosen start is
refused, keeps few of its observations, or leaves out a camera that shares
enough tracks with the cameras placed to have been placed, the solve is run
again from the other start, and the two are compared by the truncated
quadratic (MSAC) cost of every observation: a camera left out, or a track
dropped, costs each of its observations the truncation. The scale never
enters the comparison.

Pixels as observed; costs in px^2.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from camnet.errors import SolveError
from camnet.geometry.cold_start import PairStart, pair_looks_parallel
from camnet.geometry.diagnostics import WRONG_START_INLIER_SHARE
from camnet.geometry.model import Calibration, Observations
from camnet.geometry.register import MIN_INLIER_SHARE, MIN_RESECTION_POINTS

if TYPE_CHECKING:
    from camnet.geometry.calibrate import Result

log = logging.getLogger(__name__)

# A camera left out that shares this many tracks with the cameras placed should have been placed: at
# registration's least inlier share, they hold enough agreeing points to resect it.
RETRY_SHARED_TRACKS = int(np.ceil(MIN_RESECTION_POINTS / MIN_INLIER_SHARE))
# A solve keeping less of its observations than a wrong start's refusal asks of one that left cameras out may
# have started in the wrong basin: the other start is tried. Real matches hold false ones, which a sound solve
# rejects: below this the retry costs a second solve, and most live cold solves keep more.
RETRY_INLIER_SHARE = WRONG_START_INLIER_SHARE
SOUND_INLIER_SHARE = 0.9  # where the first start is refused, a solve from the other is kept only keeping this share


def shared_left_out(obs: Observations, calibration: Calibration) -> list[str]:
    """The cameras left out of `calibration` that share at least RETRY_SHARED_TRACKS tracks with those placed."""
    placed = np.isin([c.id for c in obs.cameras], [c.id for c in calibration.cameras])
    seen_by_placed = np.zeros(len(obs.track_ids), dtype=int)
    np.add.at(seen_by_placed, obs.track_index[placed[obs.cam_index]], 1)
    out = []
    for i in np.flatnonzero(~placed):
        own = obs.track_index[obs.cam_index == i]
        if np.sum(seen_by_placed[own] >= 2) >= RETRY_SHARED_TRACKS:  # points the placed cameras triangulate
            out.append(obs.cameras[i].id)
    return out


def msac_cost(obs: Observations, calibration: Calibration, truncation_px: float) -> float:
    """Sum over every observation of min(squared reprojection error, truncation^2), px^2.

    An observation of a camera or a track the calibration lacks (left out,
    dropped) costs the truncation, as does one behind its camera.
    """
    cost = np.full(len(obs.uv), truncation_px**2)
    ids = np.asarray(calibration.point_ids)
    order = np.argsort(ids, kind="stable")
    at = np.minimum(np.searchsorted(ids, obs.track_ids, sorter=order), max(len(ids) - 1, 0))
    found = (ids[order[at]] == obs.track_ids) if len(ids) else np.zeros(len(obs.track_ids), dtype=bool)
    point = np.where(found, order[at] if len(ids) else 0, -1)[obs.track_index]
    for camera in calibration.cameras:
        here = np.flatnonzero((obs.cam_index == obs.index_of(camera.id)) & (point >= 0))
        uv = camera.project(calibration.points[point[here]])
        r2 = np.sum((uv - obs.uv[here]) ** 2, axis=1)
        cost[here] = np.minimum(np.nan_to_num(r2, nan=np.inf), truncation_px**2)
    return float(cost.sum())


def _inlier_share(result: Result) -> float:
    report = result.calibration.report
    return report.inliers / report.observations if report is not None and report.observations else 0.0


def _sound(obs: Observations, result: Result, min_inlier_share: float) -> bool:
    """At least that share of the observations kept, and every camera placed that shares enough tracks to be."""
    return _inlier_share(result) >= min_inlier_share and not shared_left_out(obs, result.calibration)


def solve_from_either_start(
    obs: Observations, solve: Callable[[PairStart], Result], *, outlier_sigmas: float, min_outlier_px: float
) -> Result:
    """The solve from the start the pair's matches choose, or from the other where that one went wrong.

    solve(pair): a cold solve from that start (raises SolveError when
    refused). outlier_sigmas, min_outlier_px: the truncation of the MSAC
    cost, outlier_sigmas times the smaller reprojection RMS of the two
    solves, at least min_outlier_px (as the outlier rejection's).
    """
    try:
        first, refusal = solve(PairStart.AUTO), None
    except SolveError as exc:
        first, refusal = None, exc
    if first is not None and _sound(obs, first, RETRY_INLIER_SHARE):
        return first
    other = PairStart.ESSENTIAL if pair_looks_parallel(obs) else PairStart.PAPER
    why = f"is refused ({refusal})" if refusal else f"is unsound ({_inlier_share(first):.0%} of the observations " \
        f"kept; cameras sharing tracks left out: {shared_left_out(obs, first.calibration)})"
    log.info("the solve from the pair's first start %s: solving from the %s start", why, other.value)
    try:
        second = solve(other)
    except SolveError as exc:
        log.info("the solve from the %s start is refused too (%s)", other.value, exc)
        second = None
    if first is None:
        if second is not None and _sound(obs, second, SOUND_INLIER_SHARE):
            return second
        raise refusal
    if second is None:
        return first
    rms = min(first.calibration.rms_reprojection_px, second.calibration.rms_reprojection_px)
    truncation_px = max(min_outlier_px, outlier_sigmas * rms)
    costs = [msac_cost(obs, r.calibration, truncation_px) for r in (first, second)]
    log.info("MSAC cost (truncated at %.2f px) from the first start %.0f px^2, from the %s start %.0f px^2",
             truncation_px, costs[0], other.value, costs[1])
    return second if costs[1] < costs[0] else first
