"""The matcher node reads the rig's calibration from the bus and then matches only the view graph's pairs."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import replace

import numpy as np
from camnet.services.calibrator import CalibratorConfig, CalibratorNode
from camnet.services.matcher import (
    PARTIAL_VIEW_GRAPH_PERIOD_S,
    VIEW_GRAPH_PERIOD_S,
    MatcherNode,
    MatcherNodeConfig,
)
from camnet.services.matcher_calibration import ASK_PERIOD_S, CalibrationInbox

from camnet.bus import keys
from camnet.bus.node import Tally
from camnet.bus.source import SourcedPublisher, declare_calibrator
from camnet.io.formats import calibration_to_doc
from camnet.io.rig import parse_rig
from camnet.model.calibration import Calibration
from tests.conftest import matched_publisher, running_node, wait_for
from tests.test_matcher_node import network, rig_document  # noqa: F401 (network: the fixture)

AWAY_M = np.array([20.0, 0.0, 0.0])  # mono_b, as the calibration has it: 20 m to the right


def calibration_with_mono_b_elsewhere(rig) -> dict:
    """The ground truth, but mono_b 20 m away looking at points of its own: it overlaps no camera."""
    cameras = rig.simulated_truth()
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.15, -0.15, 0.5], [0.3, 0.15, 0.8], (300, 3))  # the textured box's region
    index = [c.id for c in cameras].index("mono_b")
    mono_b = cameras[index]
    moved = replace(mono_b, t=mono_b.t - mono_b.R @ AWAY_M)  # centre + AWAY_M: x_cam = R X + t
    cameras[index] = moved
    own = moved.centre + 0.65 * moved.R[2] + rng.uniform(-0.1, 0.1, (100, 3))
    all_points = np.concatenate([points, own])
    cal = Calibration(tuple(cameras), np.arange(len(all_points)), all_points, 0.3, "left")
    return calibration_to_doc(cal)


def pairs_matched(net) -> tuple[list[int], list[tuple[int, int]]]:
    """Pairs matched in each frame set of all four cameras until all six are; (pairs matched, of) as they change."""
    seen: list[tuple[int, int]] = []

    def all_six() -> bool:
        stats = net.node.engine.stats
        if stats.frame_sets_matched and (not seen or stats.pairs != seen[-1]):
            seen.append(stats.pairs)
        return bool(seen) and seen[-1][0] >= 6

    # As long as frame sets are matched (a loaded machine matches them slowly), up to 10 minutes.
    wait_for(all_six, 120.0, 0.01, progress=lambda: net.node.engine.stats.frame_sets_matched, limit_s=600.0)
    return [matched for matched, possible in seen if possible == 6], seen


def test_a_calibration_narrows_the_pairs_and_exploration_finds_the_rest_again(network):  # noqa: F811
    rig = parse_rig(rig_document("vgtest"))
    net = network(rig, MatcherNodeConfig(publish_period_s=0.5, max_wait_s=0.3, explore_pairs=1))
    token = declare_calibrator(net.observer, rig.name)  # noqa: F841 (kept: a token dropped is undeclared)
    publisher = SourcedPublisher(matched_publisher(net.observer, keys.calibration(rig.name), timeout_s=30.0))
    publisher.put(json.dumps(calibration_with_mono_b_elsewhere(rig)).encode())
    assert wait_for(lambda: net.node.calibration.waiting, 60.0), "the calibration never reached the matcher"
    for camera_id in rig_document("vgtest")["cameras"]:
        net.start_driver(camera_id["id"])
    full, seen = pairs_matched(net)
    # The three overlapping pairs and one explored pair of mono_b, not all six: the calibration was read.
    assert full and full[0] == 4, seen
    # mono_b's pairs, explored one per frame set, match well and stay: the camera is found again.
    assert full[-1] == 6, seen
    # What does not parse is counted, and the last calibration stays.
    publisher.put(b"{not a calibration")
    assert wait_for(lambda: net.node.rejected.counts.get("calibration") == 1, 60.0)
    assert net.node.engine.view_graph.calibrated == {"left", "right", "mono_a", "mono_b"}
    assert wait_for(lambda: net.count() >= 1 and any("mono_b" in t["observations"]
                                                     for t in net.latest()["tracks"]), 60.0)


def test_a_matcher_started_after_the_calibrator_asks_it_for_the_latest_calibration(network, tmp_path):  # noqa: F811
    # The calibrator resumed its calibration before the matcher started: nothing is published again until
    # the next solve, and the restarted matcher must not match all six pairs until then.
    rig = parse_rig(rig_document("vgquery"))
    net = network(rig, MatcherNodeConfig(publish_period_s=0.5, max_wait_s=0.3, explore_pairs=1), start=False)
    state = tmp_path / "calibration.json"
    state.write_text(json.dumps(calibration_with_mono_b_elsewhere(rig)))
    with running_node(CalibratorNode(net.observer, rig.name, CalibratorConfig(state_path=state))) as calibrator:
        assert wait_for(lambda: calibrator.latest_doc is not None, 60.0), "the calibrator did not resume"
        net.start_matcher()
        assert wait_for(lambda: net.node.calibration.waiting, 60.0), "the matcher never got the calibration"
    # The calibrator has answered and gone: no solve of its own replaces the calibration under test.
    for camera_id in rig_document("vgquery")["cameras"]:
        net.start_driver(camera_id["id"])
    full, seen = pairs_matched(net)
    assert full and full[0] == 4, seen  # the view graph's pairs from the first frame set on
    assert net.node.engine.view_graph.calibrated == {"left", "right", "mono_a", "mono_b"}



def test_the_matcher_asks_for_the_latest_calibration_until_an_answer_comes(zenoh_pair):
    # A query sent before the session knows of the calibrator's queryable gets no answer (a loaded
    # machine, a router still connecting). The calibrator here is a queryable that answers from
    # then on, and publishes nothing: the real one published its calibration before this matcher
    # subscribed.
    calibrator_side, matcher_side = zenoh_pair
    rig = parse_rig(rig_document("vgask"))
    inbox = CalibrationInbox(rig.name, rejected=Tally(logging.getLogger(__name__)),
                             foreign=Tally(logging.getLogger(__name__)))
    declared = inbox.declare(matcher_side, Tally(logging.getLogger(__name__)), time.monotonic())
    try:
        assert inbox.asked == 1
        time.sleep(0.5)
        assert not inbox.waiting
        answer = json.dumps(calibration_with_mono_b_elsewhere(rig)).encode()
        token = declare_calibrator(calibrator_side, rig.name)
        queryable = calibrator_side.declare_queryable(keys.calibration(rig.name),
                                                      lambda query: query.reply(query.key_expr, answer))
        try:
            def asked_and_answered() -> bool:
                inbox.ask_until_answered(time.monotonic())
                return inbox.waiting
            assert wait_for(asked_and_answered, 60.0), f"no answer after {inbox.asked} queries"
            calibration = inbox.take()
            assert calibration is not None and len(calibration.cameras) == 4
            asked = inbox.asked
            inbox.ask_until_answered(time.monotonic() + 10 * ASK_PERIOD_S)
            assert inbox.asked == asked, "asked again after an answer"
        finally:
            queryable.undeclare()
            token.undeclare()
    finally:
        for entity in declared:
            entity.undeclare()


class _Sample:
    """A calibration as Zenoh hands it to the subscriber's callback."""

    def __init__(self, payload: bytes) -> None:
        self.payload = self
        self._payload = payload
        self.attachment = None

    def to_bytes(self) -> bytes:
        return self._payload


