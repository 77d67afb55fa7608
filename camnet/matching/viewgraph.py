"""Which pairs of a frame set to match: every pair at a cold start, then the view graph.

Matching every pair costs M(M-1)/2 pair matches per frame set; on a ring a
camera shares its view with a few neighbours only. Once the rig has a
calibration, a frame set matches:

- the pairs whose frusta overlap in the scene's depth range
  (`camnet.model.overlap.overlapping_pairs`, from the calibration's
  cameras and points);
- the pairs that matched well before (at least `good_matches` inliers in
  their last whole match), wherever the geometry puts them, but only where
  both cameras have fewer than `neighbours` partners so far: where every
  camera sees every other (an arc around one object), every pair matched
  well at the cold start, and keeping them all would match M(M-1)/2 pairs
  for ever;
- every pair of a camera the calibration does not hold (new, or left out);
- the stereo pair, always;
- and `explore_per_set` of the other pairs, in rotation, so that a camera
  that moved, or a pair the geometry missed, is found again.

Without a calibration every pair is matched.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from camnet.model.calibration import Calibration
from camnet.model.overlap import MIN_PARTNERS, depth_ranges, overlapping_pairs

Pair = frozenset[str]


@dataclass(frozen=True)
class ViewGraphConfig:
    """How pairs are chosen once a calibration exists (see `camnet.model.overlap`)."""

    min_overlap: float = 0.05  # of either camera's frustum the other sees
    max_axis_angle_deg: float = 75.0  # optical axes further apart: features do not match across
    # Partners per camera by the geometry (at most neighbours * M / 2 pairs). 2 are, on a ring, each camera's
    # two neighbours, whose tracks chain into tracks of 3+ cameras through the middle one. Since keyframes match
    # what changed (camnet.matching.seen), 2 pool as many tracks seen by 3+ cameras as 3 and 4, for less CPU a
    # set, and calibrations from their pools differ from 3's by less than the spread between runs, well inside
    # the sigma reported (docs/benchmarks.md, "The matcher"; benchmarks/bench_matcher_stream.py --solve-every).
    neighbours: int = 2
    # Other pairs per frame set, in rotation. An explored pair without an F is probed on a quarter of one
    # camera's keypoints first (camnet.matching.reuse), and matched whole only where that finds one.
    explore_per_set: int = 1
    good_matches: int = 40  # inliers of a pair's last whole match that keep it matched

    def __post_init__(self) -> None:
        if self.neighbours < 1 or self.explore_per_set < 0 or self.good_matches < 0:
            raise ValueError("expected neighbours >= 1, explore_per_set >= 0 and good_matches >= 0")


def choose_pairs(camera_ids: Sequence[str], *, calibrated: Collection[str], overlapping: Collection[Pair],
                 matched_well: Collection[Pair] = (), always: Collection[Pair] = (), explore: int = 0,
                 cursor: int = 0, neighbours: int | None = None) -> tuple[set[Pair], int]:
    """The pairs of `camera_ids` to match in one frame set, and the exploration cursor for the next.

    Chosen: every pair with a camera not in `calibrated`, and every pair in
    `overlapping` or `always`; a pair in `matched_well` where both its
    cameras have fewer than `neighbours` partners so far (any, if None),
    giving each camera one such partner before any a second (a camera with
    fewer than 2 partners takes them whatever the other's); then
    `explore` of the remaining pairs (sorted by their ids), taken in rotation
    from `cursor`, so that frame set after frame set every remaining pair
    comes round.
    """
    all_pairs = [frozenset(p) for p in combinations(sorted(set(camera_ids)), 2)]
    chosen_from = set(overlapping) | set(always)
    chosen = {p for p in all_pairs if p in chosen_from or not p <= set(calibrated)}
    degree = Counter(camera for pair in chosen for camera in pair)
    well = sorted(set(matched_well) & set(all_pairs) - chosen, key=sorted)
    # Up to 1 partner a camera, then up to 2, ...: in id order alone, 4 cameras that all matched well but
    # overlap by none of the geometry, 2 partners each, left the last with none. A camera with fewer than
    # MIN_PARTNERS (one the calibration puts elsewhere, say) takes them whatever its partners have.
    def take(wanted: Callable[[list[int]], bool]) -> None:
        for pair in well:
            if pair not in chosen and wanted([degree[camera] for camera in pair]):
                chosen.add(pair)
                degree.update(pair)

    if neighbours is None:
        take(lambda have: True)
    else:
        for most in range(1, neighbours + 1):
            take(lambda have, most=most: max(have) < most)
        take(lambda have: min(have) < min(MIN_PARTNERS, neighbours))
    rest = sorted((p for p in all_pairs if p not in chosen), key=sorted)
    if explore <= 0 or not rest:
        return chosen, cursor
    chosen.update(rest[(cursor + k) % len(rest)] for k in range(min(explore, len(rest))))
    return chosen, cursor + explore


class ViewGraph:
    """The pairs to match, frame set after frame set, given the rig's latest calibration. Not thread-safe."""

    def __init__(self, config: ViewGraphConfig = ViewGraphConfig(), *, always: Collection[Pair] = ()) -> None:
        self.config = config
        self.always = set(always)
        self.calibrated: frozenset[str] = frozenset()
        self.overlapping: set[Pair] = set()
        self._cursor = 0

    def update(self, calibration: Calibration) -> None:
        """Take the pairs of a new calibration: its cameras' overlaps in its points' depth range."""
        c = self.config
        cameras = calibration.cameras
        pairs = overlapping_pairs(cameras, calibration.points, min_overlap=c.min_overlap,
                                  max_axis_angle_deg=c.max_axis_angle_deg, neighbours=c.neighbours)
        self.overlapping = {frozenset((cameras[i].id, cameras[j].id)) for i, j in pairs}
        # A camera that sees none of the points is matched with every camera, as a new one.
        seeing = np.isfinite(depth_ranges(cameras, calibration.points)).all(axis=1)
        self.calibrated = frozenset(cam.id for cam, sees in zip(cameras, seeing, strict=True) if sees)

    def pairs(self, camera_ids: Sequence[str], *, matched_well: Collection[Pair] = ()) -> set[Pair] | None:
        """The pairs of `camera_ids` to match now; None (every pair) before the first calibration."""
        if not self.calibrated:
            return None
        chosen, self._cursor = choose_pairs(camera_ids, calibrated=self.calibrated, overlapping=self.overlapping,
                                            matched_well=matched_well, always=self.always,
                                            explore=self.config.explore_per_set, cursor=self._cursor,
                                            neighbours=self.config.neighbours)
        return chosen
