"""Node statistics published next to each node's liveliness token (JSON)."""

from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass, field

from camnet.errors import InputError

STATS_FORMAT = "camnet.node-stats/1"


@dataclass(frozen=True)
class Activity:
    """What a node says it did: `fps` measured over the last few seconds; counters since start."""

    fps: float
    frames: int
    dropped: int
    detail: str = ""
    cameras: dict[str, CameraSeen] = field(default_factory=dict)  # a consumer of frames: what it gets of each


@dataclass(frozen=True)
class CameraSeen:
    """What a node that takes frames (the matcher) sees of one camera: seconds since its last frame
    (None: none yet), its frame rate as received, and whether it counts as missing (silent for longer
    than the node waits for it)."""

    age_s: float | None
    fps: float
    missing: bool

    def to_doc(self) -> dict:
        return {"age_s": self.age_s, "fps": self.fps, "missing": self.missing}

    @staticmethod
    def from_doc(doc: object) -> CameraSeen:
        if not isinstance(doc, dict):
            raise TypeError(f"a camera's entry must be an object, got {type(doc).__name__}")
        age = doc["age_s"]
        missing = doc["missing"]
        if not isinstance(missing, bool):
            raise TypeError("missing must be true or false")
        return CameraSeen(age_s=None if age is None else _finite(age, "age_s"), fps=_finite(doc["fps"], "fps"),
                          missing=missing)


def _finite(value: object, name: str) -> float:
    """`value` as a finite float; ValueError otherwise (JSON may carry 1e999, which reads as infinity)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {str(value)[:20]}")
    return float(value)


@dataclass(frozen=True)
class NodeStats:
    """One report of a node: its `Activity`, who it is, when (`timestamp_ns`, Unix epoch), and
    `faults`: what it dropped or survived (malformed messages, failed handlers), by kind."""

    rig: str
    kind: str
    node_id: str
    fps: float
    frames: int
    dropped: int
    timestamp_ns: int
    detail: str = ""
    faults: dict[str, int] = field(default_factory=dict)
    cameras: dict[str, CameraSeen] = field(default_factory=dict)

    def to_json(self) -> bytes:
        # Written out field by field: dataclasses.asdict, which deep-copies, is too slow for a driver's frame
        # loop, where this runs every second (docs/benchmarks.md, "Evidence behind the nodes' choices").
        doc = {"format": STATS_FORMAT, "rig": self.rig, "kind": self.kind, "node_id": self.node_id,
               "fps": self.fps, "frames": self.frames, "dropped": self.dropped,
               "timestamp_ns": self.timestamp_ns, "detail": self.detail, "faults": dict(self.faults),
               "cameras": {camera_id: seen.to_doc() for camera_id, seen in self.cameras.items()}}
        return json.dumps(doc, allow_nan=False).encode()

    @staticmethod
    def from_json(payload: bytes) -> NodeStats:
        try:
            doc = json.loads(payload)
            if doc.get("format") != STATS_FORMAT:
                raise InputError(f"stats: unsupported format {str(doc.get('format'))[:40]!r}")
            return NodeStats(rig=str(doc["rig"]), kind=str(doc["kind"]),
                             node_id=str(doc["node_id"]), fps=_finite(doc["fps"], "fps"),
                             frames=int(doc["frames"]), dropped=int(doc["dropped"]),
                             timestamp_ns=int(doc["timestamp_ns"]),
                             detail=str(doc.get("detail", "")),
                             faults={str(k): int(n) for k, n in doc.get("faults", {}).items()},
                             cameras={str(c): CameraSeen.from_doc(seen)
                                      for c, seen in doc.get("cameras", {}).items()})
        except (ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError) as exc:
            raise InputError(f"stats: malformed message ({str(exc)[:80]})") from None


class RateMeter:
    """Events per second over a sliding window of `window_s` seconds (monotonic clock)."""

    def __init__(self, window_s: float = 2.0) -> None:
        self.window_s = window_s
        self._times: deque[float] = deque()

    def tick(self, now_s: float | None = None) -> None:
        now_s = time.monotonic() if now_s is None else now_s
        self._times.append(now_s)
        self._trim(now_s)

    def _trim(self, now_s: float) -> None:
        while self._times and self._times[0] < now_s - self.window_s:
            self._times.popleft()

    def rate(self, now_s: float | None = None) -> float:
        now_s = time.monotonic() if now_s is None else now_s
        self._trim(now_s)
        if len(self._times) < 2:
            return 0.0
        span = self._times[-1] - self._times[0]
        return (len(self._times) - 1) / span if span > 0 else 0.0
