"""Chaining pairwise matches into tracks."""

from __future__ import annotations

import numpy as np

from camnet.matching.features import Detector, Features, FrameSetMatches, PairMatches
from camnet.matching.tracks import build_tracks


def _features(n: int, cam: int) -> Features:
    uv = np.c_[np.arange(n) * 10.0 + cam, np.full(n, 100.0 * cam)]
    return Features(uv, np.zeros((n, 128), np.float32), Detector.SIFT)


def _pair(a: int, b: int, pairs: list[tuple[int, int]]) -> PairMatches:
    ia, ib = (np.array(x, dtype=np.int64) for x in zip(*pairs, strict=True))
    return PairMatches(a, b, ia, ib, np.eye(3), len(pairs))


def test_chains_consistent_components_and_drops_a_camera_seen_twice():
    feats = tuple(_features(6, c) for c in range(3))
    pairs = (
        _pair(0, 1, [(0, 0), (1, 1), (3, 3)]),
        _pair(1, 2, [(0, 0), (1, 2), (4, 4)]),
        # 1-1 chains to cam-2 kp 2 via cam 1, but cam 0 kp 1 also matches cam-2 kp 3
        _pair(0, 2, [(0, 0), (1, 3)]),
    )
    tracks = build_tracks(FrameSetMatches(("a", "b", "c"), feats, pairs))
    assert tracks.dropped_inconsistent == 1
    assert sorted(tracks.views.tolist()) == [2, 2, 3]
    full = tracks.uv[tracks.views == 3][0]
    assert np.allclose(full[:, 0], [0.0, 1.0, 2.0])  # keypoint 0 in every camera
    # the 2-view tracks: (a3, b3) and (b4, c4)
    two = tracks.uv[tracks.views == 2]
    seen = {tuple(np.isfinite(t[:, 0]).tolist()) for t in two}
    assert seen == {(True, True, False), (False, True, True)}


def test_no_matches_gives_no_tracks():
    feats = tuple(_features(3, c) for c in range(2))
    empty = np.empty(0, dtype=np.int64)
    tracks = build_tracks(FrameSetMatches(("a", "b"), feats, (PairMatches(0, 1, empty, empty, None, 0),)))
    assert len(tracks) == 0
    assert tracks.uv.shape == (0, 2, 2)
