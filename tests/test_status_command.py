"""`camnet status` on real Zenoh peers (loopback, scouting off, own ports): a rig name that matches no
live node, the rigs it can see, and a session that is slow to close."""

from __future__ import annotations

import contextlib
import logging

import pytest
import zenoh

from camnet import cli
from camnet.bus import session as bus_session
from camnet.bus.node import Presence
from camnet.bus.session import BusOptions, open_session
from camnet.bus.stats import Activity
from tests.conftest import free_port


@pytest.fixture
def two_rigs():
    """The endpoint of a peer on which a driver of rig 'sim' and a matcher of rig 'lab' are live."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(BusOptions(listen=(endpoint,)))
    activity = lambda: Activity(fps=10.0, frames=5, dropped=0)  # noqa: E731
    try:
        with contextlib.ExitStack() as stack:
            for rig, kind, node_id in (("sim", "driver", "left"), ("lab", "matcher", "matcher")):
                presence = stack.enter_context(Presence(session, rig=rig, kind=kind, node_id=node_id,
                                                        report=activity, status_period_s=None))
                presence.publish()
            yield endpoint
    finally:
        session.close()


def status(endpoint: str, rig: str) -> int:
    return cli.main(["status", "--rig", rig, "--connect", endpoint, "--wait-s", "0.5"])


def test_a_rig_name_with_no_live_node_is_said_with_the_rigs_seen(two_rigs, capsys):
    """Measured before: `--rig simm` printed 'rig simm: 0 live node(s)' and an empty table, exit 0."""
    assert status(two_rigs, "simm") == 1
    out, err = capsys.readouterr()
    assert "no live node for rig 'simm'; rigs seen: lab, sim" in err and "live node(s)" not in out
    assert status(two_rigs, "sim") == 0
    out, _ = capsys.readouterr()
    assert "rig sim: 1 live node(s)" in out and "driver" in out and "left" in out
    assert "other rigs seen: lab" in out


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
    """Measured before: a ZError traceback after the table."""
    opened = bus_session.open_session
    monkeypatch.setattr(bus_session, "open_session", lambda options, **kw: SlowToClose(opened(options, **kw)))
    caplog.set_level(logging.WARNING, logger="camnet.bus.session")
    assert status(two_rigs, "sim") == 0
    out, _ = capsys.readouterr()
    assert "rig sim: 1 live node(s)" in out
    assert "did not close cleanly (close operation timed out)" in caplog.text
