"""What `camnet up` takes from the calibration key: only calibrations, whoever publishes there."""

import json

from camnet.bus import keys
from camnet.bus.source import SourcedPublisher
from camnet.commands.up import LatestCalibration
from camnet.io.formats import calibration_to_doc
from camnet.io.messages import calibration_message_to_doc
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from tests.conftest import matched_publisher, wait_for


def test_anything_but_a_calibration_is_counted_and_never_kept(zenoh_pair):
    """Two bytes, {}, on the calibration key must not stop camnet up and its nodes."""
    a, b = zenoh_pair
    listener = LatestCalibration()
    subscriber = a.declare_subscriber(keys.calibration("uptest"), listener)
    try:
        publisher = matched_publisher(b, keys.calibration("uptest"))
        good = calibration_to_doc(calibrate(observe(make_rig(seed=1), seed=1).observations).calibration)
        # The last: a calibration whose solve number is no number (not to be shown as solve 'three').
        for junk in (b"{}", b"[" * 100_000, b"\xff\xfe", json.dumps({"format": "camnet.calibration/1"}).encode(),
                     json.dumps({**good, "solve": "three"}).encode()):
            publisher.put(junk)
        assert wait_for(lambda: sum(listener.malformed.counts.values()) == 5), listener.malformed.counts
        assert listener.malformed.counts["solve"] == 1
        assert listener.latest is None and not listener.arrived.is_set()
        publisher.put(json.dumps(good).encode())
        assert wait_for(listener.arrived.is_set)
        assert calibration_message_to_doc(listener.latest)["cameras"] == good["cameras"]
    finally:
        subscriber.undeclare()


def test_a_calibration_that_does_not_state_the_calibrators_session_is_counted_and_never_kept(zenoh_pair):
    """Given the session of the rig's calibrator, camnet up keeps only the calibrations that state it."""
    a, b = zenoh_pair
    listener = LatestCalibration(source=str(b.zid()))
    subscriber = a.declare_subscriber(keys.calibration("uptest"), listener)
    try:
        plain = matched_publisher(b, keys.calibration("uptest"))
        good = calibration_to_doc(calibrate(observe(make_rig(seed=1), seed=1).observations).calibration)
        for solve in (7, 8):  # well-formed, from the right session, but stating no source
            plain.put(json.dumps({**good, "solve": solve}).encode())
        assert wait_for(lambda: listener.foreign.total == 2), listener.foreign.counts
        assert listener.latest is None and not listener.arrived.is_set()
        SourcedPublisher(plain).put(json.dumps({**good, "solve": 9}).encode())
        assert wait_for(listener.arrived.is_set)
        assert listener.latest.solve == 9 and listener.foreign.total == 2 and listener.malformed.total == 0
    finally:
        subscriber.undeclare()
