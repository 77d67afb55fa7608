"""What the matcher receives and publishes at a cost: frames only of cameras without features, and the
pool's document encoded a track at a time (camnet.io.observations_encoder)."""

from __future__ import annotations

import json
import logging
import threading

import numpy as np
from camnet.services.matcher import MatcherNode, MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.features_wire import FeaturesMessage, encode_features
from camnet.bus.frame import Frame, encode_frame
from camnet.bus.latency import StageStamps
from camnet.bus.source import declare_stage
from camnet.io.formats import observations_to_doc, parse_observations
from camnet.io.messages import ObservationsMessage, encode_observations_message
from camnet.io.observations_encoder import ObservationsEncoder
from camnet.io.rig import parse_rig
from camnet.matching.pool import PoolConfig, TrackPool, regrow_pool
from camnet.model.camera import CameraInfo
from camnet.model.observations import Stereo
from camnet.testing.random_tracks import HEIGHT, WIDTH, random_tracks, reseen
from tests.conftest import matched_publisher, wait_for
from tests.test_matcher_node import rig_document


def test_the_cached_document_is_the_codecs_byte_for_byte_through_adds_reobservations_evictions():
    rng = np.random.default_rng(3)
    cameras = [CameraInfo(f"cam{i}", WIDTH, HEIGHT) for i in range(6)]
    ids = tuple(c.id for c in cameras)
    stereo = Stereo("cam0", "cam1", 0.125)
    pool = TrackPool(cameras, stereo, PoolConfig(max_tracks=600))
    encoder = ObservationsEncoder()
    done = {"reobserved": 0, "evicted": 0}
    for frame_seq in range(12):
        update = pool.add(random_tracks(rng, ids, 150), frame_seq=frame_seq)
        if frame_seq % 3 == 2:
            update = pool.add(reseen(rng, pool, 40), frame_seq=frame_seq)
            done["reobserved"] += update.reobserved
        done["evicted"] += update.evicted
        message = ObservationsMessage(pool.observations(), rig="r", pool_id="p", frame_sets=frame_seq + 1,
                                      latency_ns=StageStamps(taken_ns=1))
        # The contract's document, then the envelope's keys in their order, None left out.
        doc = {**observations_to_doc(pool.observations()), "rig": "r", "pool_id": "p", "frame_sets": frame_seq + 1,
               "latency_ns": {"taken": 1}}
        assert encoder.encode(message) == json.dumps(doc).encode() == encode_observations_message(message), frame_seq
        if frame_seq > 0:
            assert encoder.encoded < len(pool)  # the unchanged tracks came from the cache
    assert done["reobserved"] >= 20 and done["evicted"] >= 600, done
    # A camera joins: the pool starts afresh over seven cameras, track ids renumbered.
    grown = regrow_pool(pool, [*cameras, CameraInfo("cam6", WIDTH, HEIGHT)], stereo, pool.config, frame_seq=12)
    bare = ObservationsMessage(grown.observations())
    assert encoder.encode(bare) == json.dumps(observations_to_doc(grown.observations())).encode()
    assert parse_observations(json.loads(encoder.encode(bare))).uv.shape == grown.observations().uv.shape


class CountingMatcher(MatcherNode):
    """The matcher node, counting the frames its frame subscribers deliver, by camera."""

    def __init__(self, *args, **kwargs) -> None:
        self.delivered: dict[str, int] = {}
        super().__init__(*args, **kwargs)

    def on_sample(self, sample) -> None:
        camera_id = str(sample.key_expr).split("/")[-2]
        self.delivered[camera_id] = self.delivered.get(camera_id, 0) + 1
        super().on_sample(sample)


class Repeating:
    """Puts a message made by `make(n)` every `period_s` on a thread of its own, counting them, until closed."""

    def __init__(self, put, make, period_s: float) -> None:
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(put, make, period_s), daemon=True)
        self._thread.start()

    def _run(self, put, make, period_s: float) -> None:
        while not self._stop.wait(period_s):
            put(make(self.sent))
            self.sent += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)


def features_of(camera_id: str, n: int) -> bytes:
    rng = np.random.default_rng(n)
    return encode_features(FeaturesMessage(camera_id, n, n * 200_000_000, WIDTH, HEIGHT, "sift", 0, 0,
                                           rng.random((50, 2)) * 500, rng.integers(0, 256, (50, 128), np.uint8)))


def test_a_camera_sending_features_has_its_frames_unsubscribed_until_its_features_stop(zenoh_pair, caplog):
    node_session, peer = zenoh_pair
    rig = parse_rig(rig_document("fsub"))
    node = CountingMatcher(node_session, rig, config=MatcherNodeConfig(stats_period_s=0.5))
    worker = threading.Thread(target=node.run, daemon=True)
    worker.start()
    pixels = np.zeros((HEIGHT, WIDTH), np.uint8)
    running, stages = [], []
    try:
        frames = matched_publisher(peer, keys.frame(rig.name, "mono_b"), timeout_s=30.0)
        running.append(Repeating(lambda n: frames.put(encode_frame(Frame("mono_b", n, n * 100_000_000, "mono8",
                                                                         pixels))), lambda n: n, 0.1))
        assert wait_for(lambda: node.delivered.get("mono_b", 0) >= 3, 60.0), "no frames reached the matcher"
        with caplog.at_level(logging.INFO, logger="camnet.services.matcher_frames"):
            stages.append(declare_stage(peer, rig.name, "mono_b"))  # a stage of mono_b: its features are taken
            features = Repeating(lambda n: peer.put(keys.features(rig.name, "mono_b"), features_of("mono_b", n)),
                                 lambda n: n, 0.2)
            running.append(features)
            # Nothing on the bus wants mono_b's frames any more: its driver's frames go nowhere.
            assert wait_for(lambda: not frames.matching_status.matching, 60.0), "mono_b's frames still subscribed"
            assert node.frames.feature_cameras == {"mono_b"}
            before, sent = node.delivered["mono_b"], running[0].sent
            assert wait_for(lambda: running[0].sent >= sent + 10 and features.sent >= 5, 60.0)
            assert node.delivered["mono_b"] == before, "frames of a camera with features still delivered"
            # Its features say it is there (`camnet status`), not its frames.
            assert wait_for(lambda: not node.cameras_seen()["mono_b"].missing, 60.0), node.cameras_seen()["mono_b"]
            # The other cameras' frames are still received.
            matched_publisher(peer, keys.frame(rig.name, "left"), timeout_s=30.0).undeclare()

            features.close()  # the stage stops: the matcher must take mono_b's frames again
            assert wait_for(lambda: node.delivered["mono_b"] > before, 120.0), "mono_b's frames never came back"
        assert frames.matching_status.matching and node.frames.feature_cameras == frozenset()
        assert node.frames.fallbacks == 1
        assert any("no features from its stage" in r.getMessage() and r.levelno == logging.WARNING
                   for r in caplog.records)
    finally:
        for repeating in running:
            repeating.close()
        for stage in stages:
            stage.undeclare()
        node.stop.set()
        worker.join(timeout=30)
    assert not worker.is_alive()
