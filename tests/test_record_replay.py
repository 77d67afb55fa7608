"""Recording a rig to MCAP and replaying it, on real Zenoh peers over loopback (scouting off).

One session is recorded once per module from three sim driver nodes (320x256)
plus frames, observations and a calibration published by the test; the
replay tests and the damaged-file tests read that file.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from camnet.services.recorder import ChunkCompression, Recorder, RecorderConfig
from camnet.services.recording_gaps import ByteBoundedQueue
from camnet.services.replayer import Replayer, ReplayOptions
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from camnet.bus import keys
from camnet.bus.frame import FrameError, encode_frame
from camnet.bus.session import BusOptions, open_session
from camnet.bus.source import SourcedPublisher, declare_calibrator
from camnet.errors import InputError
from camnet.io.rig import parse_rig
from camnet.io.session_file import (
    FRAME_SCHEMA,
    GAP_FORMAT,
    frame_header,
    frame_schema,
    gaps_topic,
    open_session_file,
)
from tests.conftest import free_port, matched_publisher, open_patient_session, wait_for
from tests.test_frame import _malformed, make_frame

ROOT = Path(__file__).resolve().parent.parent
RIG = "rec"
CAMERAS = ("left", "right", "mono")
INJECTED = "inject"
INJECTED_SEQS = (0, 1, 2, 5, 6, 3)  # a gap of two (3, 4), then a restart at 3
MIN_FRAMES = 20  # recorded of each camera
OBSERVATIONS = {"format": "camnet.observations/1", "cameras": [], "tracks": []}
CALIBRATION = {"format": "camnet.calibration/1", "cameras": [], "points": []}


def _features(seq: int) -> bytes:
    from camnet.bus.features_wire import FeaturesMessage, encode_features

    rng = np.random.default_rng(seq)
    return encode_features(FeaturesMessage("left", seq, seq * 50_000_000, 320, 256, "sift", 0, 0,
                                           rng.random((4, 2)) * 200, rng.integers(0, 256, (4, 128), np.uint8)))


FEATURES = [_features(seq) for seq in (1, 2)]  # a feature stage's messages, recorded and replayed as they came


def small_rig():
    sim = {"width": 320, "height": 256, "encoding": "mono8", "fps": 20, "f_px": 380,
           "cx_px": 159.5, "cy_px": 127.5}
    centres = {"left": [0.0, 0.0, 0.0], "right": [0.125, 0.0, 0.0], "mono": [-0.3, 0.0, 0.05]}
    cameras = [{"id": cid, "driver": "sim", "sim": {**sim, "centre_m": centres[cid]}}
               for cid in CAMERAS]
    cameras[2]["sim"]["look_at_m"] = [0.0625, 0.0, 0.65]
    return parse_rig({"rig": RIG, "stereo": {"left": "left", "right": "right", "baseline_m": 0.125, "parallel": True},
                      "scene": {"seed": 3}, "cameras": cameras})


def run_in_thread(target) -> threading.Thread:
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(path, recorder summary, injected frame payloads): ~2.5 s of a 3-camera sim rig."""
    from camnet.drivers.node import DriverNode
    from camnet.drivers.sim import create

    path = tmp_path_factory.mktemp("session") / "session.mcap"
    rig = small_rig()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bus = open_session(BusOptions(listen=(endpoint,)))
    recorder_bus = open_session(BusOptions(connect=(endpoint,)))
    recorder = Recorder(recorder_bus, RecorderConfig(rig=RIG, path=path, flush_period_s=0.5,
                                                      compression=ChunkCompression.ZSTD))
    result = {}
    nodes, threads = [], []
    left: set[str] = set()  # the nodes whose leaving the recorder's session has seen

    def on_token(sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            left.add(str(sample.key_expr).rsplit("/", 1)[-1])

    recorder_bus.liveliness().declare_subscriber(keys.all_nodes(RIG), on_token)
    token = declare_calibrator(bus, RIG)  # noqa: F841 (kept: a token dropped is undeclared); the test publishes as the calibrator
    try:
        threads.append(run_in_thread(lambda: result.setdefault("summary", recorder.run())))
        injector = matched_publisher(bus, keys.frame(RIG, INJECTED))
        for entry in rig.cameras:
            node = DriverNode(bus, rig, create(entry, rig), stats_period_s=0.5)
            nodes.append(node)
            threads.append(run_in_thread(node.run))
        time.sleep(1.0)
        injected = [encode_frame(make_frame("mono8", seq=seq, camera_id=INJECTED))
                    for seq in INJECTED_SEQS]
        for payload in injected:
            injector.put(payload)
        bus.put(keys.observations(RIG), json.dumps(OBSERVATIONS))
        SourcedPublisher(bus.declare_publisher(keys.calibration(RIG))).put(json.dumps(CALIBRATION).encode())
        for payload in FEATURES:
            bus.put(keys.features(RIG, "left"), payload)
        bus.put(keys.observations(RIG), b"not json")  # counted, not written
        # The recorder has written all put before it once it has counted the last (one session,
        # one priority: they arrive in order), however loaded the machine.
        assert wait_for(lambda: recorder.malformed.counts.get("json") == 1, 120.0), recorder.summary()
        # Enough frames of every camera, as long as they keep coming (a loaded machine renders them slowly).
        written = lambda: {c: t.frames for c, t in recorder.summary().cameras.items()}  # noqa: E731
        assert wait_for(lambda: all(written().get(c, 0) > MIN_FRAMES for c in CAMERAS), 60.0, progress=written), \
            written()
    finally:
        for node in nodes:
            node.stop.set()
        for thread in threads[1:]:  # the drivers: their liveliness tokens go as they end
            thread.join(timeout=20)
        # Their leaving reaches the recorder's session (seen here on it) and is written before it stops
        # (on stopping it writes what is queued for only a second); the tests below say if it was not.
        wait_for(lambda: left >= set(CAMERAS), 60.0)
        wait_for(lambda: recorder._queue.backlog()[0] == 0, 60.0, progress=lambda: recorder._messages)
        recorder.stop.set()
        for thread in threads:
            thread.join(timeout=20)
        recorder_bus.close()
        bus.close()
    assert "summary" in result, "the recorder did not finish"
    return path, result["summary"], injected


def read_all(path):
    """(schemas by name, channels by topic, messages by topic in file order) via mcap's reader."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        by_topic: dict[str, list] = {}
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            by_topic.setdefault(channel.topic, []).append(message)
        schemas = {s.name: s for s in summary.schemas.values()}
        channels = {c.topic: c for c in summary.channels.values()}
        return schemas, channels, by_topic, summary


def test_file_is_standard_mcap_with_schemas_and_channels(recorded):
    path, _, _ = recorded
    schemas, channels, by_topic, summary = read_all(path)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "camnet"
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert metadata["camnet.session"]["rig"] == RIG
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    frame_schema_record = schemas[FRAME_SCHEMA]
    assert json.loads(frame_schema_record.data)["magic"] == "CNFR"
    for name in ("camnet.calibration/1", "camnet.observations/1", "camnet.node-stats/1",
                 "camnet.node-event/1"):
        assert schemas[name].encoding == "jsonschema"
        assert json.loads(schemas[name].data)["type"] == "object"
    for camera_id in (*CAMERAS, INJECTED):
        channel = channels[keys.frame(RIG, camera_id)]
        assert channel.message_encoding == FRAME_SCHEMA
        assert summary.schemas[channel.schema_id].name == FRAME_SCHEMA
    for key in (keys.groundtruth(RIG), keys.observations(RIG), keys.calibration(RIG),
                keys.node_stats(RIG, "driver", "left"), keys.node(RIG, "driver", "left")):
        assert channels[key].message_encoding == "json"
        for message in by_topic[key]:
            assert isinstance(json.loads(message.data), dict)
    truth = json.loads(by_topic[keys.groundtruth(RIG)][0].data)
    assert {c["id"] for c in truth["cameras"]} == set(CAMERAS)
    assert [json.loads(m.data) for m in by_topic[keys.observations(RIG)]] == [OBSERVATIONS]
    events = [json.loads(m.data)["event"] for m in by_topic[keys.node(RIG, "driver", "mono")]]
    assert events == ["joined", "left"]
    for message in by_topic[keys.frame(RIG, "left")]:
        assert message.publish_time == frame_header(message.data).timestamp_ns
        assert message.log_time >= message.publish_time


def test_every_frame_is_accounted_for(recorded):
    path, summary, _ = recorded
    _, _, by_topic, _ = read_all(path)
    gaps = [json.loads(m.data) for m in by_topic.get(gaps_topic(RIG), [])]
    assert all(g["format"] == GAP_FORMAT for g in gaps)
    for camera_id in CAMERAS:
        seqs = [frame_header(m.data).seq for m in by_topic[keys.frame(RIG, camera_id)]]
        assert len(seqs) > MIN_FRAMES
        assert seqs == sorted(seqs)
        missing = sum(g["missing"] for g in gaps if g["camera_id"] == camera_id)
        assert len(seqs) + missing == seqs[-1] - seqs[0] + 1
        tally = summary.cameras[camera_id]
        assert (tally.frames, tally.missing, tally.first_seq, tally.last_seq) == \
            (len(seqs), missing, seqs[0], seqs[-1])
    assert summary.malformed == {"json": 1}


def test_injected_gap_and_restart_are_written(recorded):
    path, summary, injected = recorded
    _, _, by_topic, _ = read_all(path)
    assert [m.data for m in by_topic[keys.frame(RIG, INJECTED)]] == injected
    gaps = [json.loads(m.data) for m in by_topic[gaps_topic(RIG)]]
    mine = [(g["kind"], g["last_seq"], g["seq"], g["missing"]) for g in gaps
            if g["camera_id"] == INJECTED]
    assert mine == [("gap", 2, 5, 2), ("restart", 6, 3, 0)]
    tally = summary.cameras[INJECTED]
    assert (tally.frames, tally.missing, tally.gaps, tally.restarts) == (6, 2, 1, 1)


def test_queue_bounded_in_bytes_counts_what_it_refuses():
    queue = ByteBoundedQueue(25)
    for _ in range(3):
        queue.put("k", b"x" * 10)
    assert queue.take_refused("k") == 1 and queue.take_refused("k") == 0 and queue.refused == 1
    times = [queue.get(timeout_s=0).log_time_ns for _ in range(2)]
    assert times == sorted(times) and queue.get(timeout_s=0) is None


def test_frame_schema_offsets_match_the_wire_format():
    frame = make_frame("bgr8", seq=123_456_789, camera_id="cam")
    data = encode_frame(frame)
    fields = {f["name"]: f for f in json.loads(frame_schema())["fields"]}
    for name, value in (("seq", frame.seq), ("timestamp_ns", frame.timestamp_ns),
                        ("width", frame.width), ("height", frame.height)):
        f = fields[name]
        assert int.from_bytes(data[f["offset"]:f["offset"] + f["size"]], "little") == value
    header = frame_header(data)
    assert (header.camera_id, header.seq, header.timestamp_ns) == ("cam", frame.seq,
                                                                    frame.timestamp_ns)
    for kind in ("truncated", "bad-magic", "unknown-version", "trailing-bytes"):
        with pytest.raises(FrameError) as info:
            frame_header(_malformed()[kind])
        assert info.value.kind == kind


# -- killed and stopped recorder processes ------------------------------------------------

def _record_process(path: Path, endpoint: str, rig: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "camnet", "record", "--rig", rig, "-o", str(path), "--connect",
         endpoint, "--flush-period-s", "0.3"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _publish_frames(session, rig: str, n: int) -> list[bytes]:
    publisher = matched_publisher(session, keys.frame(rig, "k"), timeout_s=30)
    sent = []
    for seq in range(n):
        sent.append(encode_frame(make_frame("mono8", seq=seq, camera_id="k", h=120, w=160)))
        publisher.put(sent[-1])
        time.sleep(0.01)
    return sent


def _stop(process: subprocess.Popen, sig=signal.SIGTERM) -> tuple[str, str]:
    if process.poll() is None:
        process.send_signal(sig)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
    return process.communicate(timeout=60)


def _flushed_frames(path: Path) -> list[bytes]:
    """The frame payloads readable in the file a recorder is writing, up to its last flush."""
    frames = []
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, validate_crcs=True).records:
                if getattr(record, "data", None) is not None and record.data[:4] == b"CNFR":
                    frames.append(record.data)
    except Exception:  # noqa: BLE001 (the cut where writing is under way, of whatever kind)
        pass
    return frames


def _wait_until_flushed(path: Path, sent: list[bytes]) -> None:
    """Until every frame sent is in the file: the recorder's flushes, not a fixed time, decide."""
    assert wait_for(lambda: _flushed_frames(path) == sent, 60.0, 0.1, progress=lambda: len(_flushed_frames(path))), \
        f"{len(_flushed_frames(path))} of {len(sent)} frames flushed"


def test_killed_recorder_leaves_a_file_readable_up_to_the_last_flush(tmp_path):
    path = tmp_path / "killed.mcap"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(BusOptions(listen=(endpoint,))) as session:
        process = _record_process(path, endpoint, "kill")
        try:
            sent = _publish_frames(session, "kill", 60)
            _wait_until_flushed(path, sent)
            os.kill(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
        finally:
            _stop(process, signal.SIGKILL)
    assert process.returncode == -signal.SIGKILL
    # mcap's own stream reader reads every flushed record, then meets the cut.
    frames = []
    with pytest.raises(Exception) as info, open(path, "rb") as stream:  # noqa: B017
        for record in StreamReader(stream, validate_crcs=True).records:
            if getattr(record, "data", None) is not None and record.data[:4] == b"CNFR":
                frames.append(record.data)
    assert "EndOfFile" in type(info.value).__name__
    assert frames == sent
    session_file = open_session_file(path)
    assert session_file.damage is not None and "truncated" in session_file.damage.reason
    assert [m.data for m in session_file.messages() if m.topic == keys.frame("kill", "k")] == sent


def test_sigterm_finishes_the_file_with_its_summary(tmp_path):
    path = tmp_path / "stopped.mcap"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(BusOptions(listen=(endpoint,))) as session:
        process = _record_process(path, endpoint, "term")
        try:
            sent = _publish_frames(session, "term", 30)
            _wait_until_flushed(path, sent)  # all received: what SIGTERM must finish is the file
        finally:
            out, err = _stop(process)
    assert process.returncode == 0, err
    assert "k" in out and " 30 " in out.splitlines()[1]
    _, channels, by_topic, summary = read_all(path)
    assert {c.compression for c in summary.chunk_indexes} == {"lz4"}
    assert [m.data for m in by_topic[keys.frame("term", "k")]] == sent
    assert summary.statistics.message_count >= 30
    assert open_session_file(path).damage is None


# -- replay -------------------------------------------------------------------------------

class _Listener:
    """A subscriber on every key of a rig that keeps (key, payload, arrival time)."""

    def __init__(self, session, rig: str) -> None:
        self.got: list[tuple[str, bytes, float]] = []
        self._lock = threading.Lock()
        self.subscriber = session.declare_subscriber(f"{keys.rig_prefix(rig)}/**", self._on_sample)

    def _on_sample(self, sample) -> None:
        with self._lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes(), time.monotonic()))

    def frames(self) -> list[tuple[str, bytes, float]]:
        with self._lock:
            return [g for g in self.got if g[0].endswith("/frame")]


