"""A solve's outcome: the calibration, and the adjustment's own state beside it for a caller that goes on
(a warm start, the live policy's checks, the benchmarks)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.model.calibration import Calibration
from camnet.solve.bundle import Problem, State
from camnet.solve.start.state import PairStart
from camnet.solve.uncertainty import Covariance


@dataclass(frozen=True)
class Result:
    """A solve's outcome. converged, reason: the final adjustment's (also in the calibration's report)."""

    calibration: Calibration
    state: State  # cameras in problem order: left, right, then the others
    problem: Problem  # inlier observations
    order: tuple[int, ...]  # problem camera m is observations camera order[m]
    track_rows: np.ndarray  # problem point j is track row track_rows[j]
    covariance: Covariance | None
    converged: bool
    reason: str
    timings_s: dict[str, float]
    pair_start: PairStart | None = None  # how the cold start placed the scale pair; None for a warm start
