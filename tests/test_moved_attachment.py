"""The calibrator names the cameras it found moved in an attachment of the calibration it publishes; the
matcher's inbox reads it as it arrives (camnet.bus.moved)."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import replace

import pytest
from camnet.services.calibrator import CalibratorNode
from camnet.services.matcher_calibration import CalibrationInbox

from camnet.bus import keys
from camnet.bus.moved import forgotten_attachment, moved_attachment, parse_forgotten_attachment, parse_moved_attachment
from camnet.bus.node import Tally
from camnet.bus.source import SourcedPublisher, declare_calibrator
from camnet.errors import InputError
from camnet.io.messages import decode_observations_message
from camnet.live.tracker import Status
from camnet.model.calibration import Calibration
from tests.conftest import matched_publisher, wait_for
from tests.test_calibrator_node import RIG, observations_payload


def test_a_published_calibration_names_the_moved_cameras_to_the_matcher_once(zenoh_pair):
    calibrator_side, matcher_side = zenoh_pair
    rejected = Tally(logging.getLogger(__name__))
    inbox = CalibrationInbox(RIG, rejected=rejected, foreign=Tally(logging.getLogger(__name__)))
    declared = inbox.declare(matcher_side, Tally(logging.getLogger(__name__)), time.monotonic())
    node = CalibratorNode(calibrator_side, RIG)
    token = declare_calibrator(calibrator_side, RIG)  # as the node's run declares it
    publisher = SourcedPublisher(matched_publisher(calibrator_side, keys.calibration(RIG)))
    try:
        def arrived() -> Calibration:
            assert wait_for(lambda: inbox.waiting, 60.0), "the calibration did not arrive"
            return inbox.take()

        source = decode_observations_message(observations_payload(seed=1))
        first = node.handle(observations_payload(seed=1), publisher)  # a first solve: nothing moved
        assert first is not None and first.status == Status.GOOD and not first.moved
        assert arrived() is not None and inbox.take_moved() == ()

        def publish(moved: tuple[str, ...]) -> None:  # as a solve that found `moved` publishes
            node._publish(publisher, first.calibration, source, replace(first, moved=moved), solving_ns=1,
                          received_ns=None)
            arrived()

        publish(("mono_b",))
        assert json.loads(node.latest_doc)["moved"] == ["mono_b"]  # the document as the contract has it
        assert inbox.take_moved() == ("mono_b",)
        publish(())
        assert inbox.take_moved() == (), "a camera forgotten again on a calibration that names none moved"
        # Named by two calibrations before the matcher looks: forgotten once.
        publish(("mono_b",))
        publish(("mono_a", "mono_b"))
        assert inbox.take_moved() == ("mono_a", "mono_b") and inbox.take_moved() == ()
        # One the matcher found moved itself (and forgot) is not named back to it: forgotten again, its views
        # since would be lost; the document still names it.
        node._publish(publisher, first.calibration, source, replace(first, moved=("mono_a", "mono_b"),
                                                                    told=("mono_b",)), solving_ns=1, received_ns=None)
        arrived()
        assert json.loads(node.latest_doc)["moved"] == ["mono_a", "mono_b"]
        assert inbox.take_moved() == ("mono_a",)
        assert rejected.total == 0
    finally:
        publisher.undeclare()
        token.undeclare()
        for entity in declared:
            entity.undeclare()


def test_the_attachment_round_trips_and_a_foreign_one_is_refused():
    assert moved_attachment([]) is None and parse_moved_attachment(None) == ()
    assert parse_moved_attachment(moved_attachment({"b", "a"})) == ("a", "b")
    for foreign in (b"\xff", b"[1]", b'{"moved": "a"}', b'{"moved": ["a/b"]}'):
        with pytest.raises(InputError, match="attachment|camera id"):
            parse_moved_attachment(foreign)


def test_the_matchers_forgotten_attachment_round_trips_and_a_foreign_one_is_refused():
    assert parse_forgotten_attachment(None) is None  # a source that says nothing of it
    assert parse_forgotten_attachment(forgotten_attachment({})) == {}
    assert parse_forgotten_attachment(forgotten_attachment({"mono_b": 1234, "mono_a": 0})) == {"mono_a": 0,
                                                                                               "mono_b": 1234}
    for foreign in (b"\xff", b"[1]", b'{"forgotten": ["a"]}', b'{"forgotten": {"a": -1}}', b'{"forgotten": {"a": 1.5}}',
                    b'{"forgotten": {"a": true}}', b'{"forgotten": {"a/b": 1}}'):
        with pytest.raises(InputError, match="attachment|camera id"):
            parse_forgotten_attachment(foreign)


def test_observations_with_a_foreign_attachment_are_solved_and_it_is_counted():
    class Publisher:
        def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
            self.payload = payload

    node, publisher = CalibratorNode(None, RIG), Publisher()
    outcome = node.handle(observations_payload(seed=1), publisher, attachment=b'{"forgotten": ["mono_b"]}')
    assert outcome is not None and outcome.status == Status.GOOD and json.loads(publisher.payload)["status"]
    assert node.malformed.counts == {"attachment": 1}
