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

import threading
import time
from collections import deque
from dataclasses import dataclass, field


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
             lag_s: float = 0.0) -> str | None:
        """One line for the operator on what went missing in the last `period_s` and why; None when
        nothing did. `silent_now_s`: cameras silent right now (seconds); `refused_other`: messages
        other than frames the full queue refused; `lag_s`: how far behind the writer is."""
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
                f"{c} (no frame for {s:.1f} s{'' if c in silent_now_s else ', then back'})"
                for c, s in sorted(stalls.items())))
        if self.restarts:
            parts.append("restarted: " + ", ".join(sorted(self.restarts)))
        return "; ".join(parts)
