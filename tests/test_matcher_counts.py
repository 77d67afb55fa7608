"""What the matcher counts of what it is sent on the open bus: frames stamped far from its clock, every
calibration that does not parse, features it cannot take, each with the reason said."""

from __future__ import annotations

import logging
import time

import numpy as np
from camnet.services.matcher import MatcherNode, MatcherNodeConfig
from camnet.services.matcher_calibration import CalibrationInbox

from camnet.bus import keys
from camnet.bus.frame import Frame, encode_frame
from camnet.bus.node import Tally
from camnet.bus.receiver import FrameReceiver
from camnet.bus.source import SourcedPublisher, declare_calibrator
from camnet.bus.stats import NodeStats
from camnet.io.rig import parse_rig
from tests.conftest import matched_publisher, running_node, wait_for
from tests.test_calibrator_node import RIG
from tests.test_foreign_features import forged
from tests.test_matcher_node import rig_document

HOUR_NS = 3600 * 10**9
OFF_CLOCK = "capture time off the clocks"


def lying_stamps() -> list[int]:
    now_ns = time.time_ns()
    return [2**63, 0, now_ns + HOUR_NS, now_ns - HOUR_NS]


def test_frames_stamped_far_from_this_hosts_clock_and_their_cameras_are_counted_and_kept():
    receiver = FrameReceiver({"left": None, "late": None, "kitti": None})
    pixels = np.zeros((8, 8), np.uint8)

    def received(camera_id: str, stamps: list[int]) -> list[int]:
        return [receiver.accept(encode_frame(Frame(camera_id, seq, stamp, "mono8", pixels))).timestamp_ns
                for seq, stamp in enumerate(stamps)]

    stamps = [time.time_ns(), *lying_stamps(), time.time_ns() + 10**9]  # the first and last: within a second
    # Kept: frame sets need only the cameras to agree; the count says to check the clocks.
    assert received("left", stamps) == stamps
    assert receiver.off_clock.counts == {OFF_CLOCK: 4} and receiver.malformed.total == 0
    # A camera host whose clock is an hour behind, and a replay of frames recorded in 2011: their own clocks.
    behind = [time.time_ns() - HOUR_NS + k * 10**8 for k in range(5)]
    recorded = [1_317_046_400_000_000_000 + k * 10**8 for k in range(5)]
    assert received("late", behind) == behind and received("kitti", recorded) == recorded
    assert receiver.off_clock.counts == {OFF_CLOCK: 4}


def test_every_calibration_that_does_not_parse_is_counted_and_none_replaces_a_good_one(zenoh_pair):
    from camnet.io.formats import calibration_to_doc
    from camnet.sim.simulate import make_rig

    calibrator_side, matcher_side = zenoh_pair
    rejected = Tally(logging.getLogger(__name__))
    inbox = CalibrationInbox(RIG, rejected=rejected, foreign=Tally(logging.getLogger(__name__)))
    declared = inbox.declare(matcher_side, Tally(logging.getLogger(__name__)), time.monotonic())
    token = declare_calibrator(calibrator_side, RIG)
    publisher = SourcedPublisher(matched_publisher(calibrator_side, keys.calibration(RIG)))
    try:
        import json

        from camnet.model.calibration import Calibration

        cameras = tuple(make_rig(n_cameras=3, seed=1).cameras)
        good = Calibration(cameras, np.arange(2), np.ones((2, 3)), 0.5, cameras[0].id)
        publisher.put(json.dumps(calibration_to_doc(good)).encode())
        bad = [b"not json", b"{}", b'{"format": "camnet.calibration/1"}', b"[1, 2]", b"\xff\xfe"] * 20
        for payload in bad:  # faster than the worker takes any: every one counted all the same
            publisher.put(payload)
        assert wait_for(lambda: rejected.total == len(bad), 60.0), rejected.counts
        taken = inbox.take()
        assert taken is not None and [c.id for c in taken.cameras] == [c.id for c in cameras]
        assert inbox.take() is None
    finally:
        publisher.undeclare()
        token.undeclare()
        for entity in declared:
            entity.undeclare()


def test_the_matcher_counts_lying_stamps_and_says_why_it_drops_features(zenoh_pair, caplog):
    node_session, peer = zenoh_pair
    rig = parse_rig(rig_document("counts"))
    node = MatcherNode(node_session, rig, config=MatcherNodeConfig(stats_period_s=0.3))
    stats: list[NodeStats] = []
    peer.declare_subscriber(keys.node_stats(rig.name, "matcher", "matcher"),
                            lambda s: stats.append(NodeStats.from_json(s.payload.to_bytes())))
    with caplog.at_level(logging.WARNING, logger="camnet.services.matcher"), running_node(node):
        frames = matched_publisher(peer, keys.frame(rig.name, "left"), timeout_s=30.0)
        pixels = np.zeros((512, 640), np.uint8)
        for seq, stamp in enumerate([time.time_ns(), *lying_stamps()]):  # an honest frame, then lies
            frames.put(encode_frame(Frame("left", seq, stamp, "mono8", pixels)))
        features = matched_publisher(peer, keys.features(rig.name, "stranger"), timeout_s=30.0)
        features.put(forged("stranger", 0))  # a camera the rig does not have
        features.put(forged("left", 1))  # another camera's on this key
        # Shown where the matcher's other counts are: in its statistics (`camnet status`).
        assert wait_for(lambda: stats and stats[-1].faults.get(OFF_CLOCK) == 4
                        and stats[-1].faults.get("features camera-mismatch") == 1, 60.0), \
            stats[-1].faults if stats else "no statistics"
    said = [r.getMessage() for r in caplog.records if "dropping the features" in r.getMessage()]
    assert len(said) == 2 and not any("uses sift" in line for line in said), said
    assert any("'stranger'" in line and "not a camera of rig 'counts'" in line for line in said), said
    assert any("'left'" in line and "on the key of camera 'stranger'" in line for line in said), said
