"""The features message, and the feature stage beside a driver feeding the matcher on loopback Zenoh."""

from __future__ import annotations

import collections
import struct
import threading

import numpy as np
import pytest
from camnet.services.features import (
    BUFFERED_FRAMES,
    FeatureNode,
    FeatureStageConfig,
    FeatureWorker,
    MatcherPace,
    from_message,
    pick_frame,
    to_message,
)
from camnet.services.matcher import MatcherNodeConfig

from camnet.bus import keys
from camnet.bus.features_wire import FeaturesError, FeaturesMessage, decode_features, encode_features
from camnet.bus.frame import Frame
from camnet.bus.source import declare_stage
from camnet.bus.stats import NodeStats
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
    workers, stages = [], []
    for camera_id in CAMERAS:
        on_frame = None
        if camera_id in ("left", "mono_a"):
            publisher = net.drivers_session.declare_publisher(keys.features(rig.name, camera_id))
            stages.append(declare_stage(net.drivers_session, rig.name, camera_id))  # kept: dropped, it leaves
            worker = FeatureWorker(publisher, camera_id, FeatureStageConfig(period_s=0.5)).__enter__()
            workers.append(worker)
            on_frame = worker.offer
        driver = DriverNode(net.drivers_session, rig, create_camera(rig.camera(camera_id), rig), on_frame=on_frame)
        thread = threading.Thread(target=driver.run, daemon=True)
        net.drivers.append(driver)
        net.threads.append(thread)
        thread.start()
    try:
        # A malformed features message is counted, and matching goes on. Put once the matcher's
        # subscription has reached the drivers' session, or it would go nowhere.
        matched_publisher(net.drivers_session, keys.features(rig.name, "left")).put(b"CNFT\x01 not features")

        checked = (("left", "right"), ("left", "mono_a"), ("right", "mono_b"))

        def every_pair_pooled() -> bool:
            tracks = net.latest()["tracks"] if net.count() else []
            return all(sum(a in t["observations"] and b in t["observations"] for t in tracks) >= 50
                       for a, b in checked)

        # Sets without a stage's late features, or a late camera's frames, come first on a
        # busy machine: wait for every pair checked below.
        assert wait_for(every_pair_pooled, 180.0, progress=net.progress, limit_s=600.0), \
            "the pooled tracks never joined every pair checked"
        # A stage paused for seconds on a loaded host is taken for stopped until its features come again.
        assert wait_for(lambda: net.node.frames.feature_cameras == {"left", "mono_a"}, 60.0), \
            net.node.frames.feature_cameras
        assert wait_for(lambda: net.node.rejected.counts.get("features truncated") == 1), net.node.rejected.counts
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
        for stage in stages:
            stage.undeclare()


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


def matcher_report(t_s: float, frame_sets: int) -> NodeStats:
    return NodeStats(rig="r", kind="matcher", node_id="matcher", fps=0.0, frames=frame_sets, dropped=0,
                     timestamp_ns=round(t_s * 1e9))


def test_stages_on_different_hosts_detect_the_same_slots_at_the_matchers_pace():
    """Host 0 hears the matcher from the start and takes frames one by one; host 1 joins 25 s later
    and takes them three at a time (a loaded host). Once host 1 has heard two windows of reports,
    both detect the same capture slots: few while the matcher is slow, every grid point once it keeps up."""
    fps, period_s, join_s, slow_until_s = 10, 0.5, 25.0, 60.0
    paces = [MatcherPace(period_s), MatcherPace(period_s)]
    # Not entered: the stages' threads would take frames when they are free; here the test hands them over.
    stages = [FeatureWorker(None, f"cam{host}", FeatureStageConfig(period_s=period_s), pace=pace)
              for host, pace in enumerate(paces)]
    buffers = [collections.deque(maxlen=BUFFERED_FRAMES) for _ in paces]
    last_grid_ns, picked = [-1, -1], [[], []]
    image = np.zeros((4, 4), np.uint8)
    frame_sets = 0.0
    for slot in range(130 * fps):
        t_s = slot / fps
        if slot % fps == 0:  # the matcher reports every second what it matched of host 0's offer
            # Slow and uneven (as a loaded matcher is), then keeping up with anything.
            capacity_per_s = (1.2 if slot // (7 * fps) % 2 else 0.3) if t_s < slow_until_s else 5.0
            frame_sets += min(capacity_per_s, 1 / (period_s * (1 << paces[0].level)))
            for host, pace in enumerate(paces):
                if host == 0 or t_s >= join_s:
                    pace.on_stats(matcher_report(t_s, int(frame_sets)))
        frame = Frame("cam", slot, slot * 1_000_000_000 // fps, "mono8", image)
        for host, batch in enumerate((1, 3)):
            buffers[host].append(frame)
            if slot % batch != batch - 1:
                continue
            chosen = pick_frame(buffers[host], stages[host].period_ns, last_grid_ns[host])
            if chosen is not None:
                buffers[host].clear()
                picked[host].append(chosen[0].seq)
                last_grid_ns[host] = chosen[1]

    def between(seqs, start_s, end_s):
        return [seq for seq in seqs if start_s * fps <= seq < end_s * fps]

    grid_points = lambda start_s, end_s: round((end_s - start_s) / period_s)  # noqa: E731
    both_s = 40.0  # host 1's first decision: at the first report of the window after the one it joined in
    assert between(picked[0], both_s, 130) == between(picked[1], both_s, 130)
    assert set(between(picked[0], join_s, both_s)) <= set(picked[1])  # a coarser grid's points are on the finer
    assert len(between(picked[0], 30, slow_until_s)) <= grid_points(30, slow_until_s) // 2
    assert len(between(picked[0], 110, 130)) == grid_points(110, 130)
    assert paces[0].changes >= 2 and paces[0].level == paces[1].level == 0


def test_the_pace_waits_for_a_whole_window_and_starts_again_with_the_matcher():
    pace = MatcherPace(0.5, window_s=10.0)
    for t_s in range(0, 25):  # a matcher that matches nothing
        pace.on_stats(matcher_report(t_s, 3))
        assert pace.level == (0 if t_s < 20 else pace.max_level), t_s  # heard from 0: decided at 20
    pace.on_stats(matcher_report(25, 0))  # a new matcher
    assert pace.level == 0
    pace.on_stats(matcher_report(24.5, 5))  # a late copy of an old report changes nothing
    assert pace.level == 0


def test_a_matcher_silent_for_a_window_leaves_the_pace_as_it_was():
    pace = MatcherPace(0.5, window_s=10.0)
    for t_s in range(0, 21):
        pace.on_stats(matcher_report(t_s, 2 * t_s))  # matching all it is offered: every grid point
    pace.on_stats(matcher_report(45, 50))  # the only report of its window: no rate to decide on
    assert pace.level == 0 and pace.changes == 0
