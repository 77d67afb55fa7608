"""Calibrated sites placed in one metric space: each site's floor frame set on a shared floor.

A site is a calibration written in its floor frame (camnet.model.calibration.FloorFrame: Z up, origin on the
floor below the centre of its capture volume, X toward the rig's front, metres). The meeting frame is site A's
floor frame: right-handed, Z up, the floors coinciding at z = 0. A site's placement is ``X_meeting = R @ X_site +
t`` with R a turn about Z, so that a floor stays a floor and up stays up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FACING = "facing"  # each site's front toward the other's, their origins `distance_m` apart along A's X
LAYOUTS = (FACING,)


@dataclass(frozen=True)
class Layout:
    """How sites stand to each other: `kind` (one of LAYOUTS) at `distance_m` (metres, positive)."""

    kind: str
    distance_m: float


@dataclass(frozen=True)
class Placement:
    """One site's floor frame in the meeting frame: ``X_meeting = R @ X_site + t`` (R 3x3 about Z, t metres)."""

    R: np.ndarray
    t: np.ndarray


def turn_about_z(angle_rad: float) -> np.ndarray:
    """The rotation by `angle_rad` (counter-clockwise seen from above) about the Z (up) axis."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def placements(layout: Layout, sites: int) -> tuple[Placement, ...]:
    """Each of `sites` sites' placement under `layout`.

    facing (two sites): A where it stands (the meeting frame is its floor frame); B turned half a turn about Z
    with its origin at (distance_m, 0, 0), so that a person at each site's origin looking toward their rig's
    front (+X of their floor frame) looks at the other, `distance_m` away.
    """
    if layout.kind != FACING:
        raise ValueError(f"unknown layout {layout.kind!r}")
    if sites != 2:
        raise ValueError(f"the facing layout places two sites, not {sites}")
    return (Placement(np.eye(3), np.zeros(3)), Placement(turn_about_z(np.pi), np.array([layout.distance_m, 0.0, 0.0])))
