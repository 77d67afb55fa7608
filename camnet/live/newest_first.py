"""A long pool's cold solve: its newest tracks first, then the whole pool warm from their solution.

A track pool (camnet.matching.pool) numbers its tracks in time and keeps
the newest; its oldest tracks are the falsest, so a cold solve of a whole
long pool can place cameras wrong that a solve started on its newest
tracks places right (docs/benchmarks.md, "The surround rig, live";
benchmarks/bench_cold_pool.py). The live calibrator (camnet.live.tracker)
and `camnet calibrate` both start a long pool so (`solve_newest_first`),
each solve judged by the live policy's check and solved again without the
cameras it finds placed wrong (camnet.live.judged_solve).

Ids are only an order of preference here: the whole pool is what is solved
in the end, and a caller falls back to the whole pool solved cold. Where a
file's ids say nothing of age, its "newest" tracks are merely a subset.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import partial

import numpy as np

from camnet.live.judged_solve import Check, Judged, Status, solve_judged
from camnet.live.moved_cameras import without_cameras
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.solve import Options

# A pool of at least twice as many tracks starts on its newest this many (the matcher's pool of 5000
# is full after two frame sets of nine cameras). A smaller pool is of a frame set or two, whose ids
# say nothing of age: starting it on its newest tracks only costs time (docs/benchmarks.md,
# "Evidence behind the solver's thresholds").
START_TRACKS = 2500


def newest_tracks(obs: Observations, count: int) -> Observations:
    """`obs` with only its `count` newest tracks (the largest ids: a pool numbers them in time)."""
    keep = np.zeros(len(obs.track_ids), dtype=bool)
    keep[np.argsort(obs.track_ids, kind="stable")[-count:]] = True
    rows = keep[obs.track_index]
    new_row = np.cumsum(keep) - 1
    return replace(obs, track_ids=obs.track_ids[keep], cam_index=obs.cam_index[rows],
                   track_index=new_row[obs.track_index[rows]], uv=obs.uv[rows])


def solve_newest_first(obs: Observations, options: Options, check: Check, *, start: Calibration | None = None,
                       start_tracks: int = START_TRACKS, leave_out: Mapping[str, str] | None = None) -> Judged:
    """A pool solved from `start` (None: cold) as the live calibrator solves one without a good calibration.

    A pool of at least twice `start_tracks` tracks is solved on its newest `start_tracks` first, the whole
    pool warm from there; where that is short or not good, the whole pool from `start`. Every solve is
    judged by `check` (`judged_solve.solve_judged`: without the cameras it finds placed wrong, named), and
    without the cameras of `leave_out` from the start, named with why.
    """
    if leave_out:
        obs = without_cameras(obs, leave_out)  # before the newest tracks are chosen: those that keep 2 views
    solve = partial(solve_judged, options=options, check=check, leave_out=leave_out)
    if len(obs.track_ids) >= 2 * start_tracks:
        # Only a start: the second opinion is the whole pool's to ask.
        seed = solve(newest_tracks(obs, start_tracks), start, options=replace(options, halves=False))
        if seed.status == Status.GOOD:
            whole = solve(obs, seed.calibration)
            if whole.status == Status.GOOD:
                return whole
    return solve(obs, start)
