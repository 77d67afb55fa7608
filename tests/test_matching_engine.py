"""One matching engine: `camnet match`, the offline path and the matcher node find the same tracks in the same frames.

The frames are renders of the simulated rig (camnet.sim): real pixels, the same bytes on every path."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest
from camnet.services.matcher import MatcherNode, MatcherNodeConfig, rig_stereo

from camnet.io.messages import observations_message_to_doc
from camnet.io.rig import camera_info, parse_rig
from camnet.matching.edge import FeatureExtractor
from camnet.matching.engine import CameraImage, EngineConfig, MatchingEngine
from camnet.matching.pipeline import observations_from_frame_sets
from tests.test_matcher_node import CAMERAS, render_set, rig_document

ROOT = Path(__file__).resolve().parent.parent
SETS = 4  # frame sets 1 s apart: the box turns 20 degrees between them, the rest of the scene stays


@pytest.fixture(scope="module")
def rig():
    return parse_rig(rig_document("engine"))


@pytest.fixture(scope="module")
def frame_sets(rig):
    """Rendered frame sets of the four cameras, as the matcher node receives them."""
    return [render_set(rig, k * 1_000_000_000, tuple(CAMERAS)) for k in range(1, SETS + 1)]


def node_after(rig, frame_sets, config: MatcherNodeConfig | None = None) -> MatcherNode:
    node = MatcherNode(None, rig, config=config)  # process() needs no bus
    try:
        for frame_set in frame_sets:
            node.process(frame_set)
    finally:
        node._workers.shutdown()
    return node


def engine_images(frame_set, seq: int) -> list[CameraImage]:
    return [CameraImage(c, f.image, seq=seq, encoding=f.encoding) for c, f in frame_set.frames.items()]


def assert_same_tracks(a, b) -> None:
    assert [(c.id, c.width, c.height) for c in a.cameras] == [(c.id, c.width, c.height) for c in b.cameras]
    assert len(a.track_ids) > 300
    for name in ("track_ids", "track_index", "cam_index", "uv"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_frame_sets_pooled_offline_are_the_tracks_the_matcher_node_pools(rig, frame_sets):
    # The offline path (camnet match, datasets, benchmarks) and the node run the one engine: both detect what
    # changed and match what is new, not every image and every pair whole offline.
    node = node_after(rig, frame_sets)
    offline = observations_from_frame_sets(({c: f.image for c, f in s.frames.items()} for s in frame_sets),
                                           cameras=[camera_info(rig, c, 640, 512) for c in CAMERAS],
                                           stereo=rig_stereo(rig))
    assert node.engine.matcher.incremental > 0  # later frame sets matched what was new: the live path
    assert_same_tracks(offline, node.engine.observations())


def test_camnet_match_writes_the_tracks_the_matcher_node_publishes(rig, frame_sets, tmp_path):
    (first,) = frame_sets[:1]
    for camera_id, frame in first.frames.items():
        cv2.imwrite(str(tmp_path / f"{camera_id}.png"), frame.image)
    rig_path = tmp_path / "rig.yaml"
    rig_path.write_text(json.dumps(rig_document("engine")))  # JSON is YAML
    out = tmp_path / "obs.json"
    result = subprocess.run([sys.executable, "-m", "camnet", "match", *(str(tmp_path / f"{c}.png") for c in CAMERAS),
                             "--rig", str(rig_path), "-o", str(out)], cwd=ROOT, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    offline = json.loads(out.read_text())
    live = observations_message_to_doc(node_after(rig, [first]).message())  # what the node publishes
    assert len(offline["tracks"]) > 300
    assert offline["cameras"] == live["cameras"] and offline["tracks"] == live["tracks"]


def test_a_frame_set_gives_the_same_tracks_whichever_threads_take_its_cameras_and_pairs(rig, frame_sets):
    cameras = [camera_info(rig, c, 640, 512) for c in CAMERAS]
    alone = MatchingEngine(cameras, rig_stereo(rig))
    with ThreadPoolExecutor(max_workers=4) as workers:
        threaded = MatchingEngine(cameras, rig_stereo(rig), executor=workers)
        for seq, frame_set in enumerate(frame_sets[:3]):
            alone.process(engine_images(frame_set, seq))
            threaded.process(engine_images(frame_set, seq))
    assert_same_tracks(alone.observations(), threaded.observations())


def test_features_from_a_cameras_own_stage_pool_as_its_image_detected_here(rig, frame_sets):
    cameras = [camera_info(rig, c, 640, 512) for c in CAMERAS]
    config = EngineConfig()
    images, staged = MatchingEngine(cameras, rig_stereo(rig), config), MatchingEngine(cameras, rig_stereo(rig), config)
    stage = FeatureExtractor("mono_a", config.matcher, config.edge)  # as `camnet driver --features` runs it
    for seq, frame_set in enumerate(frame_sets[:3]):
        items = engine_images(frame_set, seq)
        images.process(items)
        staged.process([stage.extract(item.image, seq=seq, timestamp_ns=0) if item.camera_id == "mono_a" else item
                        for item in items])
    assert stage.partial > 0  # the stage detected what changed, as the engine's own extractor does
    assert_same_tracks(images.observations(), staged.observations())


def test_a_moved_camera_is_forgotten_and_its_pairs_matched_whole_again(rig, frame_sets):
    cameras = [camera_info(rig, c, 640, 512) for c in CAMERAS]
    engine = MatchingEngine(cameras, rig_stereo(rig))
    for seq, frame_set in enumerate(frame_sets[:2]):
        engine.process(engine_images(frame_set, seq))
    mono_b = list(CAMERAS).index("mono_b")
    assert np.any(engine.observations().cam_index == mono_b)
    engine.forget_moved(["mono_b"])
    assert not np.any(engine.observations().cam_index == mono_b)
    # Its views are pooled afresh from the next new track on (told to the calibrator, camnet.bus.moved).
    assert list(engine.pool.forgotten) == ["mono_b"]
    assert engine.pool.forgotten["mono_b"] > engine.observations().track_ids.max()
    whole = engine.matcher.whole
    engine.process(engine_images(frame_sets[2], 2))
    assert engine.matcher.whole - whole == 3  # mono_b with each of the other three
    assert np.any(engine.observations().cam_index == mono_b)


def test_cameras_of_unknown_size_are_pooled_at_the_size_of_their_first_images(rig, frame_sets):
    engine = MatchingEngine([camera_info(rig, c, 0, 0) for c in CAMERAS], rig_stereo(rig))
    engine.forget_moved([])  # as the node does before every frame set
    engine.process(engine_images(frame_sets[0], 0))
    assert [(c.id, c.width, c.height) for c in engine.observations().cameras] == [(c, 640, 512) for c in CAMERAS]
    assert engine.stats.tracks_pooled > 300


def test_a_frame_set_of_a_camera_not_in_the_rig_is_refused_saying_so(rig, frame_sets):
    engine = MatchingEngine([camera_info(rig, c, 640, 512) for c in CAMERAS], rig_stereo(rig))
    image = frame_sets[0].frames["left"].image
    with pytest.raises(ValueError, match=r"frame set cameras \['stranger'\] are not among the rig's cameras"):
        engine.process([CameraImage("left", image, seq=0), CameraImage("stranger", image, seq=0)])
    assert engine.stats.frame_sets_matched == 0


@pytest.mark.parametrize(("side", "says"), [(None, "detecting on images at full size as before"),
                                            (320, "detecting on images of at most 320 px a side")])
def test_a_full_pool_says_how_large_images_are_detected_from_then_on(rig, frame_sets, caplog, side, says):
    # With no smaller size for a full pool, the line read "detecting on images of at most None px a side".
    config = MatcherNodeConfig(max_tracks=50, full_pool_image_side_px=side)
    with caplog.at_level(logging.INFO, logger="camnet"):
        node_after(rig, frame_sets[:2], config)
    (line,) = [r.getMessage() for r in caplog.records if "pool full" in r.getMessage()]
    assert line.startswith("pool full (50 tracks): ") and line.endswith(says) and "None" not in line, line
