"""Calibrations from another publisher than the rig's calibrator: counted, named in `camnet status`, and ignored by
the matcher and the recorder.

On loopback Zenoh: the rig's calibrator (the node itself) resumes its calibration, the ground truth. A forger on a
session of its own publishes well-formed calibrations of the rig with mono_b 20 m away, stating its session as
their source and stating none, and answers queries on the calibration key with one, for the whole test.
"""

from __future__ import annotations

import json
import logging
import threading

import numpy as np
import zenoh
from camnet.services.calibrator import CalibratorConfig, CalibratorNode
from camnet.services.matcher import MatcherNodeConfig
from camnet.services.recorder import Recorder, RecorderConfig
from mcap.reader import make_reader

from camnet.bus import keys
from camnet.bus.node import Tally
from camnet.bus.session import BusOptions, open_session
from camnet.bus.source import FOREIGN_CALIBRATIONS, HELD_PER_SOURCE, CalibratorSources, SourcedPublisher
from camnet.commands.status import suspicious
from camnet.io.formats import calibration_to_doc, parse_calibration
from camnet.io.rig import parse_rig
from camnet.model.calibration import Calibration
from tests.conftest import free_port, running_node, wait_for
from tests.test_matcher_node import network, rig_document  # noqa: F401 (network: the fixture)
from tests.test_matcher_viewgraph import calibration_with_mono_b_elsewhere

FORGED_PERIOD_S = 0.25


def truth_calibration(rig) -> dict:
    """The rig's ground truth as a calibration, with points in the textured box's region."""
    points = np.random.default_rng(0).uniform([-0.15, -0.15, 0.5], [0.3, 0.15, 0.8], (300, 3))
    return calibration_to_doc(Calibration(tuple(rig.simulated_truth()), np.arange(len(points)), points, 0.3, "left"))


def is_truth(calibration: Calibration, rig) -> bool:
    """Whether every camera of `calibration` is where the rig's ground truth has it (the forgery moves mono_b)."""
    truth = {c.id: c.centre for c in rig.simulated_truth()}
    return all(np.linalg.norm(c.centre - truth[c.id]) < 1e-6 for c in calibration.cameras)


class Forger:
    """Publishes a forged calibration every `FORGED_PERIOD_S` on `session` (stating its source, then stating
    none) on a thread, and answers queries with it, until closed."""

    def __init__(self, session, rig) -> None:
        key = keys.calibration(rig.name)
        self.payload = json.dumps(calibration_with_mono_b_elsewhere(rig)).encode()
        self.sent = 0
        self._sourced = SourcedPublisher(session.declare_publisher(key))
        self._plain = session.declare_publisher(key)
        self._queryable = session.declare_queryable(key, lambda query: query.reply(key, self.payload))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(FORGED_PERIOD_S):
            self._sourced.put(self.payload)
            self._plain.put(self.payload)
            self.sent += 2

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
        self._queryable.undeclare()


def test_the_matcher_takes_only_its_calibrators_calibrations(network, tmp_path):  # noqa: F811 (the fixture)
    rig = parse_rig(rig_document("calforge"))
    net = network(rig, MatcherNodeConfig(stats_period_s=0.5), start=False)
    # No camera runs: the matcher's worker takes no calibration, the test takes them all as they arrive.
    inbox = net.node.calibration
    taken: list[Calibration] = []

    def take() -> None:
        calibration = inbox.take()
        if calibration is not None:
            taken.append(calibration)

    state = tmp_path / "calibration.json"
    state.write_text(json.dumps(truth_calibration(rig)))
    forger = Forger(net.drivers_session, rig)  # answers the matcher's first query, before the calibrator runs
    try:
        net.start_matcher()
        # Those stating no source are counted as they come; a forgery taken ends the wait too.
        foreign = lambda: net.node.foreign.counts.get(FOREIGN_CALIBRATIONS, 0)  # noqa: E731
        assert wait_for(lambda: (take(), foreign() >= 4 or bool(taken))[1], 60.0), forger.sent
        take()
        assert not taken, "a forged calibration was taken"
        # The calibrator resumes (its only calibration here, published as it starts, and answered).
        with running_node(CalibratorNode(net.observer, rig.name, CalibratorConfig(state_path=state))):
            assert wait_for(lambda: (take(), bool(taken))[1], 60.0), "the calibrator's calibration never came"
            sent = forger.sent
            assert wait_for(lambda: (take(), forger.sent >= sent + 8)[1], 60.0)
        take()
        assert all(is_truth(calibration, rig) for calibration in taken), "a forged calibration was taken"
        assert wait_for(lambda: foreign() >= 4 + 4, 60.0), net.node.foreign.counts
        # The count goes out in the matcher's statistics, and `camnet status` flags it.
        assert wait_for(lambda: net.stats and net.stats[-1].faults.get(FOREIGN_CALIBRATIONS, 0) > 0, 60.0)
        lines = suspicious([("matcher", "matcher")], {("matcher", "matcher"): net.stats[-1]})
        assert any(line.startswith("matcher matcher: ") and "another publisher than the rig's calibrator" in line
                   for line in lines), lines
    finally:
        forger.close()


