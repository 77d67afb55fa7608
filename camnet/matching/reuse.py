"""Matching frame set after frame set without matching the same background again.

A camera's keypoints carry which of them are reused from its keyframe
(`camnet.matching.edge.CameraFeatures`): static background, matched already.
Once a pair of cameras has been matched whole with their current keyframes,
later frame sets match only what is new: the new keypoints of one camera
against the new keypoints of the other. A keypoint is reused where the
image did not change since the keyframe, so a point of the moving scene is
new in every camera that sees it; a new keypoint's partner among the other
camera's reused ones is static background re-detected inside the box of
change, whose track the whole match pooled already. Matching new against
new only costs a ninth of a whole match where a third of the keypoints are
new, instead of more than half. A new keyframe on either side (a camera
moved, the light changed, or simply its period came round) matches the pair
whole again.

New keypoints are often few (the part of the scene that moved), too few for
RANSAC to find F alone. The rig is static, so the pair's F from its last
whole match still holds: candidates within `ransac_threshold_px` of its
epipolar lines are kept when at least half of them are, otherwise the pair
gives nothing this time (a moved camera then gets a new keyframe and a new F).

A keyframe detects the whole image again, the same background included.
`IncrementalMatcher.prepare` marks what the matcher saw of a camera before
(`camnet.matching.seen`): a keyframe that shows the same scene from the same
place continues its camera's epoch, and its pairs are matched on what
changed, not whole. A pair without an F (never matched, or matched without
one: most explored pairs) is probed on a quarter of one camera's keypoints
before it is matched whole.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from camnet import blas
from camnet.matching import nearest
from camnet.matching.edge import CameraFeatures
from camnet.matching.features import (
    Detector,
    Features,
    FrameSetMatches,
    MatcherConfig,
    PairMatches,
    candidate_matches,
    match_pair,
    ransac_fundamental,
)
from camnet.matching.seen import SeenBefore
from camnet.model.observations import Stereo

log = logging.getLogger(__name__)

MIN_AGREEING = 0.5  # of the new candidates within the old F's threshold, to trust the old F
# A pair with no F (never matched, or its last whole match found none: most of the pairs a view graph explores)
# is first matched on every PROBE_EVERYth keypoint of one camera, and whole only if that finds an F with
# PROBE_INLIERS inliers: a pair that matches well (40 inliers or more) has about a quarter of them in the probe.
PROBE_EVERY = 4
PROBE_INLIERS = 10


@dataclass(frozen=True)
class PairState:
    """What a pair of cameras was last matched whole with: both keyframes, its F (b against a) and inliers."""

    keyframes: tuple[int, int]
    F: np.ndarray
    inliers: int = 0


def _subset(features: Features, index: np.ndarray) -> Features:
    return Features(features.uv[index], features.descriptors[index], features.detector)


def _new_candidates(fa: CameraFeatures, fb: CameraFeatures, config: MatcherConfig, *, prior: bool,
                    operands: tuple[nearest.Operands, nearest.Operands] | None) -> tuple[np.ndarray, np.ndarray]:
    """Candidates (indices into a and b) between the new keypoints of a and of b."""
    new_a, new_b = np.arange(fa.reused, len(fa.features)), np.arange(fb.reused, len(fb.features))
    ia, ib = candidate_matches(_subset(fa.features, new_a), _subset(fb.features, new_b), config, stereo_prior=prior,
                               operands=operands)
    return new_a[ia].astype(np.int64), new_b[ib].astype(np.int64)


def epipolar_inliers(F: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray, threshold_px: float) -> np.ndarray:
    """Boolean (m,): matches within `threshold_px` (Sampson distance) of F's epipolar geometry."""
    if len(uv_a) == 0:
        return np.zeros(0, dtype=bool)
    # OpenCV's sampsonDistance takes one point pair at a time; this is its vector form.
    xa = np.column_stack([uv_a, np.ones(len(uv_a))])
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    Fxa, Ftxb = xa @ F.T, xb @ F
    num = np.einsum("ij,ij->i", xb, Fxa) ** 2
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    return num <= threshold_px**2 * np.maximum(den, 1e-300)


