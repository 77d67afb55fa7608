"""Shared fixtures: Zenoh peers on loopback with scouting off and their own free ports."""

from __future__ import annotations

import socket
import threading
import time
from contextlib import contextmanager

import pytest


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout_s: float = 10.0, period_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period_s)
    return predicate()


@pytest.fixture
def zenoh_pair():
    """(listener, connector): two peer sessions joined over tcp loopback, no scouting."""
    from camnet.bus.session import BusOptions, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    a = open_session(BusOptions(listen=(endpoint,)))
    b = open_session(BusOptions(connect=(endpoint,)))
    try:
        assert wait_for(lambda: len(list(b.info.peers_zid())) > 0, 5.0), "peers did not connect"
        yield a, b
    finally:
        b.close()
        a.close()


def matched_publisher(session, key_expr: str, timeout_s: float = 5.0):
    """A publisher with congestion control BLOCK that already sees a matching subscriber.

    Tests must not lose frames to a subscription still in flight or to a full
    transmit queue; real drivers publish with DROP instead.
    """
    import zenoh

    publisher = session.declare_publisher(key_expr,
                                          congestion_control=zenoh.CongestionControl.BLOCK)
    assert wait_for(lambda: publisher.matching_status.matching, timeout_s), \
        f"no subscriber matched {key_expr}"
    return publisher


@contextmanager
def running_node(node, join_timeout_s: float = 60.0):
    """`node.run()` on a thread for the block; stopped (`node.stop`) and joined after it, even on failure."""
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        node.stop.set()
        thread.join(timeout=join_timeout_s)
        assert not thread.is_alive(), f"{type(node).__name__} did not stop"
