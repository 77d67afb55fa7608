"""A solve's starting values (the cameras' focal lengths and poses, the points) and how the scale pair was placed.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (camnet.solve.context.centred). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np

MIN_REGISTRATION_POINTS = 6  # a DLT has 11 degrees of freedom


class PairStart(Enum):
    """How a cold start places the scale pair (camnet.solve.start.cold)."""

    AUTO = "auto"  # the paper's where the pair's matches lie on matching rows, else the essential matrix
    PAPER = "paper"  # the paper's solver
    ESSENTIAL = "essential"  # the pair's essential matrix, its focal lengths from a third view
    # The two cameras that share the most tracks, placed by their essential matrix; every camera through the
    # view graph from them; then the scale pair's frame and distance (a scale pair that sees little together).
    STRONGEST = "strongest pair"


@dataclass
class Start:
    f: np.ndarray  # (M,) focal lengths, px
    R: np.ndarray  # (M, 3, 3)
    C: np.ndarray  # (M, 3) centres, m
    X: np.ndarray  # (T, 3) points, m; NaN where unknown
    registered: np.ndarray  # (M,) bool
    P0: np.ndarray  # (T, 3) the paper's stereo cloud (f_left = 1, unit baseline); NaN where unknown
    k: float  # f_right / f_left
    parallel: bool = True  # the pair is the paper's ideal parallel pair, to start with
    left_out: dict[str, str] = field(default_factory=dict)  # camera id -> why it could not be placed
    pair: PairStart | None = None  # how a cold start placed the scale pair (never AUTO); None: a warm start
