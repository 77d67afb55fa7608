"""The node skeleton: what every camnet node does alike, written once.

- `Tally` counts what a node drops or survives (malformed messages, failed
  handlers) by kind, and logs only the first of each kind: a flood of bad
  input must not flood the log, yet every one shows in the node's statistics.
- `guarded` runs a message handler so that an unexpected exception in it is
  counted in a tally and the node goes on: a bug met by one message must not
  stop the node.
- `stop_on_signals` makes SIGTERM (docker stop, `camnet up` stopping its
  nodes) and Ctrl-C only set the node's stop event, so its loop ends and it
  leaves the bus cleanly.
- `Presence` is a node on the bus: its liveliness token
  (`camnet.bus.keys.node`) and its statistics (`camnet.bus.stats.NodeStats`),
  published every period and once more on leaving; and the same statistics
  as one line for the operator every few seconds and on leaving, on the
  `camnet.status` logger, which `camnet` shows at its default level; and,
  when asked (`trim_heap_period_s`), the heap's freed memory handed back to
  the operating system every few seconds (`camnet.bus.heap`).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import ParamSpec, TypeVar

from camnet.bus import heap, keys
from camnet.bus.session import declare_liveliness
from camnet.bus.stats import Activity, NodeStats

log = logging.getLogger(__name__)
status_log = logging.getLogger("camnet.status")  # one line a node every few seconds: shown by default
STATUS_PERIOD_S = 5.0

P = ParamSpec("P")
R = TypeVar("R")


class Tally:
    """Occurrences by kind; the first of each kind is logged as a warning, the rest only counted.

    Thread-safe: Zenoh's callback threads and the node's own thread count into one tally.
    """

    def __init__(self, logger: logging.Logger = log) -> None:
        self._log = logger
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}

    def count(self, kind: str, message: str, *args: object, exc_info: bool = False) -> None:
        """Count one of `kind`; the first of its kind logs `message % args` (lazily formatted)."""
        with self._lock:
            first = kind not in self._counts
            self._counts[kind] = self._counts.get(kind, 0) + 1
        if first:
            self._log.warning(message + "; further ones of this kind are only counted", *args,
                              exc_info=exc_info)

    @property
    def counts(self) -> dict[str, int]:
        """A copy of the counts, by kind."""
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())


def guarded(handler: Callable[P, R], tally: Tally, what: str) -> Callable[P, R | None]:
    """`handler`, but an exception it raises is counted in `tally` (kind: `what` and the
    exception's type), logged with its traceback the first time, and turned into None."""

    def run(*args: P.args, **kwargs: P.kwargs) -> R | None:
        try:
            return handler(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 (a bug met by one message must not stop the node)
            tally.count(f"{what}: {type(exc).__name__}", "%s failed unexpectedly (%s)", what, exc,
                        exc_info=True)
            return None

    return run


def name_os_thread(name: str) -> None:
    """Give the calling thread `name` (15 bytes at most) in the operating system too, where it can.

    Python keeps a thread's name to itself; on Linux the kernel's name is what /proc/PID/task/*/comm
    shows, so that a benchmark can tell where a node's CPU time goes, thread by thread.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(15, name.encode()[:15], 0, 0, 0)  # 15: PR_SET_NAME


@contextlib.contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[threading.Event]:
    """Within, SIGTERM and SIGINT (Ctrl-C) only set `stop`; the previous handlers come back after.

    Signals reach only the main thread: elsewhere (a node run by a test) they are left alone.
    """
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {signum: signal.signal(signum, lambda *_: stop.set())
                for signum in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


class Presence:
    """One node on the bus while the context lasts: its liveliness token and its statistics.

    `report` says what the node did (`Activity`); the statistics add who it
    is, when, and the counts of its `tallies`. They go out on the first
    `publish_if_due`, then every `period_s`, and once more on leaving, just
    before the token goes, so that the final counts are seen. Every
    `status_period_s` (None: never), and on leaving, they are also logged as
    one line (`status_line`), the node's `frames` and `dropped` named by `counted`
    and `dropped` (what they count differs by node). With `trim_heap_period_s`
    (None: never), `publish_if_due` also trims the process's heap that often
    (`camnet.bus.heap`): for nodes that free large buffers as they go.
    """

    def __init__(self, session, *, rig: str, kind: str, node_id: str, report: Callable[[], Activity],
                 tallies: Sequence[Tally] = (), period_s: float = 1.0, counted: str = "frames",
                 dropped: str = "dropped", status_period_s: float | None = STATUS_PERIOD_S,
                 trim_heap_period_s: float | None = None) -> None:
        self.session = session
        self.rig, self.kind, self.node_id = rig, kind, node_id
        self.report = report
        self.tallies = tuple(tallies)
        self.period_s = period_s
        self.counted, self.dropped = counted, dropped
        self.status_period_s = status_period_s
        self._next_s = float("-inf")
        self._next_status_s = float("inf")
        self.heap_trim = heap.process_trim(trim_heap_period_s) if trim_heap_period_s is not None else None
        self._publisher = None
        self._token = None

    def __enter__(self) -> Presence:
        self._publisher = self.session.declare_publisher(keys.node_stats(self.rig, self.kind, self.node_id))
        self._token = declare_liveliness(self.session, keys.node(self.rig, self.kind, self.node_id))
        if self.status_period_s is not None:
            self._next_status_s = time.monotonic() + self.status_period_s
        return self

    def __exit__(self, *exc_info: object) -> None:
        try:
            stats = self.publish()
            if self.status_period_s is not None:
                status_log.info("%s (leaving)", self.status_line(stats))
            if self.heap_trim is not None and self.heap_trim.trims:
                log.info("heap trimmed %d times, %.1f ms each on average", self.heap_trim.trims,
                         1e3 * self.heap_trim.seconds / self.heap_trim.trims)
        finally:
            self._token.undeclare()

    def stats(self) -> NodeStats:
        activity = self.report()
        faults: dict[str, int] = {}
        for tally in self.tallies:
            for kind, n in tally.counts.items():
                faults[kind] = faults.get(kind, 0) + n
        return NodeStats(rig=self.rig, kind=self.kind, node_id=self.node_id, fps=activity.fps,
                         frames=activity.frames, dropped=activity.dropped, timestamp_ns=time.time_ns(),
                         detail=activity.detail, faults=faults, cameras=activity.cameras)

    def status_line(self, stats: NodeStats) -> str:
        """The statistics as one line for the operator."""
        who = self.kind if self.node_id == self.kind else f"{self.kind} {self.node_id}"
        line = f"{who}: {stats.frames} {self.counted} ({stats.fps:.1f}/s), {stats.dropped} {self.dropped}"
        if stats.detail:
            line += f"; {stats.detail}"
        if stats.faults:
            line += "; " + ", ".join(f"{fault} {n}" for fault, n in sorted(stats.faults.items()))
        missing = [camera_id for camera_id, seen in stats.cameras.items() if seen.missing]
        if missing:
            line += f"; MISSING: {', '.join(missing)}"
        return line

    def publish(self) -> NodeStats:
        stats = self.stats()
        self._publisher.put(stats.to_json())
        return stats

    def publish_if_due(self) -> None:
        now_s = time.monotonic()
        if now_s >= self._next_s:
            stats = self.publish()
            self._next_s = now_s + self.period_s
            if now_s >= self._next_status_s:
                status_log.info("%s", self.status_line(stats))
                self._next_status_s = now_s + self.status_period_s
        if self.heap_trim is not None:
            self.heap_trim.if_due(now_s)
