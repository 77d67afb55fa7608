"""The feature stage that detects only where the image changed, and matching only what is new.

On the simulated rig (config/sim.yaml: a box turning in front of a static
wall), frame sets half a second apart, checked against the ground truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from camnet.drivers.sim import create
from camnet.services.matcher import rig_stereo

from camnet.io.rig import load_rig
from camnet.matching.edge import CameraFeatures, EdgeConfig, FeatureExtractor
from camnet.matching.features import MatcherConfig
from camnet.matching.reuse import IncrementalMatcher
from camnet.matching.tracks import build_tracks
from tests._groundtruth import epipolar_distance_px, pairwise_epipolar_fractions

RIG = Path(__file__).resolve().parents[1] / "config" / "sim.yaml"
CAMERAS = ("left", "right", "mono_a")
SLOTS = (300, 315, 330)  # 30 fps: half a second apart


@pytest.fixture(scope="module")
def rig_images():
    rig = load_rig(RIG)
    cameras = {e.id: create(e, rig) for e in rig.cameras if e.id in CAMERAS}
    images = [{c: cameras[c].render(slot) for c in CAMERAS} for slot in SLOTS]
    truth = [cameras[c].config.camera(c) for c in CAMERAS]
    return rig, images, truth


def extract_all(images, *, edge=None):
    extractors = {c: FeatureExtractor(c, MatcherConfig(), edge) for c in CAMERAS}
    return [[extractors[c].extract(frame[c], seq=slot, timestamp_ns=slot) for c in CAMERAS]
            for slot, frame in zip(SLOTS, images, strict=False)], extractors


def test_static_background_is_reused_and_the_moving_box_detected_afresh(rig_images):
    _, images, _ = rig_images
    sets, extractors = extract_all(images)
    first, second = sets[0][0], sets[1][0]
    assert first.reused == 0 and first.keyframe_seq == SLOTS[0]
    assert second.keyframe_seq == SLOTS[0]
    # Most of the wall and floor stay; the box (a third to a half of the keypoints) is new.
    assert 0.3 * len(first.features) < second.reused < 0.9 * len(first.features)
    reused = second.features.uv[: second.reused]
    # Reused keypoints are the keyframe's, to the bit.
    index = {tuple(p) for p in first.features.uv}
    assert all(tuple(p) in index for p in reused)
    assert extractors["left"].partial == 2 and extractors["left"].full == 1


def test_a_frame_that_changed_everywhere_becomes_a_keyframe():
    extractor = FeatureExtractor("cam")
    rng = np.random.default_rng(0)
    a = (rng.random((256, 320)) * 255).astype(np.uint8)
    b = (rng.random((256, 320)) * 255).astype(np.uint8)
    assert extractor.extract(a, seq=1, timestamp_ns=1).keyframe_seq == 1
    assert extractor.extract(a, seq=2, timestamp_ns=2).keyframe_seq == 1  # unchanged: all reused
    third = extractor.extract(b, seq=3, timestamp_ns=3)
    assert third.keyframe_seq == 3 and third.reused == 0


def test_keyframe_period_one_detects_every_frame_whole(rig_images):
    _, images, _ = rig_images
    sets, _ = extract_all(images[:2], edge=EdgeConfig(keyframe_period=1))
    assert all(f.reused == 0 and f.keyframe_seq == f.seq for s in sets for f in s)


def test_incremental_matches_lie_on_the_true_epipolar_lines(rig_images):
    rig, images, truth = rig_images
    sets, _ = extract_all(images)
    matcher = IncrementalMatcher(MatcherConfig(), stereo=rig_stereo(rig))
    new_tracks = []
    for cameras in sets:
        matches = matcher.match(cameras)
        for p in matches.pairs:
            d = epipolar_distance_px(cameras[p.a].features.uv[p.index_a], cameras[p.b].features.uv[p.index_b],
                                     truth[p.a], truth[p.b])
            assert len(d) >= 20 and np.mean(d <= 1.5) >= 0.95, (p.a, p.b, len(d), np.mean(d <= 1.5))
        tracks = build_tracks(matches)
        new_tracks.append(len(tracks))
        # A pair of views that a track joins through a third camera adds two matches' errors: 3 px.
        for (a, b), (count, fraction) in pairwise_epipolar_fractions(tracks.uv, truth, 3.0).items():
            if count >= 20:
                assert fraction >= 0.98, (a, b, count, fraction)
    assert matcher.whole == 3 and matcher.incremental == 6
    # Later sets bring the box's new points (hundreds of tracks), not the background again.
    assert all(200 <= n < new_tracks[0] for n in new_tracks[1:])


def test_later_sets_match_new_keypoints_against_new_ones_only(rig_images):
    # A reused keypoint is static background, pooled by the pair's whole match: an incremental match
    # pairs no reused keypoint, on either side.
    rig, images, _ = rig_images
    sets, _ = extract_all(images)
    matcher = IncrementalMatcher(MatcherConfig(), stereo=rig_stereo(rig))
    matcher.match(sets[0])
    for cameras in sets[1:]:
        matches = matcher.match(cameras)
        assert sum(len(p) for p in matches.pairs) >= 100
        for p in matches.pairs:
            assert np.all(p.index_a >= cameras[p.a].reused) and np.all(p.index_b >= cameras[p.b].reused)


def test_camera_features_refuse_a_reused_count_beyond_the_keypoints(rig_images):
    _, images, _ = rig_images
    features = FeatureExtractor("left").extract(images[0]["left"], seq=1, timestamp_ns=1).features
    with pytest.raises(ValueError, match="reused"):
        CameraFeatures("left", 1, 1, 1280, 1024, features, keyframe_seq=1, reused=len(features) + 1)
