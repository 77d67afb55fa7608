"""How a calibration is solved (`Method`) and the robust loss of its first adjustment (`Loss`): named apart
from the model's arrays, so that a command line can offer them without importing numpy (``camnet calibrate
--help``)."""

from __future__ import annotations

from enum import StrEnum


class Method(StrEnum):
    """How a calibration was solved (see camnet.solve.pipeline)."""

    PAPER = "paper"
    REFINED = "refined"
    UNCONSTRAINED = "unconstrained"


class Loss(StrEnum):
    """The robust losses of the adjustment (scipy.optimize.least_squares' names)."""

    LINEAR = "linear"
    HUBER = "huber"
    SOFT_L1 = "soft_l1"
    CAUCHY = "cauchy"
