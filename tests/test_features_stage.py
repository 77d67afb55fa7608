"""The features message, and the feature stage beside a driver feeding the matcher on loopback Zenoh."""

from __future__ import annotations

import struct
import threading

import numpy as np
import pytest
from camnet.services.features import FeatureStageConfig, FeatureWorker, from_message, to_message
from camnet.services.matcher import MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.features_wire import FeaturesError, FeaturesMessage, decode_features, encode_features
from camnet.errors import InputError
from camnet.io.rig import parse_rig
from tests.conftest import wait_for
from tests.test_matcher_node import CAMERAS, fraction_on_epipolar_lines, network, rig_document, track_uv  # noqa: F401


def message(n: int = 5, *, detector: str = "sift", reused: int = 2) -> FeaturesMessage:
    rng = np.random.default_rng(n)
    size = 128 if detector == "sift" else 32
    return FeaturesMessage("cam0", 7, 123_456_789, 640, 512, detector, 3, reused,
                           rng.random((n, 2)) * 500, rng.integers(0, 256, (n, size), dtype=np.uint8))


@pytest.mark.parametrize("detector", ["sift", "orb"])
def test_features_round_trip_bit_exact(detector):
    sent = message(detector=detector)
    got = decode_features(encode_features(sent))
    assert (got.camera_id, got.seq, got.timestamp_ns, got.width, got.height, got.detector, got.keyframe_seq,
            got.reused) == ("cam0", 7, 123_456_789, 640, 512, detector, 3, 2)
    assert np.array_equal(got.uv, sent.uv.astype(np.float32)) and np.array_equal(got.descriptors, sent.descriptors)
    assert len(encode_features(sent)) == 56 + 4 + 5 * (8 + (128 if detector == "sift" else 32))


def test_sift_descriptors_travel_as_bytes_and_come_back_equal():
    sent = message()
    as_float = FeaturesMessage(**{**sent.__dict__, "descriptors": sent.descriptors.astype(np.float32)})
    assert encode_features(as_float) == encode_features(sent)
    with pytest.raises(ValueError, match="whole numbers"):
        encode_features(FeaturesMessage(**{**sent.__dict__, "descriptors": sent.descriptors + 0.5}))


@pytest.mark.parametrize(("mutate", "kind"), [
    (lambda b: b[:30], "truncated"),
    (lambda b: b"XXXX" + b[4:], "bad-magic"),
    (lambda b: b[:4] + b"\x09" + b[5:], "unknown-version"),
    (lambda b: b + b"\x00", "trailing-bytes"),
    (lambda b: b[:-1], "truncated"),
    (lambda b: b[:5] + b"\x07" + b[6:], "bad-detector"),
    (lambda b: b[:8] + struct.pack("<H", 99) + b[10:], "bad-header"),
    (lambda b: b[:60] + struct.pack("<f", float("nan")) + b[64:], "bad-keypoints"),
])
def test_malformed_features_are_refused_by_kind(mutate, kind):
    with pytest.raises(FeaturesError) as caught:
        decode_features(mutate(encode_features(message())))
    assert caught.value.kind == kind


def test_features_key_round_trip():
    assert keys.features("r", "c") == "camnet/r/cam/c/features"
    assert keys.parse_features(keys.features("r", "c")) == ("r", "c")
    with pytest.raises(InputError):
        keys.parse_features(keys.frame("r", "c"))


def test_a_stage_beside_two_drivers_feeds_the_matcher(network):  # noqa: F811 (the fixture)
    """left and mono_a send features, right and mono_b frames: the tracks join all four, on the true geometry."""
    from camnet.drivers.base import create_camera
    from camnet.drivers.node import DriverNode

    rig = parse_rig(rig_document("ftest"))
    net = network(rig, MatcherNodeConfig(publish_period_s=0.5, max_wait_s=0.3, stats_period_s=0.5))
    workers = []
    for camera_id in CAMERAS:
        on_frame = None
        if camera_id in ("left", "mono_a"):
            publisher = net.drivers_session.declare_publisher(keys.features(rig.name, camera_id))
            worker = FeatureWorker(publisher, camera_id, FeatureStageConfig(period_s=0.5)).__enter__()
            workers.append(worker)
            on_frame = worker.offer
        driver = DriverNode(net.drivers_session, rig, create_camera(rig.camera(camera_id), rig), on_frame=on_frame)
        thread = threading.Thread(target=driver.run, daemon=True)
        net.drivers.append(driver)
        net.threads.append(thread)
        thread.start()
    try:
        # A malformed features message is counted, and matching goes on.
        net.drivers_session.put(keys.features(rig.name, "left"), b"CNFT\x01 not features")

        checked = (("left", "right"), ("left", "mono_a"), ("right", "mono_b"))

        def every_pair_pooled() -> bool:
            tracks = net.latest()["tracks"] if net.count() else []
            return all(sum(a in t["observations"] and b in t["observations"] for t in tracks) >= 50
                       for a, b in checked)

        # Sets without a stage's late features, or a late camera's frames, come first on a
        # busy machine: wait for every pair checked below.
        assert wait_for(every_pair_pooled, 180.0), "the pooled tracks never joined every pair checked"
        assert net.node._feature_cameras == {"left", "mono_a"}
        assert net.node.rejected.counts.get("features truncated") == 1
        # Pooled tracks may come from the first messages: the stages keep publishing.
        assert wait_for(lambda: all(w.published >= 3 for w in workers), 60.0), [w.published for w in workers]
        assert not any(w.failures.counts for w in workers)
        doc = net.latest()
        ids = list(CAMERAS)
        truth = {e.id: e.config.camera(e.id) for e in rig.cameras}
        uv = track_uv(doc, ids)
        for a, b in ((0, 1), (0, 2), (1, 3)):
            n, ok = fraction_on_epipolar_lines(uv, truth, a, b, ids, 1.5)
            assert n >= 50 and ok > 0.95, (ids[a], ids[b], n, ok)
    finally:
        for driver in net.drivers:
            driver.stop.set()
        for worker in workers:
            worker.__exit__(None, None, None)


def test_message_and_camera_features_convert_both_ways():
    sent = message()
    back = to_message(from_message(sent))
    assert back.reused == 2 and back.keyframe_seq == 3 and np.array_equal(back.descriptors, sent.descriptors)
