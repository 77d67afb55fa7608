"""Shared fixtures: Zenoh peers on loopback with scouting off and their own free ports."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

from camnet.testing.ports import free_port  # noqa: F401  (the tests import it from here)

# Files the tests write by hand (state files among them) are the user's alone to write, whatever the machine's
# umask: the calibrator refuses a state file that others may write.
os.umask(0o022)

def _plain(value):
    """`value` as plain Python (numpy numbers as Python numbers, keys as strings): what xdist can send from a
    worker."""
    if isinstance(value, dict):
        return {str(_plain(k)): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "item"):
        return value.item()
    return value if isinstance(value, str | int | float | bool | type(None)) else str(value)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Properties a test records (`record_property`) as plain values, so that a worker can report them."""
    outcome = yield
    report = outcome.get_result()
    report.user_properties = [(name, _plain(value)) for name, value in report.user_properties]


# wait_for's clock, replaced by a fake one in tests/test_waiting.py.
_monotonic, _sleep = time.monotonic, time.sleep


def wait_for(predicate, timeout_s: float = 60.0, period_s: float = 0.02, *, progress=None,
             limit_s: float | None = None) -> bool:
    """Whether `predicate()` came true, polled every `period_s`.

    Without `progress`, the wait ends `timeout_s` after it began. With it, `timeout_s` is how long to
    wait with no progress: `progress()` returns a value that changes while the awaited work goes on
    (messages received, solves published, lines logged), and each change gives another `timeout_s`, so
    that a loaded machine that is slow but moving is waited for while a stalled one fails in
    `timeout_s`. `limit_s` (default: ten times `timeout_s`) bounds the whole wait.
    """
    start_s = _monotonic()
    deadline_s = start_s + timeout_s
    limit_deadline_s = start_s + (10 * timeout_s if limit_s is None else limit_s)
    last = progress() if progress is not None else None
    while _monotonic() < deadline_s:
        if predicate():
            return True
        _sleep(period_s)
        if progress is not None:
            now = progress()
            if now != last:
                last = now
                deadline_s = min(max(deadline_s, _monotonic() + timeout_s), limit_deadline_s)
    return predicate()


def logs_written(directory: Path, pattern: str = "*.log") -> int:
    """Bytes of the *.log files (or those `pattern` matches) under `directory`: the progress of nodes that
    log as they work (`camnet up` starts its nodes with -v, logging to its run directory)."""
    total = 0
    for path in Path(directory).rglob(pattern):
        try:
            total += path.stat().st_size
        except OSError:  # rotated or removed meanwhile
            continue
    return total


def run_to_end(argv: list[str], *, timeout_s: float, **popen_kwargs) -> subprocess.CompletedProcess:
    """`subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)`, except that past the
    timeout the process is stopped with `stop_process` (so that `camnet up` stops its nodes; run's
    SIGKILL would leave them running), and TimeoutExpired raised with what it printed."""
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen_kwargs)
    try:
        stdout, stderr = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        stop_process(process)
        stdout, stderr = process.communicate()
        raise subprocess.TimeoutExpired(argv, timeout_s, stdout, stderr) from None
    finally:
        if process.poll() is None:  # anything else raised while waiting
            stop_process(process)
    return subprocess.CompletedProcess(argv, process.returncode, stdout, stderr)


def stop_process(process: subprocess.Popen, *, first_signal: int = signal.SIGTERM, grace_s: float = 60.0) -> None:
    """Stop `process` (and, with SIGTERM or SIGINT, the nodes it started) and reap it, even on failure.

    `camnet up` starts its nodes in sessions of their own: a SIGKILL to it alone would leave them
    running, loading the machine for the tests after. So it is asked first and killed only past `grace_s`.
    """
    if process.poll() is None:
        process.send_signal(first_signal)
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            process.kill()
    process.wait()


# Zenoh drops a message published with CongestionControl.DROP (as nodes publish frames and features)
# when its transmit thread has not freed a batch within these microseconds: 1 ms, and 50 ms for a
# message of several batches (a keyframe's features, a frame). A loaded machine often leaves that
# thread unscheduled for longer, with no congestion at all. Sessions of the tests wait longer, so
# that a test loses no message to scheduling; real nodes keep Zenoh's defaults.
PATIENT_DROP = {"transport/link/tx/queue/congestion_control/drop/wait_before_drop": 1_000_000,
                "transport/link/tx/queue/congestion_control/drop/max_wait_before_drop_fragments": 30_000_000}


def open_patient_session(options):
    """`open_session(options)` with `PATIENT_DROP`."""
    import json

    from camnet.bus.session import make_config, open_session

    config = make_config(options)
    for key, value in PATIENT_DROP.items():
        config.insert_json5(key, json.dumps(value))
    return open_session(options, config=config)


@pytest.fixture
def zenoh_pair():
    """(listener, connector): two peer sessions joined over tcp loopback, no scouting, patient before dropping."""
    from camnet.bus.session import BusOptions

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    a = open_patient_session(BusOptions(listen=(endpoint,)))
    b = open_patient_session(BusOptions(connect=(endpoint,)))
    try:
        assert wait_for(lambda: len(list(b.info.peers_zid())) > 0), "peers did not connect"
        yield a, b
    finally:
        b.close()
        a.close()


def matched_publisher(session, key_expr: str, timeout_s: float = 60.0):
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
