"""The observations and calibration messages: typed values that encode to the bytes the nodes have always
published, decode back equal, and refuse what is malformed in one line."""

from __future__ import annotations

import json
from dataclasses import fields, replace

import numpy as np
import pytest
from camnet.drivers.sim import SimCamera
from camnet.services.calibrator import CalibratorNode
from camnet.services.matcher import MatcherNode, MatcherNodeConfig

from camnet.bus.frame import Frame
from camnet.bus.latency import StageStamps
from camnet.bus.sync import FrameSet
from camnet.io.formats import calibration_to_doc, observations_to_doc
from camnet.io.messages import (
    CalibrationMessage,
    MessageError,
    ObservationsMessage,
    decode_calibration_message,
    decode_observations_message,
    encode_calibration_message,
    encode_observations_message,
    load_calibration_message,
)
from camnet.io.rig import parse_rig
from camnet.live.policy import LIVE_FREE
from camnet.model.observations import Stereo
from camnet.sim.scene import Scene
from camnet.sim.simulate import make_rig, observe
from camnet.solve.options import Options
from camnet.solve.pipeline import calibrate
from camnet.solve.report.verdict import judge
from tests.test_matcher_node import rig_document


class Publisher:
    """What a node puts, kept."""

    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        self.payloads.append(payload)


@pytest.fixture(scope="module")
def matcher_bytes() -> tuple[MatcherNode, bytes]:
    """A matcher node after three frame sets of a simulated rig's rendered frames, and its last publication."""
    rig = parse_rig(rig_document("msgs"))
    node = MatcherNode(None, rig, config=MatcherNodeConfig())  # process() needs no bus
    cameras = [SimCamera(e.id, e.config, Scene(rig.scene)) for e in rig.cameras]
    publisher = Publisher()
    for slot in (10, 20, 30):
        frames = {c.camera_id: Frame(c.camera_id, slot, c.slot_timestamp_ns(slot), "mono8", c.render(slot))
                  for c in cameras}
        node.process(FrameSet(cameras[0].slot_timestamp_ns(slot), frames))
        assert node._publish_if_due(publisher, float(slot), force=True)
    return node, publisher.payloads[-1]


@pytest.fixture(scope="module")
def solved() -> tuple[ObservationsMessage, bytes]:
    """An observations message as the matcher sends it, and the calibration the calibrator publishes of it."""
    obs = observe(make_rig(n_points=150, seed=3), seed=3).observations
    message = ObservationsMessage(obs, rig="msgs", pool_id="ab12", frame_sets=5, latest_capture_ns=1_000,
                                  latency_ns=StageStamps(taken_ns=2_000, detected_ns=3_000, matched_ns=4_000,
                                                         pooled_ns=5_000), published_ns=6_000)
    publisher = Publisher()
    outcome = CalibratorNode(None, "msgs").handle(encode_observations_message(message), publisher,
                                                 received_ns=7_000)
    assert outcome is not None and outcome.status == "good", outcome
    return message, publisher.payloads[-1]


def same_observations(a, b) -> bool:
    """Whether `a` and `b` say the same on the wire: the stereo pair as the contract has it (the matcher's
    rig file also says how to match it, which stays with the matcher)."""
    a, b = (replace(o, stereo=Stereo(o.stereo.left, o.stereo.right, o.stereo.baseline_m, sigma_m=o.stereo.sigma_m))
            for o in (a, b))
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) if isinstance(getattr(a, f.name), np.ndarray)
               else getattr(a, f.name) == getattr(b, f.name) for f in fields(a))


def envelope(message) -> dict:
    return {f.name: getattr(message, f.name) for f in fields(message)[1:]}


def test_the_matchers_bytes_are_the_contracts_document_then_its_envelope(matcher_bytes):
    node, payload = matcher_bytes
    message = decode_observations_message(payload)
    obs = message.observations
    assert len(obs.track_ids) > 100 and message.frame_sets == 3
    # The bytes as the formats contract writes them, and the envelope after, key by key as it always was.
    stamps = message.latency_ns
    doc = {**observations_to_doc(obs), "rig": "msgs", "pool_id": node.engine.pool_id, "frame_sets": 3,
           "latest_capture_ns": node.latest_capture_ns,
           "latency_ns": {"taken": stamps.taken_ns, "detected": stamps.detected_ns, "matched": stamps.matched_ns,
                          "pooled": stamps.pooled_ns}, "published_ns": message.published_ns}
    assert payload == json.dumps(doc).encode()
    assert message.latest_capture_ns <= stamps.taken_ns < stamps.detected_ns < stamps.pooled_ns < message.published_ns
    # Decoded and encoded again: the same bytes, through the codec and the matcher's incremental encoder.
    assert encode_observations_message(message) == payload
    assert node._encoder.encode(message) == payload


def test_an_observations_message_decodes_to_the_message_encoded(matcher_bytes, solved):
    node, _ = matcher_bytes
    for message in (node.message(), solved[0], ObservationsMessage(solved[0].observations)):
        decoded = decode_observations_message(encode_observations_message(message))
        assert envelope(decoded) == envelope(message)
        assert same_observations(decoded.observations, message.observations)


