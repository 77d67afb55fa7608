"""A cold solve from several starts, which to keep, and its rivals.

The scale pair is placed as the paper's parallel pair, by its essential
matrix, or from the two cameras that share the most tracks (camnet.solve.
start.cold). No threshold on the pair's matches decides every rig: a pair
45 degrees apart can pass for parallel when RANSAC's fundamental matrix
fits its matches loosely, and a parallel head toed in by two degrees is
better started as parallel. And where every start converges, real scenes
hold several minima of nearly equal cost. So every cold solve runs from
each start of `start_order` (one the data cannot make is passed over,
unsolved; one that would repeat another is not run), and the solves are
compared by the truncated quadratic (MSAC) cost of every observation: a
camera left out, or a track dropped, costs each of its observations the
truncation. The scale never enters the comparison. A solve the data cannot
tell from the kept one, yet which differs from it, is named in the report
as its rival, and the sigmas widened to cover both
(camnet.solve.report.rivals).

Pixels as observed; costs in px^2.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from camnet.errors import SolveError
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.model.resection import MIN_INLIER_SHARE, MIN_RESECTION_POINTS
from camnet.solve.report.assemble import WRONG_START_INLIER_SHARE
from camnet.solve.report.rivals import rival, with_rivals
from camnet.solve.start.cold import NoStart, PairStart, pair_looks_parallel, stronger_pair, strongest_pair

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
    """The starts every cold solve runs, in order: the scale pair's own (the paper's where the pair looks
    parallel, else the essential matrix's) and the strongest pair's where it is not the scale pair
    (`cold.strongest_pair`), first where the scale pair sees few tracks together (`cold.stronger_pair`).

    A start that would repeat one run (the strongest pair being the scale
    pair) is not listed. The scale pair's other start is a fallback
    (`fallback_start`): a parallel pair solved from its essential matrix
    frees the rotation the paper's start holds, and fits the noise better
    by that alone.
    """
    starts = [PairStart.PAPER if pair_looks_parallel(obs) else PairStart.ESSENTIAL]
    if strongest_pair(obs) is None:
        return starts
    return [PairStart.STRONGEST, *starts] if stronger_pair(obs) is not None else [*starts, PairStart.STRONGEST]


def fallback_start(order: list[PairStart]) -> PairStart:
    """The scale pair's start that `order` lacks: tried where no solve from `order` is sound."""
    return PairStart.ESSENTIAL if PairStart.PAPER in order else PairStart.PAPER


def solve_from_any_start(
    obs: Observations, solve: Callable[[PairStart], Result], *, outlier_sigmas: float, min_outlier_px: float
) -> Result:
    """The solve of least MSAC cost from the starts of `start_order`, naming its rivals.

    solve(pair): a cold solve from that start (raises SolveError when
    refused, NoStart when the start cannot be made). Where none of them is
    sound, the scale pair's other start is tried too (`fallback_start`: a
    parallel head toed in looks not parallel). A solve is compared when the first start that could
    be made gave one, else only keeping SOUND_INLIER_SHARE of the
    observations. outlier_sigmas, min_outlier_px: the truncation of the
    MSAC cost, outlier_sigmas times the smallest reprojection RMS of the
    solves, at least min_outlier_px (as the outlier rejection's). Another
    converged, sound solve whose cost is nearly equal yet which differs is
    named in the report (camnet.solve.report.rivals).
    """
    solved: list[tuple[PairStart, Result | None]] = []  # per start made: its solve, None where refused
    refusal: SolveError | None = None  # the first solve's
    passed: list[str] = []

    def run(pair: PairStart) -> None:
        nonlocal refusal
        try:
            result = solve(pair)
        except NoStart as exc:
            log.info("no %s start: %s", pair.value, exc)
            passed.append(f"{pair.value}: {exc}")
            return
        except SolveError as exc:
            log.info("the solve from the %s start is refused (%s)", pair.value, exc)
            result, refusal = None, refusal if solved else exc
        solved.append((pair, result))

    order = start_order(obs)
    for pair in order:
        run(pair)
    made = any(p in (PairStart.PAPER, PairStart.ESSENTIAL) for p, _ in solved)  # the scale pair's own
    if not made or not any(r is not None and _sound(obs, r, RETRY_INLIER_SHARE) for _, r in solved):
        log.info("the scale pair's start cannot be made or no solve is sound: solving from the %s start too",
                 fallback_start(order).value)
        run(fallback_start(order))
    first_solved = bool(solved) and solved[0][1] is not None
    kept = [(p, r) for p, r in solved if r is not None and (first_solved or _sound(obs, r, SOUND_INLIER_SHARE))]
    if not kept:
        if refusal is None:  # no start could be made at all
            raise SolveError("start: no start could be made (" + "; ".join(passed) + ")")
        others = ", ".join(p.value for p, _ in solved[1:])
        also = f" (from the {others} start too: refused, or keeping under {SOUND_INLIER_SHARE:.0%})" if others else ""
        raise SolveError(f"{refusal}{also}") from None
    return _least_cost(obs, kept, outlier_sigmas, min_outlier_px)


def _least_cost(obs: Observations, kept: list[tuple[PairStart, Result]], outlier_sigmas: float,
                min_outlier_px: float) -> Result:
    """The result of least MSAC cost, truncated at outlier_sigmas times the least RMS (at least min_outlier_px),
    with its rivals among the other converged, sound ones (`rivals.rival`)."""
    if len(kept) == 1:
        return kept[0][1]
    truncation_px = max(min_outlier_px, outlier_sigmas * min(r.calibration.rms_reprojection_px for _, r in kept))
    costs = [msac_cost(obs, r.calibration, truncation_px) for _, r in kept]
    log.info("MSAC cost (truncated at %.2f px): %s", truncation_px,
             ", ".join(f"from the {p.value} start {c:.0f} px^2" for (p, _), c in zip(kept, costs, strict=True)))
    best = int(np.argmin(costs))
    result = kept[best][1]
    found = []
    for k, (pair, other) in enumerate(kept):
        if k == best or not (other.converged and _sound(obs, other, RETRY_INLIER_SHARE)):
            continue
        named = rival(result.calibration, costs[best], other.calibration, costs[k], pair.value)
        if named is not None:
            log.info("the solve from the %s start is a rival: %s", pair.value,
                     "; ".join(f"{d.parameter} {d.camera or ''} {d.kept:.4g} against {d.rival:.4g}"
                               for d in named.differences))
            found.append((named, other.calibration))
    return replace(result, calibration=with_rivals(result.calibration, found)) if found else result
