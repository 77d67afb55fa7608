"""Which cameras' frames the matcher receives: only those of cameras without a feature stage.

A camera whose feature stage (`camnet driver --features`) publishes its
keypoints and descriptors still publishes its frames, for the recorder and
the viewer. Received by the matcher only to be dropped, 16 cameras' frames
cost its Zenoh threads a fifth of its CPU. So the matcher subscribes to frames
with one key expression for the whole rig while every camera sends frames
only, and with one subscriber per camera that needs its frames once some send
features (a key expression cannot leave cameras out). Frames of a camera not
in the rig are then no longer received, nor reported: its features are.

A feature stage that stops must not leave its camera unseen: when no features
of a camera came for `STALE_INTERVALS` of its own intervals between features
(the frame-set interval of a stage on a capture grid), and at least
`MIN_STALE_S`, its frames are received again, with a warning; its features,
should they come back, take over again.

Zenoh's threads report features (`features_arrived`) and ask whether a frame
is wanted (`sends_features`); the worker declares and undeclares subscribers
(`update`), never a callback, which must not wait on Zenoh.
"""

from __future__ import annotations

import logging
import statistics
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)

STALE_INTERVALS = 10  # a stage silent for this many of its intervals is taken for stopped
MIN_STALE_S = 5.0  # and for at least this long: a loaded host delays features by seconds
INTERVALS_KEPT = 9  # the median of a stage's recent intervals is its interval


@dataclass
class _Stage:
    """A camera's feature stage as the matcher sees it."""

    last_s: float  # monotonic time of its latest features
    gaps_s: deque = field(default_factory=lambda: deque(maxlen=INTERVALS_KEPT))

    def interval_s(self) -> float:
        return statistics.median(self.gaps_s) if self.gaps_s else 0.0

    def deadline_s(self) -> float:
        return self.last_s + max(MIN_STALE_S, STALE_INTERVALS * self.interval_s())


class FrameSubscriptions:
    """The frame subscribers of a rig's cameras (`declare_all`, `declare_one`: what Zenoh's
    ``declare_subscriber`` returns, for every camera's frames and for one camera's)."""

    def __init__(self, camera_ids: Iterable[str], *, declare_all: Callable[[], Any],
                 declare_one: Callable[[str], Any]) -> None:
        self.camera_ids = tuple(camera_ids)
        self._declare_all = declare_all
        self._declare_one = declare_one
        self._lock = threading.Lock()
        self._stages: dict[str, _Stage] = {}  # cameras whose features come from their own stage
        self._all = None  # the subscriber to every camera's frames, while no camera sends features
        self._one: dict[str, Any] = {}  # otherwise one subscriber per camera whose frames are needed
        self.fallbacks = 0  # stages taken for stopped

    # ------------------------------------------------------------ Zenoh's threads

    def features_arrived(self, camera_id: str, now_s: float) -> None:
        with self._lock:
            stage = self._stages.get(camera_id)
            if stage is None:
                self._stages[camera_id] = _Stage(now_s)
                log.info("camera %r: features from its own stage; its frames are no longer received here",
                         camera_id)
                return
            stage.gaps_s.append(now_s - stage.last_s)
            stage.last_s = now_s

    def sends_features(self, camera_id: str) -> bool:
        return camera_id in self._stages  # a dict lookup is atomic: no lock on the frame path

    def arrivals(self, now_s: float) -> dict[str, tuple[float, float]]:
        """(seconds since its latest features, its interval between features) per camera whose stage sends them."""
        with self._lock:
            return {c: (now_s - stage.last_s, stage.interval_s()) for c, stage in self._stages.items()}

    @property
    def feature_cameras(self) -> frozenset[str]:
        with self._lock:
            return frozenset(self._stages)

    @property
    def frame_cameras(self) -> frozenset[str]:
        """Cameras whose frames are subscribed to now."""
        return frozenset(self.camera_ids) if self._all is not None else frozenset(self._one)

    # ------------------------------------------------------------ the worker

    def update(self, now_s: float) -> None:
        """Take stopped stages' cameras back to frames, then subscribe to the frames needed."""
        with self._lock:
            for camera_id, stage in list(self._stages.items()):
                if now_s > stage.deadline_s():
                    del self._stages[camera_id]
                    self.fallbacks += 1
                    log.warning("camera %r: no features from its stage for %.1f s (%.2f s apart before); "
                                "receiving its frames again", camera_id, now_s - stage.last_s, stage.interval_s())
            features = set(self._stages)
        if not features:
            if self._all is None:
                self._undeclare(list(self._one))
                self._all = self._declare_all()
            return
        if self._all is not None:
            # Undeclared first: a frame missed while switching is harmless, one received twice is not.
            self._all.undeclare()
            self._all = None
        self._undeclare([c for c in self._one if c in features])
        for camera_id in self.camera_ids:
            if camera_id not in features and camera_id not in self._one:
                self._one[camera_id] = self._declare_one(camera_id)

    def _undeclare(self, camera_ids: list[str]) -> None:
        for camera_id in camera_ids:
            self._one.pop(camera_id).undeclare()

    def close(self) -> None:
        self._undeclare(list(self._one))
        if self._all is not None:
            self._all.undeclare()
            self._all = None
