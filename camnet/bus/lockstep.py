"""Lockstep replay: one frame set at a time through the matcher and the calibrator.

`camnet replay --lockstep` publishes the frames of one capture instant (a
step) on the drivers' keys, then announces the step on
``keys.lockstep_step(rig)``, and waits:

1. for the matcher (run with ``--lockstep``) to acknowledge that step on
   ``keys.lockstep_ack(rig, "matcher")``, saying which observations document
   it published for it, if any (`pool_id`, `frame_sets`);
2. if it published one, for the calibrator (``--lockstep``) to acknowledge
   that document on ``keys.lockstep_ack(rig, "calibrator")`` once it has
   solved it and published what came of it.

Then comes the next step. Nothing is dropped and no decision depends on the
wall clock (the matcher forms frame sets and paces its publications on the
replayed capture times), so two replays of a session give the same
observations and the same calibrations. Each lockstep node declares a
liveliness token on its ack key, by which the replayer knows it is there.

Messages are JSON objects:

- step: ``{"format": "camnet.lockstep-step/1", "step": 3, "capture_ns": ...,
  "frames": {"left": 41, "right": 41}, "final": false}`` (camera id -> seq
  of the frames of the step; the step's capture time is its first frame's).
  After the last step comes one with no frames and ``"final": true``, on
  which the matcher publishes what it has not published yet;
- ack: ``{"format": "camnet.lockstep-ack/1", "step": 3 | null, "pool_id":
  "..." | null, "frame_sets": 12 | null, "status": "..."}``.
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import asdict, dataclass

from camnet.bus.frame import Frame
from camnet.bus.json_payload import decode_json_payload
from camnet.errors import InputError

STEP_FORMAT = "camnet.lockstep-step/1"
ACK_FORMAT = "camnet.lockstep-ack/1"


def _load(payload: bytes, expected_format: str) -> dict:
    try:
        doc = decode_json_payload(payload)
    except InputError as exc:
        raise InputError(f"{expected_format}: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != expected_format:
        raise InputError(f"expected a {expected_format} message")
    return doc


@dataclass(frozen=True)
class Step:
    """The frames of one replayed capture instant: camera id -> seq."""

    step: int
    capture_ns: int
    frames: dict[str, int]
    final: bool = False  # the session's end: publish what is pending, whatever the period

    def to_json(self) -> bytes:
        return json.dumps({"format": STEP_FORMAT, **asdict(self)}).encode()

    @classmethod
    def parse(cls, payload: bytes) -> Step:
        doc = _load(payload, STEP_FORMAT)
        try:
            step, capture_ns = int(doc["step"]), int(doc["capture_ns"])
            frames = {str(c): int(seq) for c, seq in doc["frames"].items()}
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise InputError(f"{STEP_FORMAT}: bad or missing field ({exc})") from None
        return cls(step, capture_ns, frames, bool(doc.get("final", False)))


@dataclass(frozen=True)
class Ack:
    """A lockstep node is done: with `step` (matcher) or with the observations document named by
    (`pool_id`, `frame_sets`) (calibrator). A matcher that published no document for its step
    leaves `pool_id` None."""

    step: int | None = None
    pool_id: str | None = None
    frame_sets: int | None = None
    status: str = ""

    def to_json(self) -> bytes:
        return json.dumps({"format": ACK_FORMAT, **asdict(self)}).encode()

    @classmethod
    def parse(cls, payload: bytes) -> Ack:
        doc = _load(payload, ACK_FORMAT)
        step, pool_id, frame_sets = doc.get("step"), doc.get("pool_id"), doc.get("frame_sets")
        for name, value, kind in (("step", step, int), ("pool_id", pool_id, str), ("frame_sets", frame_sets, int)):
            if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
                raise InputError(f"{ACK_FORMAT}: {name} must be {kind.__name__} or null, got {type(value).__name__}")
        return cls(step, pool_id, frame_sets, str(doc.get("status", "")))


class StepInbox:
    """The matcher's side: frames and step messages as Zenoh's threads deliver them, in any order.

    Bounded: at most `capacity` frames and steps are held (the replayer sends
    one step at a time); beyond that the oldest go, counted in `overflowed`.
    """

    def __init__(self, *, capacity: int = 64) -> None:
        self._ready = threading.Condition()
        self._frames: OrderedDict[tuple[str, int], Frame | None] = OrderedDict()
        self._steps: deque[Step] = deque()
        self._capacity = capacity
        self.overflowed = 0

    def add_frame(self, camera_id: str, seq: int, frame: Frame | None) -> None:
        """A frame arrived (None: it arrived but cannot be used)."""
        with self._ready:
            self._frames[(camera_id, seq)] = frame
            if len(self._frames) > self._capacity:
                self._frames.popitem(last=False)
                self.overflowed += 1
            self._ready.notify_all()

    def add_step(self, step: Step) -> None:
        with self._ready:
            self._steps.append(step)
            if len(self._steps) > self._capacity:
                self._steps.popleft()
                self.overflowed += 1
            self._ready.notify_all()

    def next_step(self, *, timeout_s: float) -> Step | None:
        with self._ready:
            if not self._ready.wait_for(lambda: self._steps, timeout=timeout_s):
                return None
            return self._steps.popleft()

    def take_frames(self, step: Step, *, timeout_s: float) -> tuple[dict[str, Frame], list[str]]:
        """(usable frames of `step` by camera id, cameras whose frame never came), waiting up to `timeout_s`."""
        wanted = set(step.frames.items())
        with self._ready:
            self._ready.wait_for(lambda: wanted <= self._frames.keys(), timeout=timeout_s)
            taken = {key: self._frames.pop(key) for key in sorted(wanted) if key in self._frames}
        frames = {camera_id: frame for (camera_id, _), frame in taken.items() if frame is not None}
        missing = sorted(camera_id for camera_id, seq in wanted if (camera_id, seq) not in taken)
        return frames, missing


class AckBox:
    """The replayer's side: acknowledgements by node kind, waited on one at a time."""

    def __init__(self, *, capacity: int = 64) -> None:
        self._ready = threading.Condition()
        self._acks: dict[str, deque[Ack]] = {}
        self._capacity = capacity

    def add(self, kind: str, ack: Ack) -> None:
        with self._ready:
            self._acks.setdefault(kind, deque(maxlen=self._capacity)).append(ack)
            self._ready.notify_all()

    def wait(self, kind: str, wanted: Callable[[Ack], bool], *, timeout_s: float,
             stop: threading.Event) -> Ack | None:
        """The first ack of `kind` for which `wanted` holds (removed), or None on timeout or `stop`."""
        deadline = time.monotonic() + timeout_s
        with self._ready:
            while not stop.is_set():
                queue = self._acks.get(kind, ())
                found = next((ack for ack in queue if wanted(ack)), None)
                if found is not None:
                    queue.remove(found)
                    return found
                left_s = deadline - time.monotonic()
                if left_s <= 0:
                    return None
                self._ready.wait(min(left_s, 0.1))
        return None
