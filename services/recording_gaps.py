"""What the recorder knows of missing frames, and the one line every few seconds that says why.

`ByteBoundedQueue` is the recorder's receive queue: bounded in bytes, it
refuses (and counts) what does not fit, stamps what it takes with its
receive time, and remembers when each key last arrived, so that a camera
that stalled shows even while the writer is behind. `GapWindow` collects,
over one report period, the frames missing from each camera's sequence and
the evidence of why: frames this recorder's full queue refused (this
machine cannot keep up with writing), frames the drivers say their cameras
dropped (the camera's machine cannot keep up), the rest lost on the way
(a congested link or a busy machine drops frames), and cameras that went
silent. `GapWindow.line` is the one warning a period, instead of one per gap.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field

from camnet.bus.stats import NodeStats
from camnet.errors import InputError

log = logging.getLogger(__name__)
STALL_REPEAT_S = 60.0  # a camera that stays silent is said again at most this often


@dataclass(frozen=True)
class QueueItem:
    log_time_ns: int
    key: str
    payload: bytes
    event: str = ""  # "joined" / "left" for liveliness changes, "" for samples


class ByteBoundedQueue:
    """FIFO bounded in bytes; a full queue refuses the new item, counted in total and per key."""

    def __init__(self, capacity_bytes: int) -> None:
        self.capacity_bytes = capacity_bytes
        self._items: deque[QueueItem] = deque()
        self._bytes = 0
        self._last_ns = 0
        self._ready = threading.Condition()
        self._refused_by_key: dict[str, int] = {}
        self._arrived_ns: dict[str, int] = {}
        self.refused = 0

    def put(self, key: str, payload: bytes, event: str = "") -> None:
        with self._ready:
            # Stamped under the lock: queue order is log-time order.
            self._last_ns = max(time.time_ns(), self._last_ns)
            self._arrived_ns[key] = self._last_ns  # refused or not, the sender is alive
            if self._items and self._bytes + len(payload) > self.capacity_bytes:
                self._refused_by_key[key] = self._refused_by_key.get(key, 0) + 1
                self.refused += 1
                return
            self._items.append(QueueItem(self._last_ns, key, payload, event))
            self._bytes += len(payload)
            self._ready.notify()

    def get(self, *, timeout_s: float) -> QueueItem | None:
        with self._ready:
            if not self._ready.wait_for(lambda: self._items, timeout=timeout_s):
                return None
            item = self._items.popleft()
            self._bytes -= len(item.payload)
            return item

    def take_refused(self, key: str) -> int:
        """Items of `key` refused since the last call."""
        with self._ready:
            return self._refused_by_key.pop(key, 0)

    def arrived_ns(self, key: str) -> int | None:
        """When an item of `key` last arrived (taken or refused), on the log-time clock."""
        with self._ready:
            return self._arrived_ns.get(key)

    def backlog(self) -> tuple[int, int, float]:
        """(items, bytes, seconds since the oldest one arrived) still waiting to be written."""
        with self._ready:
            if not self._items:
                return 0, 0, 0.0
            return len(self._items), self._bytes, max(0.0, (time.time_ns() - self._items[0].log_time_ns) / 1e9)

    def clear(self) -> tuple[int, int]:
        """Drop everything still queued; (items, bytes) dropped."""
        with self._ready:
            dropped = len(self._items), self._bytes
            self._items.clear()
            self._bytes = 0
            return dropped


@dataclass
class GapWindow:
    """Missing frames and their likely causes over one report period, by camera."""

    missing: dict[str, int] = field(default_factory=dict)  # frames missing from the sequence
    refused: dict[str, int] = field(default_factory=dict)  # of those, refused by the recorder's full queue
    driver_dropped: dict[str, int] = field(default_factory=dict)  # what the drivers say their cameras dropped
    restarts: dict[str, int] = field(default_factory=dict)
    silent_s: dict[str, float] = field(default_factory=dict)  # the longest silence that ended in the period

    def add_gap(self, camera_id: str, missing: int, refused: int) -> None:
        self.missing[camera_id] = self.missing.get(camera_id, 0) + missing
        self.refused[camera_id] = self.refused.get(camera_id, 0) + refused

    def add_restart(self, camera_id: str) -> None:
        self.restarts[camera_id] = self.restarts.get(camera_id, 0) + 1

    def add_driver_drops(self, camera_id: str, dropped: int) -> None:
        self.driver_dropped[camera_id] = self.driver_dropped.get(camera_id, 0) + dropped

    def add_silence(self, camera_id: str, silent_s: float) -> None:
        self.silent_s[camera_id] = max(silent_s, self.silent_s.get(camera_id, 0.0))

    def line(self, *, period_s: float, silent_now_s: dict[str, float], refused_other: int = 0,
             lag_s: float = 0.0, gone: frozenset[str] = frozenset()) -> str | None:
        """One line for the operator on what went missing in the last `period_s` and why; None when
        nothing did. `silent_now_s`: cameras silent right now (seconds); `refused_other`: messages
        other than frames the full queue refused; `lag_s`: how far behind the writer is; `gone`:
        cameras whose driver left the bus."""
        missing = sum(self.missing.values())
        stalls = {**self.silent_s, **silent_now_s}
        if not (missing or stalls or self.restarts or refused_other):
            return None
        parts = []
        if missing:
            by_camera = ", ".join(f"{c} {n}" for c, n in sorted(self.missing.items()) if n)
            parts.append(f"{missing} frame(s) missing in the last {period_s:.0f} s ({by_camera})")
        refused = sum(self.refused.values()) + refused_other
        if refused:
            behind = f", {lag_s:.1f} s behind" if lag_s >= 0.5 else ""
            parts.append(f"{refused} refused by this recorder's full queue{behind}: this machine cannot keep up "
                         "with writing (try --compression none, or a faster disk)")
        dropped = min(sum(self.driver_dropped.values()), max(0, missing - sum(self.refused.values())))
        if dropped:
            parts.append(f"{dropped} dropped at the cameras, as their drivers say: the camera or its machine "
                         "cannot keep up")
        lost = missing - sum(self.refused.values()) - dropped
        if lost > 0:
            parts.append(f"{lost} lost on the way: a congested link or a busy machine drops frames")
        if stalls:
            parts.append("stalled: " + ", ".join(
                f"{c} (no frame for {s:.1f} s{_since(c, silent_now_s, gone)})" for c, s in sorted(stalls.items())))
        if self.restarts:
            parts.append("restarted: " + ", ".join(sorted(self.restarts)))
        return "; ".join(parts)


def _since(camera_id: str, silent_now_s: dict[str, float], gone: frozenset[str]) -> str:
    if camera_id not in silent_now_s:
        return ", then back"
    return ": its driver left the bus" if camera_id in gone else ""


class GapTracker:
    """The recorder's side of `GapWindow`: fed what it writes, it reports once a period (`report`)."""

    def __init__(self, *, stall_s: float) -> None:
        self.stall_s = stall_s
        self._window = GapWindow()
        self._window_started = time.monotonic()
        self._frame_keys: dict[str, str] = {}  # camera id -> its frame key
        self._last_frame_ns: dict[str, int] = {}  # camera id -> receive time of its last frame written
        self._driver_dropped: dict[str, int] = {}  # camera id -> its driver's last reported drop count
        self._refused_reported = 0
        self._stall_said: dict[str, float] = {}  # camera id -> when its silence was last said
        self._drivers_gone: set[str] = set()  # camera ids whose driver left the bus

    def gap(self, camera_id: str, *, missing: int, refused: int, restart: bool) -> None:
        if restart:
            self._window.add_restart(camera_id)
        else:
            self._window.add_gap(camera_id, missing, refused)

    def frame(self, camera_id: str, key: str, log_time_ns: int) -> None:
        """A frame written, received at `log_time_ns`: a long silence before it was a stall."""
        previous_ns = self._last_frame_ns.get(camera_id)
        if previous_ns is not None and log_time_ns - previous_ns >= self.stall_s * 1e9:
            self._window.add_silence(camera_id, (log_time_ns - previous_ns) / 1e9)
        self._last_frame_ns[camera_id] = log_time_ns
        self._frame_keys[camera_id] = key

    def node_stats(self, payload: bytes) -> None:
        """Count what a driver says its camera dropped since its last statistics (a cause of gaps)."""
        try:
            stats = NodeStats.from_json(payload)
        except InputError:
            return  # recorded as it came; only the drivers' own counts matter here
        if stats.kind != "driver":
            return
        before = self._driver_dropped.get(stats.node_id, 0)
        self._driver_dropped[stats.node_id] = stats.dropped
        # A count that went down is a restarted driver: all it reports is new.
        new = stats.dropped - before if stats.dropped >= before else stats.dropped
        if new > 0:
            self._window.add_driver_drops(stats.node_id, new)

    def driver_event(self, camera_id: str, event: str) -> None:
        """A driver joined or left: a camera silent with its driver gone has not stalled, it left."""
        if event == "left":
            self._drivers_gone.add(camera_id)
        else:
            self._drivers_gone.discard(camera_id)

    def _silent_cameras(self, queue: ByteBoundedQueue) -> dict[str, float]:
        """Cameras silent for `stall_s` or more, by seconds: said when they fall silent, then at most
        every STALL_REPEAT_S while they stay so (a camera switched off is not news every period)."""
        now_ns, now_s, silent = time.time_ns(), time.monotonic(), {}
        for camera_id, key in self._frame_keys.items():
            arrived_ns = queue.arrived_ns(key)
            if arrived_ns is None or now_ns - arrived_ns < self.stall_s * 1e9:
                self._stall_said.pop(camera_id, None)
                continue
            if now_s - self._stall_said.get(camera_id, -STALL_REPEAT_S) >= STALL_REPEAT_S:
                self._stall_said[camera_id] = now_s
                silent[camera_id] = (now_ns - arrived_ns) / 1e9
        return silent

    def report(self, queue: ByteBoundedQueue) -> None:
        """One warning on the frames that went missing since the last report and why, if any did."""
        period_s = time.monotonic() - self._window_started
        self._window_started = time.monotonic()
        refused = queue.refused - self._refused_reported
        self._refused_reported = queue.refused
        line = self._window.line(period_s=period_s, silent_now_s=self._silent_cameras(queue),
                                 refused_other=max(0, refused - sum(self._window.refused.values())),
                                 lag_s=queue.backlog()[2], gone=frozenset(self._drivers_gone))
        if line is not None:
            log.warning("%s", line)
        self._window = GapWindow()