class IncrementalMatcher:
    """Matches the frame sets of one static rig in order, remembering what each pair has matched.

    Not thread-safe: the matcher node owns one. Memory: one `PairState` per pair.
    """

    def __init__(self, config: MatcherConfig | None = None, *, stereo: Stereo | None = None,
                 probe_every: int = PROBE_EVERY) -> None:
        self.config = MatcherConfig() if config is None else config
        self.stereo = stereo
        self._pairs: dict[tuple[str, str], PairState] = {}
        self.whole = 0  # pairs matched whole
        self.incremental = 0  # pairs matched on their new keypoints only
        self.probed = 0  # pairs with no F probed on a share of their keypoints (`_probe`)
        self.compared = 0  # keypoint comparisons: rows times columns of the pairs' descriptor products
        self.probe_every = probe_every
        self._probe_config = replace(self.config, min_matches=PROBE_INLIERS)
        self.seen = SeenBefore()
        # Per camera of the frame set `prepare` took: its new keypoints' descriptors as distance operands,
        # made once for all of its pairs (a camera has about 3 on a ring).
        self._operands: dict[str, tuple[CameraFeatures, nearest.Operands]] = {}

    def forget(self, camera_id: str) -> None:
        """Match every pair of `camera_id` whole next time."""
        self._pairs = {k: v for k, v in self._pairs.items() if camera_id not in k}
        self.seen.forget(camera_id)

    def prepare(self, cameras: Sequence[CameraFeatures]) -> list[CameraFeatures]:
        """The cameras of a frame set with what this matcher has seen of them before marked as reused, and
        a keyframe that continues its camera's epoch in it (`camnet.matching.seen`). Once per frame set, in
        order, before `match`; matching the cameras as they come instead matches every keyframe's pairs whole."""
        marked = [self.seen.mark(camera) for camera in cameras]
        self._operands = {c.camera_id: (c, nearest.operands(c.features.descriptors[c.reused:], binary=False))
                          for c in marked if c.features.detector is Detector.SIFT}  # ORB's go to OpenCV's matcher
        return marked

    def _new_operands(self, fa: CameraFeatures,
                      fb: CameraFeatures) -> tuple[nearest.Operands, nearest.Operands] | None:
        """The operands `prepare` made of these very cameras' new keypoints (None: it did not)."""
        made = []
        for camera in (fa, fb):
            prepared, ops = self._operands.get(camera.camera_id, (None, None))
            if prepared is not camera:
                return None
            made.append(ops)
        return made[0], made[1]

    def matched_well(self, min_inliers: int) -> set[frozenset[str]]:
        """Pairs whose last whole match found an F with at least `min_inliers` inliers."""
        return {frozenset(k) for k, state in self._pairs.items() if state.inliers >= min_inliers}

    def match(self, cameras: Sequence[CameraFeatures], *, pairs: Collection[frozenset[str]] | None = None,
              seed: int = 0) -> FrameSetMatches:
        """Match `pairs` of cameras (frozensets of two ids; None: every pair) of one frame set."""
        cv2.setRNGSeed(seed)
        ids = tuple(c.camera_id for c in cameras)
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate camera ids in frame set: {ids}")
        stereo = self.stereo
        use_prior = stereo is not None and stereo.parallel and self.config.use_stereo_prior
        out = []
        # The distance products of a pair are a few thousand rows: BLAS threads save no wall time on them
        # but double the CPU, spinning beside the other nodes (docs/benchmarks.md, "The matcher").
        # The pairs asked for, in the order of the cameras: the node asks one pair per call, which must not walk
        # every pair of a large rig (docs/benchmarks.md, "Evidence behind the nodes' choices").
        index = {camera_id: k for k, camera_id in enumerate(ids)}
        todo = ([(i, j) for i in range(len(ids)) for j in range(i + 1, len(ids))] if pairs is None else
                sorted({tuple(sorted(index[c] for c in pair)) for pair in pairs if pair <= index.keys()}))
        with blas.one_thread():
            for i, j in todo:
                # A parallel head is matched with its left camera as `a`: the disparity's sign depends on it.
                a, b = (j, i) if use_prior and (ids[j], ids[i]) == (stereo.left, stereo.right) else (i, j)
                prior = use_prior and (ids[a], ids[b]) == (stereo.left, stereo.right)
                out.append(self._match_pair(cameras[a], cameras[b], a, b, prior=prior))
        return FrameSetMatches(ids, tuple(c.features for c in cameras), tuple(out))

    def _match_pair(self, fa: CameraFeatures, fb: CameraFeatures, a: int, b: int, *, prior: bool) -> PairMatches:
        config = self.config
        key = (fa.camera_id, fb.camera_id)
        state = self._pairs.get(key)
        keyframes = (fa.keyframe_seq, fb.keyframe_seq)
        empty = np.empty(0, dtype=np.int64)
        if state is None and not self._probe(fa.features, fb.features, prior=prior):
            return PairMatches(a, b, empty, empty, None, 0)
        if state is None or state.keyframes != keyframes:
            matched = match_pair(fa.features, fb.features, config, stereo_prior=prior, a=a, b=b)
            self.compared += len(fa.features) * len(fb.features)
            self.whole += 1
            if matched.F is None:
                self._pairs.pop(key, None)
            else:
                self._pairs[key] = PairState(keyframes, matched.F, len(matched))
            return matched
        self.incremental += 1
        ia, ib = _new_candidates(fa, fb, config, prior=prior, operands=self._new_operands(fa, fb))
        self.compared += (len(fa.features) - fa.reused) * (len(fb.features) - fb.reused)
        inliers = epipolar_inliers(state.F, fa.features.uv[ia], fb.features.uv[ib], config.ransac_threshold_px)
        if len(ia) == 0 or inliers.mean() < MIN_AGREEING:
            log.debug("pair %s-%s: %d of %d new candidates on the old F", *key, int(inliers.sum()), len(ia))
            return PairMatches(a, b, empty, empty, None, len(ia))
        return PairMatches(a, b, ia[inliers], ib[inliers], state.F, len(ia))

    def _probe(self, fa: Features, fb: Features, *, prior: bool) -> bool:
        """Whether a pair with no F yet is worth matching whole: every `probe_every`th keypoint of `fa`
        against all of `fb` finds an F with at least `PROBE_INLIERS` inliers."""
        if self.probe_every <= 1:
            return True
        rows = np.arange(0, len(fa), self.probe_every)
        ia, ib = candidate_matches(_subset(fa, rows), fb, self.config, stereo_prior=prior)
        self.compared += len(rows) * len(fb)
        self.probed += 1
        if len(ia) < PROBE_INLIERS:
            return False
        F, inliers = ransac_fundamental(fa.uv[rows[ia]], fb.uv[ib], self._probe_config)
        return F is not None and int(inliers.sum()) >= PROBE_INLIERS
