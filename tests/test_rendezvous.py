"""The default bus: nodes on one machine meet at the loopback rendezvous with no flags.

This is the one test that uses the default port (7447); it skips when the
port is taken by something else, since it cannot run beside another rig.
"""

import socket

import pytest

from camnet.bus.session import BusOptions, open_session
from tests.conftest import wait_for


def port_in_use(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_three_default_nodes_find_each_other_and_survive_the_holder_leaving():
    if port_in_use(7447):
        pytest.skip("port 7447 is in use on this machine (another rig or router)")
    sessions = [open_session(BusOptions()) for _ in range(3)]  # the first takes the rendezvous port
    first, second, third = sessions
    got = []
    try:
        sub = third.declare_subscriber("camnet/rdv/test", lambda s: got.append(s.payload.to_bytes()))
        assert wait_for(lambda: len(list(second.info.peers_zid())) >= 2, 60), "peers did not meet"
        assert wait_for(lambda: (second.put("camnet/rdv/test", b"one"), got)[1], 60)
        first.close()
        # The holder left: the others still talk, and a node started now takes the port
        # and is found by them (they keep retrying the rendezvous).
        got.clear()
        assert wait_for(lambda: (second.put("camnet/rdv/test", b"two"), got)[1], 60)
        late = []
        fourth = open_session(BusOptions())
        sessions.append(fourth)
        late_sub = fourth.declare_subscriber("camnet/rdv/test", lambda s: late.append(s.payload.to_bytes()))
        assert wait_for(lambda: (second.put("camnet/rdv/test", b"three"), late)[1], 60), "late node not found"
        late_sub.undeclare()
        sub.undeclare()
    finally:
        for session in reversed(sessions):
            if not session.is_closed():
                session.close()
