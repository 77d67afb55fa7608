"""A solve's starting values (the cameras' focal lengths and poses, the points) and how the scale pair was placed.

Cameras are in problem order (left stereo camera, right stereo camera, then
the others in the order of the observations), points one per track row
(NaN where not yet known). Pixels handed to the solvers are *centred*:
relative to each camera's principal point, undistorted where the
distortion is known (camnet.solve.context.centred). Poses are ``x_cam = R (X - C)``, metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum
from types import MappingProxyType

import numpy as np

MIN_REGISTRATION_POINTS = 6  # a DLT has 11 degrees of freedom


class PairStart(Enum):
    """How a cold start places the scale pair (camnet.solve.start.cold)."""

    AUTO = "auto"  # the paper's where the pair's matches lie on matching rows, else the essential matrix
    PAPER = "paper"  # the paper's solver
    ESSENTIAL = "essential"  # the pair's essential matrix, its focal lengths from a third view
    # The two cameras that share the most tracks, placed by their essential matrix; every camera through the
    # view graph from them; then the scale pair's frame and distance (where they are not the scale pair).
    STRONGEST = "strongest pair"


@dataclass(frozen=True)
class Start:
    """A solve's starting values, read-only: a stage that places more makes a new Start (`working`, `placed`)."""

    f: np.ndarray  # (M,) focal lengths, px
    R: np.ndarray  # (M, 3, 3)
    C: np.ndarray  # (M, 3) centres, m
    X: np.ndarray  # (T, 3) points, m; NaN where unknown
    registered: np.ndarray  # (M,) bool
    P0: np.ndarray  # (T, 3) the paper's stereo cloud (f_left = 1, unit baseline); NaN where unknown
    k: float  # f_right / f_left
    parallel: bool = True  # the pair is the paper's ideal parallel pair, to start with
    left_out: Mapping[str, str] = field(default_factory=dict)  # camera id -> why it could not be placed
    pair: PairStart | None = None  # how a cold start placed the scale pair (never AUTO); None: a warm start

    def __post_init__(self) -> None:
        for name in ("f", "R", "C", "X", "registered", "P0"):
            array = np.array(getattr(self, name))  # its own copy: the caller's arrays may change after
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        object.__setattr__(self, "left_out", MappingProxyType(dict(self.left_out)))

    def working(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Writable copies of (f, R, C, X, registered), for a stage that places more cameras and points."""
        return self.f.copy(), self.R.copy(), self.C.copy(), self.X.copy(), self.registered.copy()

    def placed(self, f: np.ndarray, R: np.ndarray, C: np.ndarray, X: np.ndarray, registered: np.ndarray,
               **changes) -> Start:
        """This start with the cameras and points `f, R, C, X, registered` (and any other field changed)."""
        return replace(self, f=f, R=R, C=C, X=X, registered=registered, **changes)
