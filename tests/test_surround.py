"""config/surround.yaml: the matcher finds true tracks between ring neighbours of the simulated person."""

from __future__ import annotations

import numpy as np
from camnet.drivers.base import create_camera

from camnet.io.rig import load_rig
from camnet.matching.features import MatcherConfig, match_frame_set
from tests._groundtruth import epipolar_distance_px
from tests.test_rig import CONFIG

# The head, its two ring neighbours (45 degrees) and the camera opposite.
CAMERAS = ("head_left", "head_right", "ring1", "ring7", "ring4")


def test_ring_neighbours_share_true_matches(record_property):
    rig = load_rig(CONFIG / "surround.yaml")
    truth = {c.id: c for c in rig.simulated_truth()}
    images = {c: create_camera(rig.camera(c), rig).render(4) for c in CAMERAS}
    matches = match_frame_set(images, MatcherConfig(), stereo=rig.stereo)
    ids = matches.camera_ids
    found = {}
    for pair in matches.pairs:
        a, b = ids[pair.a], ids[pair.b]
        uv_a, uv_b = matches.features[pair.a].uv[pair.index_a], matches.features[pair.b].uv[pair.index_b]
        d = epipolar_distance_px(uv_a, uv_b, truth[a], truth[b])
        found[a, b] = found[b, a] = (len(pair), float(np.mean(d < 1.0)) if len(d) else float("nan"))
    record_property("pairs", found)
    assert found["head_left", "head_right"][0] >= 800 and found["head_left", "head_right"][1] >= 0.98
    for neighbour in ("ring1", "ring7"):
        for head_camera in ("head_left", "head_right"):
            count, on_line = found[head_camera, neighbour]
            assert count >= 60 and on_line >= 0.9, (head_camera, neighbour, count, on_line)


def test_a_pair_with_a_handful_of_inliers_contributes_nothing():
    # Views 90 degrees apart across the person: what F-RANSAC keeps of them is mostly false.
    rig = load_rig(CONFIG / "surround.yaml")
    truth = {c.id: c for c in rig.simulated_truth()}
    images = {c: create_camera(rig.camera(c), rig).render(4) for c in ("ring1", "ring7")}
    few = match_frame_set(images, MatcherConfig(min_matches=8))
    (pair,) = few.pairs
    d = epipolar_distance_px(few.features[0].uv[pair.index_a], few.features[1].uv[pair.index_b],
                             truth["ring1"], truth["ring7"])
    assert 8 <= len(pair) < MatcherConfig().min_matches and np.mean(d < 1.0) < 0.5
    assert len(match_frame_set(images, MatcherConfig()).pairs[0]) == 0
