"""What `camnet record` says and when it stops: on time, with missing frames told once a period, with why.

The recorder runs on real Zenoh peers over loopback (scouting off, own ports).
"""

from __future__ import annotations

import json
import logging
import re
import time

from camnet.services.recorder import Recorder, RecorderConfig
from camnet.services.recording_gaps import ByteBoundedQueue, GapTracker, GapWindow
from mcap.reader import make_reader

from camnet.bus import keys
from camnet.bus.frame import encode_frame
from camnet.bus.stats import NodeStats
from tests.conftest import matched_publisher, running_node, wait_for
from tests.test_frame import make_frame

RIG = "console"


def test_a_period_of_gaps_is_one_line_that_says_why():
    window = GapWindow()
    for _ in range(30):
        window.add_gap("left", 1, 0)
    window.add_gap("right", 5, 3)
    window.add_driver_drops("left", 20)
    window.add_silence("mono", 3.2)
    window.add_restart("right")
    line = window.line(period_s=5.0, silent_now_s={"far": 4.0}, lag_s=2.5)
    assert "35 frame(s) missing in the last 5 s (left 30, right 5)" in line
    assert "3 refused by this recorder's full queue, 2.5 s behind: this machine cannot keep up" in line
    assert "20 dropped at the cameras" in line
    assert "12 lost on the way" in line  # 35 - 3 refused - 20 dropped
    assert "stalled: far (no frame for 4.0 s), mono (no frame for 3.2 s, then back)" in line
    assert "restarted: right" in line
    assert "\n" not in line


def test_a_quiet_period_says_nothing_and_causes_never_exceed_the_missing():
    assert GapWindow().line(period_s=5.0, silent_now_s={}) is None
    window = GapWindow()
    window.add_gap("left", 2, 0)
    window.add_driver_drops("left", 50)  # statistics may tell of drops whose gaps come later
    line = window.line(period_s=5.0, silent_now_s={})
    assert "2 dropped at the cameras" in line and "lost on the way" not in line


def test_a_silent_camera_is_said_when_it_falls_silent_not_every_period(caplog):
    queue = ByteBoundedQueue(1 << 20)
    tracker = GapTracker(stall_s=0.05)
    for camera_id in ("off", "unplugged"):
        key = keys.frame(RIG, camera_id)
        queue.put(key, b"frame")
        tracker.frame(camera_id, key, queue.get(timeout_s=0).log_time_ns)
    tracker.driver_event("unplugged", "left")
    time.sleep(0.2)
    caplog.set_level(logging.WARNING)
    for _ in range(3):
        tracker.report(queue)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1, lines
    assert re.search(r"stalled: off \(no frame for [\d.]+ s\), unplugged \(no frame for [\d.]+ s: its driver "
                     r"left the bus\)", lines[0]), lines[0]


def _recorder(session, tmp_path, **options) -> Recorder:
    config = RecorderConfig(rig=RIG, path=tmp_path / "session.mcap", flush_period_s=0.2, stats_period_s=0.2,
                            **options)
    return Recorder(session, config)


def test_gaps_are_told_once_a_period_and_a_silent_camera_as_stalled(zenoh_pair, tmp_path, caplog):
    """One warning a period, not one per gap, and a camera gone silent said to be so."""
    a, b = zenoh_pair
    recorder = _recorder(a, tmp_path, report_period_s=1.0, stall_s=1.0)
    caplog.set_level(logging.WARNING, logger="camnet.services.recorder")
    started = time.monotonic()
    with running_node(recorder):
        gappy = matched_publisher(b, keys.frame(RIG, "gappy"))
        quiet = matched_publisher(b, keys.frame(RIG, "quiet"))
        stats = matched_publisher(b, keys.node_stats(RIG, "driver", "gappy"))
        stats.put(NodeStats(rig=RIG, kind="driver", node_id="gappy", fps=10.0, frames=60, dropped=59,
                            timestamp_ns=time.time_ns()).to_json())
        for seq in range(3):
            quiet.put(encode_frame(make_frame("mono8", seq=seq, camera_id="quiet")))
        for seq in range(0, 120, 2):
            gappy.put(encode_frame(make_frame("mono8", seq=seq, camera_id="gappy")))
        assert wait_for(lambda: recorder.summary().cameras.get("gappy", None) is not None
                        and recorder.summary().cameras["gappy"].frames == 60, 60.0), recorder.summary()
        assert wait_for(lambda: "quiet (no frame for" in caplog.text, 60.0), caplog.text
    elapsed_s = time.monotonic() - started
    assert recorder.summary().cameras["gappy"].missing == 59
    lines = [r.getMessage() for r in caplog.records if "missing in the last" in r.getMessage()]
    assert lines and any("gappy" in line for line in lines)
    # At most one line a period (and one at the stop), never one per gap.
    assert len(lines) <= elapsed_s / 1.0 + 2 and len(lines) < 59, lines
    assert any("dropped at the cameras" in line for line in lines), lines


def test_a_recorder_behind_its_queue_stops_on_time_with_a_valid_file(zenoh_pair, tmp_path, caplog):
    """A recorder behind writes its queue for a bounded time after the end, not its whole backlog
    (docs/benchmarks.md, "Bus, recording, Rerun")."""
    a, _ = zenoh_pair
    recorder = _recorder(a, tmp_path, duration_s=0.5, stop_grace_s=0.5)
    queued = 400
    for seq in range(queued):  # a backlog, as a recorder that fell behind has it
        recorder._queue.put(keys.frame(RIG, "left"), encode_frame(make_frame("mono8", seq=seq, camera_id="left")))
    write = recorder._write

    def slow_write(channels, item):  # a disk that cannot keep up: 400 items would take 20 s
        time.sleep(0.05)
        write(channels, item)

    recorder._write = slow_write
    caplog.set_level(logging.WARNING, logger="camnet.services.recorder")
    started = time.monotonic()
    summary = recorder.run()
    elapsed_s = time.monotonic() - started
    assert elapsed_s < 10.0, f"took {elapsed_s:.1f} s for 0.5 s and a 0.5 s grace"
    written = summary.cameras["left"].frames
    assert 0 < written < queued and summary.unwritten_at_stop >= queued - written
    assert "stopping on time" in caplog.text and "not written" in "\n".join(summary.lines())
    with open(summary.path, "rb") as stream:
        reader = make_reader(stream)
        assert reader.get_summary().statistics.message_count == summary.messages
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert int(metadata["camnet.recording-summary"]["unwritten_at_stop"]) == summary.unwritten_at_stop
    assert json.loads(metadata["camnet.recording-summary"]["cameras"])["left"]["frames"] == written
