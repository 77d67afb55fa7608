"""The calibrator with its rig file: forged observations and a state file of another rig are refused."""

import json
from pathlib import Path

from camnet.services.calibrator import MAX_MESSAGE_BYTES, CalibratorConfig, CalibratorNode

from camnet.bus import keys
from camnet.io.formats import calibration_to_doc, observations_to_doc
from camnet.io.rig import load_rig
from camnet.sim.simulate import make_rig, observe
from tests.conftest import matched_publisher, running_node, wait_for
from tests.test_hardening import sim_calibration

RIG = load_rig(Path(__file__).resolve().parents[1] / "config" / "sim.yaml")


def running(session, state_path):
    return running_node(CalibratorNode(session, RIG.name, CalibratorConfig(state_path=state_path), rig=RIG))


def test_forged_observations_and_a_foreign_state_file_are_refused(zenoh_pair, tmp_path):
    a, b = zenoh_pair
    state = tmp_path / "calibration.json"
    state.write_text(json.dumps(calibration_to_doc(sim_calibration(4.0))))  # another rig: 0.5 m apart
    got = []
    sub = b.declare_subscriber(keys.calibration(RIG.name), lambda s: got.append(json.loads(s.payload.to_bytes())))
    try:
        with running(a, state) as node:
            assert wait_for(lambda: list(tmp_path.glob("calibration.json.other-rig-*")), 30)
            assert node.tracker.good is None and not state.exists()
            publisher = matched_publisher(b, keys.observations(RIG.name))
            forged = observations_to_doc(observe(make_rig(seed=4), seed=4).observations)
            forged["stereo"]["baseline_m"] = 0.5
            publisher.put(json.dumps(forged).encode())
            assert wait_for(lambda: node.malformed.counts.get("other rig") == 1, 30)
            publisher.put(b" " * (MAX_MESSAGE_BYTES + 1))
            assert wait_for(lambda: node.malformed.counts.get("too large") == 1, 30)
            assert not got and node.tracker.solves == 0
            forged["stereo"]["baseline_m"] = 0.125
            publisher.put(json.dumps(forged).encode())
            assert wait_for(lambda: got, 90), "the rig's own observations were not solved"
            # Published as a calibration, its status the verdict on it (57 points: not necessarily good).
            assert got[-1]["status"] == got[-1]["verdict"]["level"] and node.tracker.good is not None
    finally:
        sub.undeclare()
