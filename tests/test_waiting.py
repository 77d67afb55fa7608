"""The tests' own waiting and port helpers (tests/conftest.py, camnet/bus/ports.py), on a fake clock: a
wait with progress goes on while the progress moves and ends a timeout after it stops; ports are never
handed out twice."""

from __future__ import annotations

import socket

import pytest

from camnet.testing import ports
from tests import conftest


class FakeClock:
    """The monotonic clock and sleep of conftest.wait_for, advancing only when slept."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def monotonic(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.now_s += seconds


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(conftest, "_monotonic", fake.monotonic)
    monkeypatch.setattr(conftest, "_sleep", fake.sleep)
    return fake


def test_without_progress_the_wait_ends_at_its_timeout(clock):
    start_s = clock.now_s
    assert not conftest.wait_for(lambda: False, 5.0, 0.5)
    assert 5.0 <= clock.now_s - start_s < 5.6


def test_progress_extends_the_wait_until_it_stops(clock):
    start_s = clock.now_s
    # Moves every second for 30 s, then stalls: the wait lasts 30 s and one timeout more.
    progress = lambda: min(clock.now_s - start_s, 30.0) // 1.0  # noqa: E731
    assert not conftest.wait_for(lambda: False, 5.0, 0.5, progress=progress)
    assert 35.0 <= clock.now_s - start_s < 36.1


def test_progress_that_never_stops_is_bounded_by_the_limit(clock):
    start_s = clock.now_s
    assert not conftest.wait_for(lambda: False, 5.0, 0.5, progress=clock.monotonic, limit_s=20.0)
    assert 20.0 <= clock.now_s - start_s < 20.6
    clock.now_s = start_s = 0.0
    assert not conftest.wait_for(lambda: False, 5.0, 0.5, progress=clock.monotonic)  # default: 10 timeouts
    assert 50.0 <= clock.now_s - start_s < 50.6


def test_the_predicate_ends_the_wait_once_true(clock):
    start_s = clock.now_s
    assert conftest.wait_for(lambda: clock.now_s - start_s >= 12.0, 5.0, 0.5, progress=clock.monotonic)
    assert clock.now_s - start_s < 12.6


def test_free_ports_are_bindable_outside_the_ephemeral_range_and_never_repeated():
    low, high = ports.ephemeral_range()
    given = [conftest.free_port() for _ in range(200)]
    assert len(set(given)) == len(given)
    assert not any(low <= port <= high for port in given)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", given[-1]))