def test_the_calibrators_bytes_decode_and_encode_again_unchanged(solved):
    observations, payload = solved
    message = decode_calibration_message(payload)
    assert encode_calibration_message(message) == payload
    assert message.rig == "msgs" and message.solve == 1 and message.warm_start is False and message.moved == ()
    assert message.status == judge(message.calibration).level
    assert (message.frame_sets, message.latest_capture_ns) == (5, 1_000)
    assert message.latency_ns == replace(observations.latency_ns, published_ns=6_000, solving_ns=message.latency_ns
                                         .solving_ns, received_ns=7_000)
    assert message.solved_ns >= message.latency_ns.solving_ns > 6_000
    # The contract's document first, then the calibrator's keys, in their order.
    doc = json.loads(payload)
    contract = calibration_to_doc(message.calibration)
    assert list(doc)[:len(contract)] == list(contract)
    assert list(doc)[len(contract):] == ["rig", "solve", "status", "warm_start", "moved", "solved_ns",
                                         "latest_capture_ns", "frame_sets", "latency_ns"]
    assert list(doc["latency_ns"]) == ["taken", "detected", "matched", "pooled", "published", "solving", "received"]
    resumed = decode_calibration_message(encode_calibration_message(replace(message, resumed=True)))
    assert envelope(resumed) == {**envelope(message), "resumed": True}


def test_a_contract_document_alone_is_a_message_without_envelope(tmp_path):
    obs = observe(make_rig(n_points=40, seed=1), seed=1).observations
    message = decode_observations_message(json.dumps(observations_to_doc(obs)).encode())
    assert all(value is None for value in envelope(message).values())
    assert same_observations(message.observations, obs)
    cal = calibrate(obs, Options(free=LIVE_FREE)).calibration
    (tmp_path / "calibration.json").write_text(json.dumps(calibration_to_doc(cal)))
    loaded = load_calibration_message(tmp_path / "calibration.json")
    assert envelope(loaded) == envelope(CalibrationMessage(cal))
    assert encode_calibration_message(loaded) == json.dumps(calibration_to_doc(cal)).encode()


def test_decoding_keeps_at_most_max_tracks_and_says_of_how_many():
    obs = observe(make_rig(n_points=60, seed=2), seed=2).observations
    payload = encode_observations_message(ObservationsMessage(obs, frame_sets=2))
    message = decode_observations_message(payload, max_tracks=25, subsample_seed=0)
    assert len(message.observations.track_ids) == 25 and message.subsampled_from == len(obs.track_ids)
    assert decode_observations_message(payload, max_tracks=100, subsample_seed=0).subsampled_from is None


OBSERVATIONS_SPOILED = [
    (b"{not json", "json", "observations: not valid JSON"),
    (lambda d: d.pop("tracks"), "tracks", "tracks: missing"),
    (lambda d: d.update(pool_id=7), "pool_id", "pool_id: expected a non-empty string, got 7"),
    (lambda d: d.update(pool_id=None), "pool_id", "pool_id: expected a non-empty string"),
    (lambda d: d.update(frame_sets="3"), "frame_sets", "frame_sets: expected an integer, got '3'"),
    (lambda d: d.update(frame_sets=-1), "frame_sets", "frame_sets: expected 0 to"),
    (lambda d: d.update(latest_capture_ns=True), "latest_capture_ns", "latest_capture_ns: expected an integer"),
    (lambda d: d.update(published_ns=1.5e18), "published_ns", "published_ns: expected an integer"),
    (lambda d: d.update(latency_ns=[1, 2]), "latency_ns", "latency_ns: expected an object, got list"),
    (lambda d: d.update(latency_ns={"taken": "soon"}), "latency_ns.taken", "latency_ns.taken: expected an integer"),
    (lambda d: d.update(rig="a/b"), "rig", "rig: 'a/b' contains '/'"),
]


@pytest.mark.parametrize("spoil, kind, message", OBSERVATIONS_SPOILED)
def test_a_malformed_observations_message_is_refused_in_one_line_naming_the_key(solved, spoil, kind, message):
    payload = _spoiled(encode_observations_message(solved[0]), spoil)
    with pytest.raises(MessageError) as err:
        decode_observations_message(payload)
    assert err.value.kind == kind and str(err.value).startswith(message) and "\n" not in str(err.value)


CALIBRATION_SPOILED = [
    (b"{\"format\": \"\x80\"}", "json", "calibration: not UTF-8 text"),
    (lambda d: d.pop("cameras"), "cameras", "cameras: missing"),
    (lambda d: d.update(status="great"), "status", "status: unknown value 'great'"),
    (lambda d: d.update(solve=-2), "solve", "solve: expected 0 to"),
    (lambda d: d.update(moved="mono_b"), "moved", "moved: expected a list, got str"),
    (lambda d: d.update(warm_start="yes"), "warm_start", "warm_start: expected true or false"),
    (lambda d: d.update(resumed=1), "resumed", "resumed: expected true or false"),
    (lambda d: d["latency_ns"].update(received=2**63), "latency_ns.received", "latency_ns.received: integer out"),
]


@pytest.mark.parametrize("spoil, kind, message", CALIBRATION_SPOILED)
def test_a_malformed_calibration_message_is_refused_in_one_line_naming_the_key(solved, spoil, kind, message):
    with pytest.raises(MessageError) as err:
        decode_calibration_message(_spoiled(solved[1], spoil))
    assert err.value.kind == kind and str(err.value).startswith(message) and "\n" not in str(err.value)


@pytest.mark.parametrize("spoil, kind, _", OBSERVATIONS_SPOILED)
def test_the_calibrator_counts_a_malformed_message_and_publishes_nothing(solved, spoil, kind, _):
    """A wrong-typed envelope is counted, not solved with its values copied into the calibration as they came."""
    node, publisher = CalibratorNode(None, "msgs"), Publisher()
    assert node.handle(_spoiled(encode_observations_message(solved[0]), spoil), publisher) is None
    assert node.malformed.counts == {kind: 1} and publisher.payloads == [] and node.tracker.solves == 0


def _spoiled(payload: bytes, spoil) -> bytes:
    if isinstance(spoil, bytes):
        return spoil
    doc = json.loads(payload)
    spoil(doc)
    return json.dumps(doc).encode()

