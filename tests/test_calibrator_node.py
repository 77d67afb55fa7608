"""The calibrator node on real Zenoh peers (loopback, scouting off)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from camnet.services.calibrator import CalibratorConfig, CalibratorNode, load_state

from camnet.bus import keys
from camnet.bus.lockstep import Ack
from camnet.errors import InputError
from camnet.io.formats import observations_to_doc, parse_calibration
from camnet.sim.simulate import make_rig, observe
from camnet.solve.report.verdict import judge
from tests.conftest import free_port, matched_publisher, running_node, wait_for

RIG = "calnode"


def running(session, config):
    return running_node(CalibratorNode(session, RIG, config))


def observations_payload(seed: int, n_points: int = 150) -> bytes:
    doc = observations_to_doc(observe(make_rig(n_points=n_points, seed=seed), seed=seed).observations)
    doc["latest_capture_ns"] = 123
    return json.dumps(doc).encode()


def test_solves_publishes_persists_and_answers_late_joiners(zenoh_pair, tmp_path):
    a, b = zenoh_pair
    state = tmp_path / "calibration.json"
    got = []
    sub = b.declare_subscriber(keys.calibration(RIG), lambda s: got.append(json.loads(s.payload.to_bytes())))
    try:
        with running(a, CalibratorConfig(state_path=state)) as node:
            publisher = matched_publisher(b, keys.observations(RIG))
            publisher.put(b"{not json")
            assert wait_for(lambda: node.malformed.counts == {"json": 1})
            publisher.put(json.dumps({"format": "camnet.observations/1", "cameras": 3}).encode())
            assert wait_for(lambda: node.malformed.counts == {"json": 1, "cameras": 1})
            publisher.put(observations_payload(seed=1))
            assert wait_for(lambda: got, 60), "no calibration published"
            doc = got[-1]
            assert doc["rig"] == RIG and doc["latest_capture_ns"] == 123
            cal = parse_calibration(doc)
            assert doc["status"] == judge(cal).level.value  # the verdict's level, not a fixed "good"
            assert {c.id for c in cal.cameras} == {"left", "right", "mono_a", "mono_b"}
            # Written after it is published.
            assert wait_for(lambda: state.exists() and json.loads(state.read_text())["solve"] == doc["solve"])
            replies = list(b.get(keys.calibration(RIG), timeout=30.0))
            assert len(replies) == 1
            assert json.loads(replies[0].ok.payload.to_bytes())["solve"] == doc["solve"]
    finally:
        sub.undeclare()


def test_a_restarted_calibrator_resumes_from_its_state(zenoh_pair, tmp_path):
    a, b = zenoh_pair
    state = tmp_path / "calibration.json"
    with running(a, CalibratorConfig(state_path=state)) as node:
        publisher = matched_publisher(b, keys.observations(RIG))
        publisher.put(observations_payload(seed=2))
        assert wait_for(lambda: node.tracker.good is not None, 60)
        first = node.tracker.good
    with running(a, CalibratorConfig(state_path=state)) as node:
        replies = []
        # The queryable is declared just after the resumed calibration is loaded; let it reach the other peer.
        assert wait_for(lambda: replies.extend(r for r in b.get(keys.calibration(RIG), timeout=1.0) if r.ok)
                        or replies)
        resumed_doc = json.loads(replies[0].ok.payload.to_bytes())
        assert resumed_doc["resumed"] is True and resumed_doc["solve"] == 1  # said so, with its number
        resumed = parse_calibration(resumed_doc)
        for cam, before in zip(resumed.cameras, first.cameras, strict=True):
            np.testing.assert_array_equal(cam.K, before.K)
            np.testing.assert_array_equal(cam.t, before.t)
        # The next solve is warm-started from the resumed calibration.
        publisher = matched_publisher(b, keys.observations(RIG))
        publisher.put(observations_payload(seed=2, n_points=160))
        assert wait_for(lambda: sum(node.tracker.counts.values()) == 1, 60)
        assert node.tracker.counts["good"] == 1
        assert node.tracker.solves == 2  # numbered on from the resumed solve 1: a number names one calibration


def test_on_stopping_it_writes_the_observations_behind_its_last_calibration(zenoh_pair, tmp_path):
    from camnet.io.messages import load_calibration_message
    from camnet.io.run_dir import observations_behind

    a, b = zenoh_pair
    state, solved_from = tmp_path / "calibration.json", tmp_path / "observations.json"
    with running(a, CalibratorConfig(state_path=state, observations_path=solved_from)) as node:
        publisher = matched_publisher(b, keys.observations(RIG))
        publisher.put(observations_payload(seed=3))
        assert wait_for(lambda: node.tracker.counts["good"] == 1, 60)
        publisher.put(b"{not json")  # not solved: the file names the last one published
        assert wait_for(lambda: node.malformed.counts == {"json": 1})
        assert not solved_from.exists()  # written once, when it stops
    kept = observations_behind(solved_from, load_calibration_message(state))
    assert kept is not None and kept.latest_capture_ns == 123
    assert len(kept.observations.track_ids) == len(json.loads(observations_payload(seed=3))["tracks"])


@pytest.mark.parametrize("content", [b"\xff\xfe{}", b"[" * 100_000, b'{"format": "camnet.calibration/1", "cameras": '
                                     b'[{"id": "a", "width": 100000000000000000000000000000, "height": 1}]}'])
def test_a_state_file_that_is_not_a_calibration_is_moved_aside_with_a_warning(tmp_path, content, caplog):
    state = tmp_path / "calibration.json"
    state.write_bytes(content)
    assert load_state(state) is None
    aside = list(tmp_path.glob("calibration.json.damaged-*"))
    assert len(aside) == 1 and aside[0].read_bytes() == content and not state.exists()
    assert "cannot resume from it" in caplog.text


def test_a_damaged_state_file_is_kept_aside(zenoh_pair, tmp_path):
    a, _ = zenoh_pair
    state = tmp_path / "calibration.json"
    state.write_text('{"format": "camnet.calibration/1", "cameras": [')
    with running(a, CalibratorConfig(state_path=state)) as node:
        assert node.tracker.good is None
    aside = list(tmp_path.glob("calibration.json.damaged-*"))
    assert len(aside) == 1 and aside[0].read_text().startswith('{"format"')


@pytest.mark.parametrize(("mode", "who"), [(0o664, "its group"), (0o646, "others"), (0o666, "its group and others")])
def test_a_state_file_others_may_write_is_refused_naming_the_fix(tmp_path, mode, who):
    state = tmp_path / "calibration.json"
    state.write_text('{"format": "camnet.calibration/1"}')
    state.chmod(mode)
    with pytest.raises(InputError, match=f"chmod go-w {state}"):
        load_state(state)
    proc = subprocess.run([sys.executable, "-m", "camnet.cli", "calibrator", "--rig", RIG, "--state", str(state),
                           "--connect", f"tcp/127.0.0.1:{free_port()}"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (f"camnet calibrator: error: --state {state}: writable by {who}, so anyone may have "
                                   f"written it and it is not resumed; make it its owner's alone: chmod go-w {state}")
    # Refused as it is: neither moved aside nor replaced.
    assert [p.name for p in tmp_path.iterdir()] == ["calibration.json"]
    assert state.read_text() == '{"format": "camnet.calibration/1"}' and state.stat().st_mode & 0o777 == mode


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a file to another user takes root")
def test_a_state_file_of_another_user_is_refused(tmp_path):
    state = tmp_path / "calibration.json"
    state.write_text('{"format": "camnet.calibration/1"}')
    os.chown(state, 54321, -1)
    with pytest.raises(InputError, match=f"{state}: owned by uid 54321, not by .* who runs the calibrator, so it is "
                                         f"not resumed; remove it, or make it .*'s: chown .* {state}"):
        load_state(state)
    assert state.exists()


def test_command_refuses_bad_flags_in_one_line(tmp_path):
    for flags, fragment in ((["--rig", "a*b"], "--rig"), (["--rig", "r", "--max-rms-px", "0"], "--max-rms-px"),
                            (["--rig", str(tmp_path / "missing.yaml")], "missing.yaml"),
                            (["--rig", "r", "--session-id", "not-hex"], "--session-id")):
        proc = subprocess.run([sys.executable, "-m", "camnet.cli", "calibrator", *flags],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and fragment in lines[0], proc.stderr


def test_solves_that_are_not_kept_warn_once_a_period_not_each_time(caplog):
    """A rig whose every solve is refused: one warning a period, not one per solve."""
    import logging

    from camnet.live.policy import LiveConfig, SoundnessLimits

    node = CalibratorNode(None, RIG, CalibratorConfig(live=LiveConfig(limits=SoundnessLimits(max_rms_px=1e-9))))
    caplog.set_level(logging.INFO, logger="camnet.services.calibrator")
    payload = observations_payload(seed=3, n_points=80)
    outcomes = [node.handle(payload, publisher=None) for _ in range(3)]
    assert [o.status for o in outcomes] == ["rejected"] * 3
    kept_back = [r for r in caplog.records if "the last good calibration stays" in r.getMessage()]
    assert [r.levelname for r in kept_back] == ["WARNING", "INFO", "INFO"]
    assert node.tracker.counts["rejected"] == 3


def test_in_lockstep_each_message_is_acknowledged_naming_the_one_solved(zenoh_pair):
    a, b = zenoh_pair
    acks = []
    sub = b.declare_subscriber(keys.lockstep_ack(RIG, "calibrator"),
                               lambda s: acks.append(Ack.parse(s.payload.to_bytes())))
    try:
        with running_node(CalibratorNode(a, RIG, CalibratorConfig(), lockstep=True)):
            publisher = matched_publisher(b, keys.observations(RIG))
            publisher.put(b"{not json")  # names no message: the replayer waits for none
            assert wait_for(lambda: len(acks) == 1)
            publisher.put(json.dumps({**json.loads(observations_payload(seed=3)), "pool_id": "p",
                                      "frame_sets": 4}).encode())
            assert wait_for(lambda: len(acks) == 2, 60)
    finally:
        sub.undeclare()
    assert acks == [Ack(status="not solved"), Ack(pool_id="p", frame_sets=4, status="good")]