def test_the_recorder_writes_only_its_calibrators_calibrations(tmp_path):
    rig = parse_rig(rig_document("recforge"))
    state, path = tmp_path / "calibration.json", tmp_path / "session.mcap"
    state.write_text(json.dumps(truth_calibration(rig)))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sessions = [open_session(BusOptions(listen=(endpoint,)))]
    sessions += [open_session(BusOptions(connect=(endpoint,))) for _ in range(2)]
    calibrator_bus, forger_bus, recorder_bus = sessions
    recorder = Recorder(recorder_bus, RecorderConfig(rig=rig.name, path=path, flush_period_s=0.5,
                                                     stats_period_s=0.5))
    key = keys.calibration(rig.name)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("summary", recorder.run()), daemon=True)
    forger = None
    try:
        # The calibrator resumed before the recorder starts: the recorder has its calibration only by asking,
        # and the forger answers too.
        with running_node(CalibratorNode(calibrator_bus, rig.name, CalibratorConfig(state_path=state))) as node:
            assert wait_for(lambda: node.latest_doc is not None, 60.0), "the calibrator did not resume"
            forger = Forger(forger_bus, rig)
            thread.start()
            # A calibration written: the calibrator's answer.
            assert wait_for(lambda: recorder._sequence.get(key, 0) >= 1, 60.0), (forger.sent, recorder._sequence)
            sent = forger.sent
            assert wait_for(lambda: forger.sent >= sent + 16, 60.0)
    finally:
        if forger is not None:
            forger.close()
        recorder.stop.set()
        if thread.ident is not None:  # started
            thread.join(timeout=60)
        for session in reversed(sessions):
            session.close()
    with open(path, "rb") as stream:
        written = [parse_calibration(json.loads(message.data))
                   for _, channel, message in make_reader(stream).iter_messages() if channel.topic == key]
    assert written, "the calibrator's calibration was not written"
    assert all(is_truth(calibration, rig) for calibration in written), "a forged calibration was written"
    summary = result["summary"]
    assert summary.foreign_calibrations == recorder.foreign.total >= 4  # those stating no source, as they come
    assert any(line.startswith("calibrations from another publisher") for line in summary.lines())


class _Token:
    """A calibrator's liveliness token as Zenoh hands it to the callback: joined (PUT) or left (DELETE)."""

    def __init__(self, source: str, kind: zenoh.SampleKind) -> None:
        self.key_expr, self.kind = keys.calibrator("tokens", source), kind


def test_a_calibration_waits_for_its_calibrators_token_for_a_while_and_is_then_counted():
    foreign = Tally(logging.getLogger(__name__))
    sources = CalibratorSources(foreign, hold_s=10.0)
    handed: list[str] = []
    # The calibrator's first calibration and its answer, before its token; a forger's; one stating no source.
    sources.admit("c0ffee", lambda: handed.append("resumed"), now_s=0.0)
    sources.admit("c0ffee", lambda: handed.append("answer"), now_s=0.5)
    sources.admit("f00d", lambda: handed.append("forged"), now_s=1.0)
    sources.admit(None, lambda: handed.append("unstated"), now_s=1.0)
    assert handed == [] and foreign.total == 1  # no source: counted at once
    sources.on_token(_Token("c0ffee", zenoh.SampleKind.PUT))
    assert handed == ["resumed", "answer"]  # in the order they came
    sources.admit("c0ffee", lambda: handed.append("solved"), now_s=2.0)
    assert handed == ["resumed", "answer", "solved"]
    sources.expire(now_s=10.5)
    assert foreign.total == 1  # the forger's is still held
    sources.expire(now_s=11.0)
    assert foreign.counts == {FOREIGN_CALIBRATIONS: 2} and "forged" not in handed
    # Only the latest few of a source are held: the older ones are counted as the newer come.
    for n in range(HELD_PER_SOURCE + 3):
        sources.admit("f00d", lambda: handed.append("forged"), now_s=12.0 + n)
    assert foreign.total == 2 + 3
    # A calibrator that left is no longer taken from, until it declares itself again.
    sources.on_token(_Token("c0ffee", zenoh.SampleKind.DELETE))
    sources.admit("c0ffee", lambda: handed.append("after leaving"), now_s=20.0)
    assert handed == ["resumed", "answer", "solved"]
    sources.on_token(_Token("c0ffee", zenoh.SampleKind.PUT))
    assert handed[-1] == "after leaving" and "forged" not in handed
