"""A static camera's new keyframe is matched on what changed, not whole; a moved camera's is matched whole.

config/hosts16.yaml's first cameras (640x512: a box turning in front of a
static wall), frame sets half a second apart, each camera's feature stage
taking a keyframe every other frame, as `keyframe_period` does every 30th.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from camnet.drivers.sim import create
from camnet.services.matcher import rig_stereo

from camnet.io.rig import load_rig
from camnet.matching.edge import EdgeConfig, FeatureExtractor
from camnet.matching.features import MatcherConfig
from camnet.matching.reuse import IncrementalMatcher
from tests._groundtruth import epipolar_distance_px

RIG = Path(__file__).resolve().parents[1] / "config" / "hosts16.yaml"
CAMERAS = ("left", "right", "mono_a")
SLOTS = (100, 105, 110, 115)  # 10 fps: half a second apart; keyframes at the first and the third


@pytest.fixture(scope="module")
def rig_images():
    rig = load_rig(RIG)
    cameras = {e.id: create(e, rig) for e in rig.cameras if e.id in (*CAMERAS, "mono_05")}
    images = [{c: cameras[c].render(slot) for c in (*CAMERAS, "mono_05")} for slot in SLOTS]
    truth = [cameras[c].config.camera(c) for c in CAMERAS]
    return rig, images, truth


def frame_sets(images, *, moved_at: int | None = None):
    """Each set's features; from set `moved_at` on, mono_a sees what mono_05 sees (it moved there)."""
    extractors = {c: FeatureExtractor(c, MatcherConfig(), EdgeConfig(keyframe_period=2)) for c in CAMERAS}
    out = []
    for k, (slot, frame) in enumerate(zip(SLOTS, images, strict=True)):
        source = {c: c for c in CAMERAS} | ({"mono_a": "mono_05"} if moved_at is not None and k >= moved_at else {})
        out.append([extractors[c].extract(frame[source[c]], seq=slot, timestamp_ns=slot) for c in CAMERAS])
    return out


def test_a_static_cameras_keyframe_is_matched_on_what_changed(rig_images):
    rig, images, truth = rig_images
    sets = frame_sets(images)
    assert [s[0].keyframe_seq == s[0].seq for s in sets] == [True, False, True, False]
    matcher = IncrementalMatcher(MatcherConfig(), stereo=rig_stereo(rig))
    whole, found = [], []
    for cameras in sets:
        before = matcher.whole
        cameras = matcher.prepare(cameras)
        matches = matcher.match(cameras)
        whole.append(matcher.whole - before)
        found.append(sum(len(p) for p in matches.pairs))
        for p in matches.pairs:
            # Only what was not seen before is matched: the keyframe's background was pooled already.
            assert np.all(p.index_a >= cameras[p.a].reused) and np.all(p.index_b >= cameras[p.b].reused)
            d = epipolar_distance_px(cameras[p.a].features.uv[p.index_a], cameras[p.b].features.uv[p.index_b],
                                     truth[p.a], truth[p.b])
            assert np.mean(d <= 1.5) >= 0.95, (p.a, p.b, len(d), np.mean(d <= 1.5))
    # Matched whole once, at the start: the keyframes of the third set continue their cameras' epochs.
    assert whole == [3, 0, 0, 0]
    assert matcher.seen.continued == 3 and matcher.seen.restarted == 0
    # The third set's keyframes still bring the box's new points.
    assert found[2] >= 100, found


def test_a_moved_cameras_keyframe_is_matched_whole(rig_images):
    rig, images, _ = rig_images
    sets = frame_sets(images, moved_at=2)
    matcher = IncrementalMatcher(MatcherConfig(), stereo=rig_stereo(rig))
    whole = []
    for cameras in sets:
        before = matcher.whole
        matcher.match(matcher.prepare(cameras))
        whole.append(matcher.whole - before)
    # mono_a's new view shares none of its keypoints with its old one: its pairs start again, whole (or,
    # where they no longer overlap, after a probe that finds nothing).
    assert matcher.seen.restarted == 1 and matcher.seen.continued == 2
    assert whole[:2] == [3, 0] and whole[2] + matcher.probed >= 2


def test_a_pair_that_does_not_overlap_is_probed_not_matched_whole(rig_images):
    rig, images, _ = rig_images
    extractor = FeatureExtractor("left")
    left = extractor.extract(images[0]["left"], seq=1, timestamp_ns=1)
    rng = np.random.default_rng(0)
    noise = FeatureExtractor("right").extract((rng.random((512, 640)) * 255).astype(np.uint8), seq=1,
                                              timestamp_ns=1)
    matcher = IncrementalMatcher(MatcherConfig(), stereo=rig_stereo(rig))
    matches = matcher.match([left, noise])
    assert matcher.probed == 1 and matcher.whole == 0 and len(matches.pairs[0]) == 0
    # Below a quarter of a whole match's comparisons.
    assert matcher.compared <= len(left.features) * len(noise.features) / 4 + len(noise.features)