def _replay(path: Path, rig: str, options: ReplayOptions, *, during=None):
    """Replay `path` to a listener on another peer; (listener, replay summary, during's result)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # The replayer publishes frames as drivers do (CongestionControl.DROP at a rate): on its patient
    # session every frame arrives however loaded the machine (an impatient one loses frames under load).
    with open_session(BusOptions(listen=(endpoint,))) as sub_bus, \
            open_patient_session(BusOptions(connect=(endpoint,))) as pub_bus:
        listener = _Listener(sub_bus, rig)
        replayer = Replayer(pub_bus, open_session_file(path), options=options)
        result = {}
        thread = run_in_thread(lambda: result.setdefault("summary", replayer.run()))
        try:
            seen = during(sub_bus) if during else None
            assert wait_for(lambda: not thread.is_alive(), 60.0, progress=lambda: len(listener.got)), \
                "the replay did not end"
            assert wait_for(lambda: len(listener.frames()) >= sum(result["summary"].frames.values()), 60.0,
                            progress=lambda: len(listener.got))
        finally:
            replayer.stop.set()
            thread.join(timeout=10)
            listener.subscriber.undeclare()
        return listener, result["summary"], seen


def _recorded_frames(path: Path) -> list[tuple[str, bytes, int]]:
    return [(m.topic, m.data, m.publish_time_ns) for m in open_session_file(path).messages()
            if m.topic.endswith("/frame")]


def test_features_are_recorded_and_replayed_bit_exact(recorded):
    path, _, _ = recorded
    _, channels, by_topic, _ = read_all(path)
    topic = keys.features(RIG, "left")
    assert channels[topic].message_encoding == "camnet.features/1"
    assert [m.data for m in by_topic[topic]] == FEATURES
    listener, _, _ = _replay(path, "copy", ReplayOptions(rate=0, rig="copy", wait_s=5))
    assert wait_for(lambda: len([g for g in listener.got if g[0].endswith("/features")]) == 2)
    assert [(k, d) for k, d, _ in listener.got if k.endswith("/features")] == \
        [(keys.features("copy", "left"), data) for data in FEATURES]


def test_replay_as_fast_as_possible_is_bit_exact_ordered_and_deterministic(recorded):
    path, _, _ = recorded
    recorded_frames = _recorded_frames(path)
    span_s = (recorded_frames[-1][2] - recorded_frames[0][2]) / 1e9
    runs = []
    for _ in range(2):
        listener, summary, _ = _replay(path, "copy", ReplayOptions(rate=0, rig="copy", wait_s=5))
        got = listener.frames()
        assert [(key.replace("camnet/copy/", f"camnet/{RIG}/"), data) for key, data, _ in got] == \
            [(topic, data) for topic, data, _ in recorded_frames]
        assert got[-1][2] - got[0][2] < span_s / 2
        assert summary.damage is None and summary.total_frames == len(recorded_frames)
        # Observations and calibrations are left to the live nodes unless asked for.
        assert not [k for k, _, _ in listener.got if k.endswith(("/observations", "/calibration"))]
        runs.append([(key, data) for key, data, _ in got])
    assert runs[0] == runs[1]


@pytest.mark.parametrize("rate", [1.0, 2.0])
def test_replay_keeps_the_recorded_pace_with_driver_tokens_and_groundtruth(recorded, rate):
    path, _, _ = recorded
    recorded_frames = [f for f in _recorded_frames(path) if f[0] != keys.frame(RIG, INJECTED)]
    span_s = (recorded_frames[-1][2] - recorded_frames[0][2]) / 1e9

    expected_live = sorted(keys.node(RIG, "driver", c) for c in (*CAMERAS, INJECTED))

    def during(session):
        # Asked until the replayer's tokens and queryable have reached this session (not after a
        # fixed delay); they stay while it replays.
        live, replies = [], []

        def answered() -> bool:
            live[:] = sorted(str(r.ok.key_expr) for r in
                             session.liveliness().get(keys.all_nodes(RIG), timeout=2.0) if r.ok)
            replies[:] = [r.ok.payload.to_bytes() for r in session.get(keys.groundtruth(RIG), timeout=2.0) if r.ok]
            return live == expected_live and bool(replies)

        wait_for(answered, 30.0, 0.05)
        return live, replies

    listener, summary, (live, truth) = _replay(
        path, RIG, ReplayOptions(rate=rate, include_results=True, wait_s=5), during=during)
    assert live == expected_live
    _, _, by_topic, _ = read_all(path)
    assert truth == [by_topic[keys.groundtruth(RIG)][0].data]
    got = [g for g in listener.frames() if g[0] != keys.frame(RIG, INJECTED)]
    assert [(k, d) for k, d, _ in got] == [(t, d) for t, d, _ in recorded_frames]
    replay_span_s = got[-1][2] - got[0][2]
    assert replay_span_s == pytest.approx(span_s / rate, abs=0.15 + 0.05 * span_s)
    results = [d for k, d, _ in listener.got if k.endswith(("/observations", "/calibration"))]
    assert sorted(json.loads(d)["format"] for d in results) == \
        ["camnet.calibration/1", "camnet.observations/1"]


# -- damaged and foreign files -------------------------------------------------------------

def _all_messages(path):
    return [(m.topic, m.log_time_ns, m.data) for m in open_session_file(path).messages()]


def _check_damaged(path: Path, reference: list) -> str:
    """'refused', or 'prefix': the file reads as a prefix of `reference`, damage noted."""
    try:
        session_file = open_session_file(path)
    except InputError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
        return "refused"
    got = [(m.topic, m.log_time_ns, m.data) for m in session_file.messages()]
    assert got == reference[:len(got)]
    assert session_file.damage is not None or got == reference
    return "prefix"


def test_truncated_files_are_refused_or_read_up_to_the_cut(recorded, tmp_path):
    path, _, _ = recorded
    data = path.read_bytes()
    reference = _all_messages(path)
    rng = random.Random(5)
    cuts = [0, 7, len(data) - 1] + [rng.randrange(len(data)) for _ in range(12)]
    outcomes = set()
    for cut in cuts:
        bad = tmp_path / f"cut{cut}.mcap"
        bad.write_bytes(data[:cut])
        outcomes.add(_check_damaged(bad, reference))
    assert outcomes == {"refused", "prefix"}
    # Cut inside the footer: every message is still there, with the damage noted.
    almost = open_session_file(tmp_path / f"cut{len(data) - 1}.mcap")
    assert len(list(almost.messages())) == len(reference) and almost.damage is not None


def test_flipped_bytes_are_refused_or_read_up_to_the_damage(recorded, tmp_path):
    path, _, _ = recorded
    data = path.read_bytes()
    reference = _all_messages(path)
    rng = random.Random(11)
    outcomes = []
    for trial in range(15):
        bad_bytes = bytearray(data)
        for _ in range(1 + trial % 3):
            offset = rng.randrange(len(bad_bytes))
            bad_bytes[offset] ^= 1 << rng.randrange(8)
        bad = tmp_path / f"flip{trial}.mcap"
        bad.write_bytes(bytes(bad_bytes))
        outcomes.append(_check_damaged(bad, reference))
    assert "prefix" in outcomes


def test_damage_found_while_replaying_stops_with_one_warning(recorded, tmp_path, caplog):
    path, _, _ = recorded
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    frame_channels = {i for i, c in summary.channels.items() if c.topic.endswith("/frame")}
    last_chunk = max((c for c in summary.chunk_indexes
                      if frame_channels & set(c.message_index_offsets)),
                     key=lambda c: c.chunk_start_offset)
    data = bytearray(path.read_bytes())
    data[last_chunk.chunk_start_offset + last_chunk.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "late-damage.mcap"
    bad.write_bytes(bytes(data))
    session_file = open_session_file(bad)
    assert session_file.damage is None  # the summary is intact: damage shows only when read
    listener, summary, _ = _replay(bad, RIG, ReplayOptions(rate=0, wait_s=5))
    # A flipped byte inside a compressed chunk fails either its decompression or its CRC check first.
    assert summary.damage is not None and ("CRC" in summary.damage or "decompression" in summary.damage)
    reference = _recorded_frames(path)
    assert 0 < len(listener.frames()) < len(reference)
    warnings = [r for r in caplog.records if r.levelname == "WARNING" and "damaged" in r.message]
    assert len(warnings) == 1


def _foreign_mcap(path: Path) -> None:
    from mcap.writer import Writer

    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema("imu", "jsonschema", b'{"type": "object"}')
        channel = writer.register_channel("/imu", "json", schema)
        writer.add_message(channel, log_time=1, data=b'{"ax": 0}', publish_time=1)
        writer.finish()


@pytest.mark.parametrize("content, expected", [
    (b"", "not an MCAP file"),
    (b"hello, this is text\n" * 10, "not an MCAP file"),
    (None, "no camnet frame channels"),
    ("missing", "cannot read"),
])
def test_foreign_files_are_refused_with_one_line(tmp_path, capsys, content, expected):
    from camnet.cli import main

    path = tmp_path / "foreign.mcap"
    if content is None:
        _foreign_mcap(path)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    assert main(["replay", str(path), "--listen", f"tcp/127.0.0.1:{free_port()}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err and str(path) in err
    assert err.startswith("camnet replay: error: ")


def test_cli_replays_a_truncated_file_up_to_the_cut_with_one_warning(recorded, tmp_path, caplog,
                                                                    capsys):
    from camnet.cli import main

    path, _, _ = recorded
    data = path.read_bytes()
    bad = tmp_path / "truncated.mcap"
    bad.write_bytes(data[:int(len(data) * 0.8)])
    rc = main(["replay", str(bad), "--as-fast-as-possible", "--wait-s", "0", "--listen",
               f"tcp/127.0.0.1:{free_port()}"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "stopped at damage" in out and "truncated" in out
    warnings = [r for r in caplog.records if r.levelname == "WARNING" and "damaged" in r.message]
    assert len(warnings) == 1


def test_record_refuses_an_existing_file(tmp_path, capsys):
    from camnet.cli import main

    path = tmp_path / "exists.mcap"
    path.write_bytes(b"keep me")
    assert main(["record", "--rig", "x", "-o", str(path), "--duration-s", "0.1", "--listen",
                 f"tcp/127.0.0.1:{free_port()}"]) == 2
    assert "exists (pass --force to overwrite)" in capsys.readouterr().err
    assert path.read_bytes() == b"keep me"


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_record_reports_a_full_disk_in_one_line(capsys):
    from camnet.cli import main

    assert main(["record", "--rig", "x", "-o", "/dev/full", "--force", "--duration-s", "0.5",
                 "--listen", f"tcp/127.0.0.1:{free_port()}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "/dev/full: cannot write" in err


def test_an_output_directory_gets_a_new_session_each_start(tmp_path):
    command = [sys.executable, "-m", "camnet.cli", "record", "--rig", "dirrig", "-o", str(tmp_path),
               "--duration-s", "0.5", "--listen", f"tcp/127.0.0.1:{free_port()}"]
    for _ in range(2):
        subprocess.run(command, check=True, capture_output=True, timeout=60)
        time.sleep(1.1)  # the file name carries the start time to the second
    sessions = sorted(tmp_path.glob("dirrig-*.mcap"))
    assert len(sessions) == 2
    for path in sessions:
        with open(path, "rb") as f:
            assert make_reader(f).get_summary() is not None