def test_the_view_graph_is_renewed_from_the_newest_calibration_at_most_once_a_period():
    # A calibrator publishes about one calibration per frame set; parsing each and renewing the view graph
    # costs the matcher a good part of a set (docs/benchmarks.md, "Sixteen cameras across hosts"). The first is
    # taken at once, then one per period.
    rig = parse_rig(rig_document("vgperiod"))
    node = MatcherNode(None, rig)  # no session: nothing here touches the bus
    try:
        payload = json.dumps(calibration_with_mono_b_elsewhere(rig)).encode()
        node.calibration.on_sample(_Sample(payload))
        node._take_calibration()
        assert node.engine.view_graph.calibrated == {"left", "right", "mono_a", "mono_b"}
        assert not node.calibration.waiting
        node.calibration.on_sample(_Sample(payload))
        node._take_calibration()
        assert node.calibration.waiting  # kept for the next period, or replaced by a newer one
        node._view_graph_s -= VIEW_GRAPH_PERIOD_S  # the period has passed
        node._take_calibration()
        assert not node.calibration.waiting
    finally:
        node._workers.shutdown()


def test_a_calibration_that_leaves_a_camera_out_is_renewed_sooner():
    # A camera the view graph's calibration leaves out is matched with every camera: on 16 cameras, the frame
    # sets with the calibrator's first calibrations (4, then 9 cameras) cost three times the others, for a
    # whole period after each. The next is taken after the shorter period; once it holds every camera, the long.
    rig = parse_rig(rig_document("vgpartial"))
    node = MatcherNode(None, rig)  # no session: nothing here touches the bus
    try:
        whole = calibration_with_mono_b_elsewhere(rig)
        index = [c["id"] for c in whole["cameras"]].index("mono_b")
        partial = {**whole, "cameras": [c for k, c in enumerate(whole["cameras"]) if k != index]}
        node.calibration.on_sample(_Sample(json.dumps(partial).encode()))
        node._take_calibration()
        assert node.engine.view_graph.calibrated == {"left", "right", "mono_a"}
        for _ in range(2):
            node.calibration.on_sample(_Sample(json.dumps(whole).encode()))
            node._take_calibration()
            assert node.calibration.waiting  # not at once: every calibration would be parsed
            node._view_graph_s -= PARTIAL_VIEW_GRAPH_PERIOD_S
            node._take_calibration()
        assert node.engine.view_graph.calibrated == {"left", "right", "mono_a", "mono_b"}
        assert node.calibration.waiting  # the second: every camera held, the long period
        node._view_graph_s -= VIEW_GRAPH_PERIOD_S
        node._take_calibration()
        assert not node.calibration.waiting
    finally:
        node._workers.shutdown()
