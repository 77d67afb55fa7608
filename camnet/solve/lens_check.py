"""A second opinion on lenses nobody described: the solve again with their k1 free, and what that moves.

A solve with an explicit free set that leaves distortion out (a live rig's,
camnet.live.policy.LIVE_FREE) holds the lens of a camera nobody gave a
`dist` for straight. A webcam's lens bends its image by several percent at
the edge; held straight, its focal length and its distance from the scene
take the bend up together, beyond their sigmas, and the RMS does not show
it. So the solution is solved on with k1 free for those cameras (all at
once, then each alone, which costs a warm solve a camera), and a
focal length that then moves by more than SHIFT_SIGMAS of its sigma
(camnet.solve.report.lens_shifts) is warned of, and the verdict rates its
camera poor (`SolveReport.lens_shifts`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from camnet.errors import SolveError
from camnet.model.calibration import Calibration, LensShift
from camnet.model.camera import LensModel
from camnet.model.observations import Observations
from camnet.solve.options import Options
from camnet.solve.report.lens_shifts import lens_warnings


def undescribed(obs: Observations, cal: Calibration, options: Options) -> list[str]:
    """The placed pinhole cameras of `cal` whose distortion nobody gave and `options` hold at none."""
    if isinstance(options.free, str) or "k1" in options.free:
        return []  # the automatic rule frees k1 where the data ask; a free set with k1 frees it
    placed = {c.id for c in cal.cameras}
    return [c.id for c in obs.cameras if c.id in placed and c.model == LensModel.PINHOLE and c.dist is None]


def with_lens_check(obs: Observations, cal: Calibration, options: Options,
                    solve: Callable[[Observations, Options, Calibration], Calibration]) -> Calibration:
    """`cal` (solved from `obs` with `options`) with `lens_shifts` in its report, where a camera's lens was held
    straight unknown; a warning names each focal length that moves beyond its sigmas with its k1 free.

    solve(obs, options, initial): the solve of `obs` with `options` warm from `initial`; raises SolveError where
    it cannot (the check is then not made).
    """
    report = cal.report
    cameras = undescribed(obs, cal, options)
    if report is None or not cameras:
        return cal
    t0 = time.perf_counter()
    shifts: dict[str, LensShift] = {}
    # Every lens free at once, then each alone (the others held straight): where every lens bends, one camera's
    # move can hide in the others' and show alone, or the other way round; the larger move is kept.
    for freed_ids in ([cameras] + [[c] for c in cameras] if len(cameras) > 1 else [cameras]):
        for camera_id, shift in _shifts(obs, cal, options, freed_ids, solve).items():
            if camera_id not in shifts or shift.in_sigmas > shifts[camera_id].in_sigmas:
                shifts[camera_id] = shift
    timings = {**report.timings_s, "lens_check": time.perf_counter() - t0}
    return with_lens_carried(replace(cal, report=replace(report, timings_s=timings)), shifts)


def _shifts(obs: Observations, cal: Calibration, options: Options, freed_ids: list[str],
            solve: Callable[[Observations, Options, Calibration], Calibration]) -> dict[str, LensShift]:
    """How the focal lengths of cameras `freed_ids` move when `cal` is solved on with their k1 free and every
    other undescribed lens held straight (given as none); {} where that solve fails."""
    held_straight = tuple(replace(c, dist=np.zeros(5), fixed=c.fixed | {"dist"})
                          if c.dist is None and c.id not in freed_ids else c for c in obs.cameras)
    try:
        freed = solve(replace(obs, cameras=held_straight),
                      replace(options, free=frozenset(options.free) | {"k1"}, halves=False), cal)
    except SolveError:
        return {}
    held = {c.id: c for c in cal.cameras}
    shifts = {}
    for camera in freed.cameras:
        sigmas = freed.report.uncertainty.cameras.get(camera.id) if freed.report.uncertainty else None
        if camera.id not in freed_ids or sigmas is None or not sigmas.f_px > 0:
            continue
        f_held, f_free = held[camera.id].K[0, 0], camera.K[0, 0]
        shifts[camera.id] = LensShift(float(f_free / f_held - 1), float(abs(f_free - f_held) / sigmas.f_px),
                                      float(camera.dist[0]))
    return shifts


def with_lens_carried(cal: Calibration, shifts: dict[str, LensShift] | None) -> Calibration:
    """`cal` with lens `shifts` found of it or of an earlier solve of the same rig (the live calibrator checks only
    when it asks for a second opinion), and a warning where a focal length moved beyond its sigmas."""
    report = cal.report
    if report is None or shifts is None:
        return cal
    warnings = report.warnings + tuple(lens_warnings(shifts))
    return replace(cal, report=replace(report, lens_shifts=dict(shifts), warnings=warnings))
