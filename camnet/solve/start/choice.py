"""A cold solve from another start where the first went wrong, and which to keep.

The scale pair is placed as the paper's parallel pair, by its essential
matrix, or, where it sees few tracks together, from the two cameras that
share the most (camnet.solve.start.cold). Which one fits is decided
from the pair's matches, and no threshold on them decides every rig: a pair
45 degrees apart can pass for parallel when RANSAC's fundamental matrix
fits its matches loosely, and a parallel head toed in by two degrees is
better started as parallel. So where a solve from the chosen start is
refused, keeps few of its observations, or leaves out a camera that shares
enough tracks with the cameras placed to have been placed, the solve is run
again from each start not yet used (a start the data cannot make is passed
over, unsolved) until one is sound, and they are compared by the truncated
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

from camnet.errors import SolveError, in_words
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.model.resection import MIN_INLIER_SHARE, MIN_RESECTION_POINTS
from camnet.solve.report.assemble import WRONG_START_INLIER_SHARE
from camnet.solve.start.cold import NoStart, PairStart, pair_looks_parallel, stronger_pair

if TYPE_CHECKING:
    from camnet.solve.result import Result

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


def start_order(obs: Observations) -> list[PairStart]:
    """The starts a cold solve tries, in order: the stronger pair's first where the stereo pair sees few tracks
    together (`cold_start.stronger_pair`), then the paper's first where the pair looks parallel."""
    starts = [PairStart.PAPER, PairStart.ESSENTIAL]
    if not pair_looks_parallel(obs):
        starts.reverse()
    return ([PairStart.STRONGEST] if stronger_pair(obs) is not None else []) + starts


def solve_from_any_start(
    obs: Observations, solve: Callable[[PairStart], Result], *, outlier_sigmas: float, min_outlier_px: float
) -> Result:
    """The solve from the first start of `start_order` that gives one, or from the others where that went wrong.

    solve(pair): a cold solve from that start (raises SolveError when
    refused, NoStart when the start cannot be made). outlier_sigmas,
    min_outlier_px: the truncation of the MSAC cost, outlier_sigmas times
    the smallest reprojection RMS of the solves, at least min_outlier_px
    (as the outlier rejection's). A solve after a refused first one is kept
    only keeping SOUND_INLIER_SHARE of the observations.
    """
    first: Result | None = None
    refusal: SolveError | None = None  # the first solve's
    kept: list[tuple[PairStart, Result]] = []
    tried, passed = [], []
    for pair in start_order(obs):
        if tried:
            log.info("the solve from the %s start %s: solving from the %s start", tried[0].value,
                     _why(obs, first, refusal), pair.value)
        try:
            result = solve(pair)
        except NoStart as exc:
            log.info("no %s start: %s", pair.value, exc)
            passed.append(f"{pair.value}: {exc}")
            continue
        except SolveError as exc:
            log.info("the solve from the %s start is refused (%s)", pair.value, exc)
            result = None
            refusal = exc if not tried else refusal
        tried.append(pair)
        if len(tried) == 1:
            first = result
            if result is not None and _sound(obs, result, RETRY_INLIER_SHARE):
                return result
        if result is not None and (len(tried) == 1 or first is not None or _sound(obs, result, SOUND_INLIER_SHARE)):
            kept.append((pair, result))
        if len(tried) > 1 and result is not None and _sound(obs, result, SOUND_INLIER_SHARE):
            break
    if not kept:
        if refusal is None:  # no start could be made at all
            raise SolveError("start: no start could be made (" + "; ".join(passed) + ")")
        others = ", ".join(p.value for p in tried[1:])
        also = f" (from the {others} start too: refused, or keeping under {SOUND_INLIER_SHARE:.0%})" if others else ""
        raise SolveError(f"{refusal}{also}") from None
    return _least_cost(obs, kept, outlier_sigmas, min_outlier_px)


def _why(obs: Observations, first: Result | None, refusal: SolveError | None) -> str:
    if first is None:
        return f"is refused ({refusal})"
    return (f"is unsound ({_inlier_share(first):.0%} of the observations kept; cameras sharing tracks left out: "
            f"{in_words(shared_left_out(obs, first.calibration))})")


def _least_cost(obs: Observations, kept: list[tuple[PairStart, Result]], outlier_sigmas: float,
                min_outlier_px: float) -> Result:
    """The result of least MSAC cost, truncated at outlier_sigmas times the least RMS (at least min_outlier_px)."""
    if len(kept) == 1:
        return kept[0][1]
    rms = min(r.calibration.rms_reprojection_px for _, r in kept)
    truncation_px = max(min_outlier_px, outlier_sigmas * rms)
    costs = [msac_cost(obs, r.calibration, truncation_px) for _, r in kept]
    log.info("MSAC cost (truncated at %.2f px): %s", truncation_px,
             ", ".join(f"from the {p.value} start {c:.0f} px^2" for (p, _), c in zip(kept, costs, strict=True)))
    return kept[int(np.argmin(costs))][1]
