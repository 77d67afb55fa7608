"""Which cameras the two-view checks (camnet.model.pair_pose_check) find out of place, and how it is said.

A pair disagrees when its solved relative pose fits its own two views
worse than the rig's other pairs do theirs: beyond DISAGREE_FACTOR times
the median excess of the pairs without the camera judged (real features fit
their two views a few times worse than their noise allows, by a factor the
rig's pairs share) and beyond MIN_DISAGREE in any case. The camera to blame
is the one that disagrees with most of its neighbours: a camera placed
wrong disagrees with every pair it is in, its neighbours only with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camnet.errors import in_words
from camnet.model.calibration import PairPoseCheck

DISAGREE_FACTOR = 8.0
MIN_DISAGREE = 10.0  # sigmas: a chi-square of 5 degrees of freedom reaches 100 once in 1e19


@dataclass(frozen=True)
class PairVerdict:
    """named: camera id -> its disagreeing pairs, for each camera that disagrees with more than half of its
    checked neighbours; unexplained: disagreeing pairs neither of whose cameras is named."""

    named: dict[str, tuple[PairPoseCheck, ...]]
    unexplained: tuple[PairPoseCheck, ...]


def bound(checks: list[PairPoseCheck]) -> float:
    """The excess (in sigmas) beyond which a pair disagrees, from the typical excess of `checks`."""
    typical = float(np.median([c.in_sigmas for c in checks])) if checks else 0.0
    return max(MIN_DISAGREE, DISAGREE_FACTOR * typical)


def judge_pairs(checks: tuple[PairPoseCheck, ...]) -> PairVerdict:
    """The cameras to blame, most disagreeing share first. A camera's pairs are judged against the rig's pairs
    without it (a camera placed wrong spoils every pair it is in, and on a small rig that is many of them);
    each named camera's pairs are then set aside, so that a neighbour is not blamed for it."""
    left = list(checks)
    named: dict[str, tuple[PairPoseCheck, ...]] = {}
    while True:
        shares = {}
        for cam in sorted({c for check in left for c in (check.first, check.second)}):
            mine = [c for c in left if cam in (c.first, c.second)]
            beyond = bound([c for c in left if cam not in (c.first, c.second)])
            against = tuple(c for c in mine if c.in_sigmas > beyond)
            if len(mine) >= 2 and 2 * len(against) > len(mine):
                shares[cam] = (len(against) / len(mine), len(against), against)
        if not shares:
            break
        cam = max(shares, key=lambda c: shares[c][:2])
        named[cam] = shares[cam][2]
        left = [c for c in left if cam not in (c.first, c.second)]
    beyond = bound(left)
    return PairVerdict(named, tuple(c for c in left if c.in_sigmas > beyond))


def describe(pairs: tuple[PairPoseCheck, ...]) -> str:
    """How far the solved poses lie from the two-view ones, in words."""
    return (f"rotation up to {max(c.rotation_deg for c in pairs):.2f} deg and baseline direction up to "
            f"{max(c.direction_deg for c in pairs):.1f} deg off")


def pair_warnings(checks: tuple[PairPoseCheck, ...]) -> list[str]:
    """One warning per named camera and per unexplained pair."""
    verdict = judge_pairs(checks)
    out = []
    for cam, pairs in verdict.named.items():
        others = [c.second if c.first == cam else c.first for c in pairs]
        out.append(f"camera {cam}: its pose disagrees with its own two views with {in_words(others, noun='camera')} "
                   f"({describe(pairs)}): it is likely placed wrong; add a frame set, or give its K")
    for c in verdict.unexplained:
        out.append(f"cameras {c.first} and {c.second}: their relative pose disagrees with their own two views "
                   f"({describe((c,))}); one of them is likely placed wrong")
    return out
