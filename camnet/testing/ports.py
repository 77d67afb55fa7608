"""Free TCP ports of 127.0.0.1 for loopback buses: tests' and benchmarks' own routers and peers."""

from __future__ import annotations

import os
import random
import socket
import time
from pathlib import Path

RENDEZVOUS_PORT = 7447  # where camnet's nodes meet by default: never handed out

_given: set[int] = set()
_choice = random.Random(os.getpid() ^ time.time_ns())


def ephemeral_range() -> tuple[int, int]:
    """The kernel's range of ports for outgoing connections (Linux's default where it cannot be read)."""
    try:
        low, high = map(int, Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        low, high = 32768, 60999
    return low, high


def free_port() -> int:
    """A TCP port of 127.0.0.1, free a moment ago, that no other call in this process has returned.

    Outside the kernel's ephemeral range: a port from bind(("127.0.0.1", 0)) can be taken, before the
    caller's server binds it, by any outgoing connection on the machine (every Zenoh link makes one),
    and two calls could return the same one.
    """
    low, high = ephemeral_range()
    first, last = (10_000, low - 1) if low > 12_000 else (high + 1, 65_535)
    for _ in range(1000):
        port = _choice.randint(first, last)
        if port in _given or port == RENDEZVOUS_PORT:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _given.add(port)
        return port
    raise RuntimeError(f"no free TCP port of 127.0.0.1 in {first}-{last}")
