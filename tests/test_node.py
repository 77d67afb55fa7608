"""The node skeleton: tallies, guarded handlers, stopping on signals, presence on the bus."""

import logging
import os
import signal
import threading

from camnet.bus import keys
from camnet.bus.node import Presence, Tally, guarded, stop_on_signals
from camnet.bus.stats import Activity, NodeStats
from tests.conftest import wait_for


def test_tally_counts_every_one_and_logs_the_first_of_each_kind(caplog):
    tally = Tally(logging.getLogger("camnet.test"))
    with caplog.at_level(logging.WARNING, logger="camnet.test"):
        for _ in range(3):
            tally.count("truncated", "dropping a frame (%s)", "too short")
        tally.count("bad-magic", "dropping a frame (%s)", "not CNFR")
    assert tally.counts == {"truncated": 3, "bad-magic": 1} and tally.total == 4
    messages = [r.getMessage() for r in caplog.records]
    assert messages == ["dropping a frame (too short); further ones of this kind are only counted",
                        "dropping a frame (not CNFR); further ones of this kind are only counted"]


def test_a_guarded_handler_that_raises_is_counted_and_the_caller_goes_on(caplog):
    tally = Tally()

    def handler(value: int) -> int:
        if value < 0:
            raise ValueError("negative")
        return 2 * value

    safe = guarded(handler, tally, "doubling")
    with caplog.at_level(logging.WARNING):
        assert [safe(1), safe(-1), safe(-2), safe(3)] == [2, None, None, 6]
    assert tally.counts == {"doubling: ValueError": 2}
    logged = [r for r in caplog.records if "doubling failed unexpectedly" in r.getMessage()]
    assert len(logged) == 1 and logged[0].exc_info is not None


def test_signals_only_set_the_stop_event_and_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    with stop_on_signals(threading.Event()) as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.wait(5.0)
    assert signal.getsignal(signal.SIGTERM) is before
    with stop_on_signals(threading.Event()) as stop:
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt
        assert stop.wait(5.0)


def test_presence_publishes_statistics_with_faults_and_leaves(zenoh_pair):
    a, b = zenoh_pair
    stats: list[NodeStats] = []
    sub = b.declare_subscriber(keys.node_stats("t", "probe", "p1"),
                               lambda s: stats.append(NodeStats.from_json(s.payload.to_bytes())))

    def live():
        return [str(r.ok.key_expr) for r in b.liveliness().get(keys.all_nodes("t"), timeout=1.0)
                if r.ok is not None]

    tally = Tally()
    presence = Presence(a, rig="t", kind="probe", node_id="p1", tallies=(tally,), period_s=0.05,
                        report=lambda: Activity(fps=2.5, frames=7, dropped=1, detail="probing"))
    with presence:
        assert wait_for(lambda: live() == [keys.node("t", "probe", "p1")])
        tally.count("json", "dropping a message")

        def published_with_faults() -> bool:
            presence.publish_if_due()
            return bool(stats) and stats[-1].faults == {"json": 1}

        assert wait_for(published_with_faults)
    assert wait_for(lambda: live() == [])
    last = stats[-1]
    assert (last.rig, last.kind, last.node_id, last.fps, last.frames, last.dropped, last.detail) == \
        ("t", "probe", "p1", 2.5, 7, 1, "probing")
    assert last.faults == {"json": 1}
    sub.undeclare()


def test_presence_says_one_status_line_a_period_and_one_on_leaving(zenoh_pair, caplog):
    """The operator of a standalone node sees what it did every few seconds, and no more often."""
    import time

    from camnet.bus.stats import CameraSeen

    a, _ = zenoh_pair
    cameras = {"left": CameraSeen(age_s=0.1, fps=10.0, missing=False),
               "far": CameraSeen(age_s=None, fps=0.0, missing=True)}
    presence = Presence(a, rig="t", kind="matcher", node_id="matcher", period_s=0.02, status_period_s=0.5,
                        counted="frame sets matched", dropped="frames dropped", tallies=(Tally(),),
                        report=lambda: Activity(fps=1.5, frames=12, dropped=3, detail="40 frames in",
                                                cameras=cameras))
    caplog.set_level(logging.INFO, logger="camnet.status")
    started = time.monotonic()
    with presence:
        while time.monotonic() - started < 2.0:  # a node's loop: many times a period
            presence.publish_if_due()
            time.sleep(0.005)
    elapsed_s = time.monotonic() - started
    lines = [r.getMessage() for r in caplog.records if r.name == "camnet.status"]
    assert lines[-1].endswith("(leaving)")
    periodic = lines[:-1]
    assert 1 <= len(periodic) <= elapsed_s / 0.5 + 1, lines
    assert periodic[0] == ("matcher: 12 frame sets matched (1.5/s), 3 frames dropped; 40 frames in; "
                           "MISSING: far")
