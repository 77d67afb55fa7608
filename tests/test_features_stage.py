"""The features message, and the feature stage beside a driver feeding the matcher on loopback Zenoh."""

from __future__ import annotations

import struct
import threading

import numpy as np
import pytest
from camnet.services.features import FeatureNode, FeatureStageConfig, FeatureWorker, from_message, to_message
from camnet.services.matcher import MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.features_wire import FeaturesError, FeaturesMessage, decode_features, encode_features
from camnet.errors import InputError
from camnet.io.rig import parse_rig
from tests.conftest import matched_publisher, running_node, wait_for
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
        assert net.node.frames.feature_cameras == {"left", "mono_a"}
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


def test_a_feature_node_of_its_own_detects_a_cameras_frames_from_the_bus(zenoh_pair):
    """`camnet features`: frames of its camera in, features out; another camera's frames refused by their header."""
    from camnet.drivers.base import create_camera

    from camnet.bus.frame import Frame, encode_frame

    node_session, peer = zenoh_pair
    rig = parse_rig(rig_document("fnode"))
    camera = create_camera(rig.camera("left"), rig)
    got: list[FeaturesMessage] = []
    peer.declare_subscriber(keys.features(rig.name, "left"),
                            lambda sample: got.append(decode_features(sample.payload.to_bytes())))
    # The node's session must know of this subscriber before its first features go out, or they go nowhere.
    matched_publisher(node_session, keys.features(rig.name, "left"), timeout_s=30.0).undeclare()
    node = FeatureNode(node_session, rig.name, "left", FeatureStageConfig(period_s=0.25))
    with running_node(node):
        frames = matched_publisher(peer, keys.frame(rig.name, "left"), timeout_s=30.0)
        assert wait_for(lambda: node.worker is not None, 30.0)
        stranger = Frame("right", 0, 0, "mono8", np.zeros((8, 8), np.uint8))
        frames.put(encode_frame(stranger))
        for slot in range(4):
            timestamp_ns = slot * 250_000_000
            frames.put(encode_frame(Frame("left", slot, timestamp_ns, "mono8", camera.render(slot))))
            assert wait_for(lambda n=slot: len(got) > n, 60.0), f"no features for frame {slot}"
    assert [m.seq for m in got] == [0, 1, 2, 3] and all(m.camera_id == "left" for m in got)
    assert len(got[0].uv) >= 200 and got[0].reused == 0  # a keyframe, then only what changed
    assert got[-1].keyframe_seq == 0 and got[-1].reused > 0
    assert node.receiver.malformed.counts == {"unknown-camera": 1}


def test_the_features_command_refuses_a_camera_not_in_the_rig(tmp_path):
    import subprocess
    import sys

    import yaml

    rig_path = tmp_path / "rig.yaml"
    rig_path.write_text(yaml.safe_dump(rig_document("fcmd")))
    proc = subprocess.run([sys.executable, "-m", "camnet.cli", "features", "--rig", str(rig_path), "--camera",
                           "nope"], capture_output=True, text=True, timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "nope" in lines[0], proc.stderr
