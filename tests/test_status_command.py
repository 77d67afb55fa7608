"""`camnet status` on real Zenoh peers (loopback, scouting off, own ports): a rig name that matches no
live node, the rigs it can see, a node whose statistics come late, and a session that is slow to close."""

from __future__ import annotations

import contextlib
import logging
import threading

import pytest
import zenoh

from camnet import cli
from camnet.bus import keys
from camnet.bus import session as bus_session
from camnet.bus.node import Presence
from camnet.bus.session import BusOptions, open_session
from camnet.bus.stats import Activity
from tests.conftest import free_port, wait_for


@contextlib.contextmanager
def publishing(presences: list[Presence], start: threading.Event | None = None):
    """The `presences` publishing their statistics every period, as nodes do, on a thread while the block
    lasts; from when `start` is set, if given."""
    stop = threading.Event()

    def loop() -> None:
        if start is not None:
            start.wait()
        while not stop.wait(0.05):
            for presence in presences:
                presence.publish_if_due()

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        if start is not None:
            start.set()
        thread.join(timeout=30)


@pytest.fixture
def two_rigs():
    """The endpoint of a peer on which a driver of rig 'sim' and a matcher of rig 'lab' are live."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(BusOptions(listen=(endpoint,)))
    activity = lambda: Activity(fps=10.0, frames=5, dropped=0)  # noqa: E731
    try:
        with contextlib.ExitStack() as stack:
            presences = [stack.enter_context(Presence(session, rig=rig, kind=kind, node_id=node_id, report=activity,
                                                      period_s=0.2, status_period_s=None))
                         for rig, kind, node_id in (("sim", "driver", "left"), ("lab", "matcher", "matcher"))]
            stack.enter_context(publishing(presences))
            yield endpoint
    finally:
        session.close()


def status(endpoint: str, rig: str) -> int:
    return cli.main(["status", "--rig", rig, "--connect", endpoint, "--wait-s", "0.5"])


def test_a_rig_name_with_no_live_node_is_said_with_the_rigs_seen(two_rigs, capsys):
    """Not 'rig simm: 0 live node(s)' with an empty table and exit 0, but the rigs seen and a failure."""
    assert status(two_rigs, "simm") == 1
    out, err = capsys.readouterr()
    assert "no live node for rig 'simm'; rigs seen: lab, sim" in err and "live node(s)" not in out
    assert status(two_rigs, "sim") == 0
    out, _ = capsys.readouterr()
    assert "rig sim: 1 live node(s)" in out and "driver" in out and "left" in out
    assert "other rigs seen: lab" in out


def test_a_node_whose_statistics_come_after_the_wait_is_waited_for(capsys):
    """A live node whose statistics reach `camnet status` only after its --wait-s (as on a loaded machine,
    where a node's statistics can arrive seconds apart) is shown with them, not as "(no statistics yet)"
    (and of a matcher, with its cameras)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    activity = lambda: Activity(fps=12.5, frames=7, dropped=0)  # noqa: E731
    codes: list[int] = []
    with open_session(BusOptions(listen=(endpoint,))) as session:
        prompt, late = (Presence(session, rig="slow", kind=kind, node_id=kind, report=activity, period_s=0.2,
                                 status_period_s=None) for kind in ("driver", "calibrator"))
        late_starts = threading.Event()
        with prompt, late, publishing([prompt]), publishing([late], late_starts):
            probe = session.declare_publisher(keys.node_stats("slow", "probe", "probe"))  # sees status subscribe
            command = threading.Thread(target=lambda: codes.append(status(endpoint, "slow")), daemon=True)
            command.start()
            assert wait_for(lambda: probe.matching_status.matching, 60.0), "camnet status did not subscribe"
            # Twice its --wait-s after it subscribed: the late node's first statistics.
            assert not late_starts.wait(1.0)
            late_starts.set()
            command.join(timeout=120)
            probe.undeclare()
    assert codes == [0]
    out, _ = capsys.readouterr()
    rows = {tuple(line.split()[:2]): line for line in out.splitlines()}
    assert "12.5" in rows[("driver", "driver")] and "12.5" in rows[("calibrator", "calibrator")], out
    assert "no statistics" not in out, out


class SlowToClose:
    """A session whose close times out, as Zenoh's does on a slow or lossy link."""

    def __init__(self, session) -> None:
        self._session = session

    def __getattr__(self, name):
        return getattr(self._session, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        self._session.close()
        raise zenoh.ZError("close operation timed out")


def test_a_session_slow_to_close_ends_cleanly(two_rigs, capsys, caplog, monkeypatch):
    """No ZError traceback after the table."""
    opened = bus_session.open_session
    monkeypatch.setattr(bus_session, "open_session", lambda options, **kw: SlowToClose(opened(options, **kw)))
    caplog.set_level(logging.WARNING, logger="camnet.bus.session")
    assert status(two_rigs, "sim") == 0
    out, _ = capsys.readouterr()
    assert "rig sim: 1 live node(s)" in out
    assert "did not close cleanly (close operation timed out)" in caplog.text
