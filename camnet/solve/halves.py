"""A second opinion the curvature cannot give: the scene solved again in two halves, and the halves compared.

The covariance at a minimum says nothing of another minimum as good, nor
of a model that fits one part of the scene and not another. So the tracks
of a solved calibration are split in two, across the widest axis of its
point cloud (then across the second, then at random where a spatial split
would leave a camera with too little to be placed), each half is solved
alone from a cold start (from the whole's, a half keeps its outliers and
its basin, and agrees), and every parameter the halves disagree on beyond
their own sigmas gets its reported sigma widened to their half-difference
(camnet.solve.report.halves), said in a warning.

A half is smaller than the whole, and its cold solve can end short of the
half's own least-cost solution, in a minimum that is no solution of the
half. A split whose halves disagree is ruled out, and the next tried, where
the whole's solution fits one half better than that half's own does, by more
than the noise's spread of a cost (as the rivals of a cold solve are
weighed: camnet.solve.report.rivals): that half was not solved, so the split
says nothing of the whole. A half's own solution fits it better than the
whole's does wherever it was solved, however far apart the two lie.

A half the scene leaves weak can lie in a valley along which its cost
barely changes: its cold solve stops anywhere along it, and the curvature
there, which knows nothing of the valley's length, calls a point as good as
the whole's several sigmas away. So the halves of a split that disagree are
each solved again from the whole's solution, and compared at whichever of
the two solutions fits that half better: where the half's data prefer its
cold solution, the disagreement stands; where one near the whole fits it as
well or better, the half never said otherwise.

Split tracks by position: points in metres, in the calibration's world frame.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np

from camnet.errors import SolveError, in_words
from camnet.model.calibration import Calibration, HalvesCheck
from camnet.model.observations import Observations
from camnet.solve.report.halves import HalfDifference, differences, disagreement_warning, sigma_factor, widened, widest
from camnet.solve.report.rivals import NEAR_COST_SIGMAS, cost_noise_px2
from camnet.solve.start.choice import msac_cost

log = logging.getLogger(__name__)

SPLITS = 1  # splits compared (two halves each): the first that keeps every camera in both halves
MIN_HALF_OBSERVATIONS = 30  # each camera keeps this many observations in each half, or the split is not made
SPLIT_SEED = 0  # the random split is the same on every run of the same observations


def track_sides(obs: Observations, cal: Calibration) -> Iterator[tuple[str, np.ndarray]]:
    """(name, side) of each split to try, in order: side (T,) int per track row of `obs`, 0 or 1, -1 for a track
    the calibration dropped (in neither half). Across the cloud's widest axis, its second, then at random."""
    row_of = {int(t): i for i, t in enumerate(obs.track_ids)}
    rows = np.array([row_of.get(int(p), -1) for p in cal.point_ids], dtype=int)
    points = cal.points[rows >= 0]
    rows = rows[rows >= 0]
    if len(rows) < 2:
        return
    centred = points - np.median(points, axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    for name, along in (("across the widest axis", centred @ axes[0]), ("across the second axis", centred @ axes[1]),
                        ("at random", np.random.default_rng(SPLIT_SEED).standard_normal(len(rows)))):
        side = np.full(len(obs.track_ids), -1)
        side[rows] = (along > np.median(along)).astype(int)
        yield name, side


def _thinned(obs: Observations, side: np.ndarray, most: int) -> np.ndarray:
    """`side` with each half cut to about `most` tracks (the others set to -1, in neither half).

    A camera seen in few of a half's tracks keeps them first, up to twice the observations a half needs of it,
    drawn evenly: every k-th track alone would thin a camera seen in a twentieth of a long pool below what a
    half needs to place it, and leave it without a second opinion. Every k-th of the rest fills the half.
    """
    out = np.full_like(side, -1)
    per_track = [np.flatnonzero(obs.cam_index == c) for c in range(len(obs.cameras))]
    for h in (0, 1):
        rows = np.flatnonzero(side == h)
        if len(rows) <= most:
            out[rows] = h
            continue
        kept = np.zeros(len(side), dtype=bool)
        in_half = side[obs.track_index] == h
        seen = np.bincount(obs.cam_index[in_half], minlength=len(obs.cameras))
        for c in np.argsort(seen, kind="stable"):
            tracks = np.unique(obs.track_index[per_track[c][in_half[per_track[c]]]])
            short = 2 * MIN_HALF_OBSERVATIONS - int(kept[tracks].sum())
            if short > 0:
                spare = tracks[~kept[tracks]]
                kept[spare[np.linspace(0, len(spare) - 1, min(short, len(spare))).astype(int)]] = True
        rest = rows[~kept[rows]]
        room = min(most - int(kept.sum()), len(rest))
        if room > 0:  # `room` of them, drawn evenly: every k-th with k rounded up would keep as few as half
            kept[rest[np.linspace(0, len(rest) - 1, room).round().astype(int)]] = True
        out[kept] = h
    return out


def _half(obs: Observations, keep: np.ndarray) -> Observations:
    """`obs` with only the track rows where `keep` (T,) is true."""
    rows = keep[obs.track_index]
    return replace(obs, cam_index=obs.cam_index[rows], track_index=obs.track_index[rows], uv=obs.uv[rows])


def _short(obs: Observations, side: np.ndarray, cameras: list[str]) -> list[str]:
    """The cameras of `cameras` that keep fewer than MIN_HALF_OBSERVATIONS observations in either half."""
    short = set()
    for h in (0, 1):
        counts = np.bincount(obs.cam_index[side[obs.track_index] == h], minlength=len(obs.cameras))
        short |= {c for c in cameras if counts[obs.index_of(c)] < MIN_HALF_OBSERVATIONS}
    return [c for c in cameras if c in short]


def with_halves_check(obs: Observations, cal: Calibration, solve: Callable[[Observations], Calibration], *,
                      truncation_px: float, max_half_tracks: int | None = None,
                      polish: Callable[[Observations, Calibration], Calibration] | None = None) -> Calibration:
    """`cal` with its report's `halves` check, and its sigmas widened where the halves disagree.

    solve: solves observations with the whole's options from a cold start, with no halves check of its own; raises
    SolveError where it cannot. A half that cannot be solved ends its split, which is not compared.
    polish: solves observations the same way from a given calibration's start (the module docstring: a disagreeing
    half compared at the better of its two solutions); None: each half at its cold solution.
    truncation_px: the MSAC cost's truncation, by which a split's disagreement is ruled out (`ruled_out`).
    max_half_tracks: each half keeps at most this many of its tracks, drawn evenly (None: all), so that a live
    calibrator's check of a long pool costs two cold solves of a bounded size.
    """
    report = cal.report
    if report is None or report.uncertainty is None:
        return cal
    t0 = time.perf_counter()
    cameras = [c.id for c in cal.cameras]
    compared: list[dict[str, HalfDifference]] = []
    dismissed: list[str] = []
    from_whole: list[str] = []
    why = "no split keeps every camera's view in both halves"
    fewest: list[str] | None = None
    for name, side in track_sides(obs, cal):
        if len(compared) == SPLITS:
            break
        if max_half_tracks is not None:
            side = _thinned(obs, side, max_half_tracks)
        short = _short(obs, side, cameras)
        if short:
            if fewest is None or len(short) < len(fewest):
                fewest = short
                why = (f"no split keeps every camera's view in both halves ({in_words(short, noun='camera')} "
                       f"{'has' if len(short) == 1 else 'have'} too few observations for two)")
            continue
        parts = (_half(obs, side == 0), _half(obs, side == 1))
        try:
            a, b = solve(parts[0]), solve(parts[1])
        except SolveError as exc:
            why = f"a half {name} could not be solved alone: {str(exc).split(' (')[0]}"  # its first clause
            log.info("halves check: %s", why)
            continue
        unplaced = sorted(set(cameras) - ({c.id for c in a.cameras} & {c.id for c in b.cameras}))
        if unplaced:  # a camera one half left out would have no second opinion
            why = f"a half {name} left out {in_words(unplaced, noun='camera')}"
            log.info("halves check: %s", why)
            continue
        diffs = differences(a, b)
        if _disagree(diffs):
            short_of = unsolved_half(cal, ((parts[0], a), (parts[1], b)), truncation_px)
            if short_of:
                log.info("halves check: the split %s is ruled out: %s", name, short_of)
                dismissed.append(name)
                why = f"the split {name} is ruled out: {short_of}"
                continue
            if polish is not None:
                cold = (a, b)
                better = [_better(parts[k], cold[k], polish, cal, truncation_px) for k in (0, 1)]
                from_whole += [f"half {k + 1} {name}" for k in (0, 1) if better[k] is not cold[k]]
                diffs = differences(*better)
        compared.append(diffs)
    report = replace(report, timings_s={**report.timings_s, "halves": time.perf_counter() - t0})
    if not compared:
        return replace(cal, report=replace(report, halves=HalvesCheck(0, reason=why, ruled_out=tuple(dismissed))))
    return _widened_by(replace(cal, report=report), widest(compared), len(compared), tuple(dismissed),
                       tuple(from_whole))


def _disagree(diffs: dict[str, HalfDifference]) -> bool:
    """Whether the halves differ anywhere beyond their sigmas: one parameter, or all of them together."""
    return any(d.disagrees for d in diffs.values()) or sigma_factor(diffs) > 1.0


def _better(part: Observations, cold: Calibration, polish: Callable[[Observations, Calibration], Calibration],
            whole: Calibration, truncation_px: float) -> Calibration:
    """Of a half's `cold` solution and its solution from the `whole`'s start, the one of lower MSAC cost on the
    half's observations `part` (truncated at `truncation_px`), by more than one observation's expected cost (less
    is the solver's tolerance: two solutions that close are one); `cold` where the other cannot be had or leaves
    out a camera `cold` placed."""
    try:
        warm = polish(part, whole)
    except SolveError:
        return cold
    if {c.id for c in cold.cameras} - {c.id for c in warm.cameras}:
        return cold
    one = 2.0 * whole.uncertainty.sigma_px**2  # px^2, two axes
    return warm if msac_cost(part, warm, truncation_px) < msac_cost(part, cold, truncation_px) - one else cold


def unsolved_half(cal: Calibration, halves: tuple[tuple[Observations, Calibration], ...], truncation_px: float) -> str:
    """How a half's own solution falls short of the whole `cal`'s on that half's tracks (the module docstring's
    rule), or "" where each half's fits it as well or better. halves: (that half's observations, its solution)
    each; costs MSAC's, truncated at `truncation_px`."""
    sigma = cal.uncertainty.sigma_px if cal.uncertainty is not None else np.nan
    if not np.isfinite(sigma) or sigma <= 0.0:
        return ""
    for k, (part, half) in enumerate(halves):
        short = msac_cost(part, half, truncation_px) - msac_cost(part, cal, truncation_px)
        noise = cost_noise_px2(sigma, half.report.inliers if half.report is not None else 0)
        if short > NEAR_COST_SIGMAS * noise:
            return (f"the whole's solution fits half {k + 1} better than that half's own, by {short / noise:.0f} "
                    "times the noise's spread of a cost: its cold solve fell short of its own minimum")
    return ""


def with_check_carried(cal: Calibration, check: HalvesCheck) -> Calibration:
    """`cal` widened by an earlier halves `check` of the same rig (the live calibrator asks for a second opinion
    only once the pool has turned over: in between, the last one's half-differences still hold)."""
    report = cal.report
    if report is None or report.uncertainty is None:
        return cal
    if not check.splits:
        return replace(cal, report=replace(report, halves=check))
    # Each difference's sigma back from its half and its ratio (infinite where the ratio was 0: none needed).
    diffs = {name: HalfDifference(half, half / check.in_sigmas[name] if check.in_sigmas.get(name) else np.inf)
             for name, half in check.half_differences.items()}
    return _widened_by(cal, diffs, check.splits, check.ruled_out, check.from_whole)


def _widened_by(cal: Calibration, diffs: dict[str, HalfDifference], splits: int,
                ruled: tuple[str, ...] = (), from_whole: tuple[str, ...] = ()) -> Calibration:
    """`cal` with its sigmas widened to the halves' `diffs`, the check in its report (`ruled`: the splits ruled
    out; `from_whole`: the halves compared at their solution from the whole's start), any disagreement warned."""
    report = cal.report
    uncertainty, raised, factor = widened(report.uncertainty, cal, diffs)
    check = HalvesCheck(splits, {k: d.half for k, d in diffs.items()}, {k: d.in_sigmas for k, d in diffs.items()},
                        raised, factor, ruled_out=ruled, from_whole=from_whole)
    said = raised or factor > 1.0
    warnings = report.warnings + ((disagreement_warning(diffs, raised, factor),) if said else ())
    floor = cal.floor_frame
    if floor is not None and floor.found:  # a floor's sigmas rest on the same covariance as every other
        floor = replace(floor, normal_sigma_deg=factor * floor.normal_sigma_deg,
                        height_sigma_m=factor * floor.height_sigma_m)
    return replace(cal, report=replace(report, uncertainty=uncertainty, halves=check, warnings=warnings),
                   floor_frame=floor)
