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

Whose features: a feature stage declares itself for its camera with a
liveliness token on the camera's features key (`declare_stage`), and states
its session as the source of each message (`camnet.bus.source`). A camera's
features are taken only while a stage is declared for it (`stage_declared`,
`stage_left`: from the matcher's liveliness subscriber), and only from the
first source that states itself: features from another source, or stating
none once a source is known, are foreign, refused so that a stray publisher on
the camera's key can neither feed the matcher nor take the place of the
camera's frames. A stage that leaves takes its source along: a restarted one,
a new session, is then taken at its first features. A publisher that declares
a stage of its own, or states the stage's source, is not told apart: only a
secured rig keeps those out.

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
    source: str | None  # the session id its features state; None while none stated one
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
        self._declared: set[str] = set()  # cameras with a feature stage on the bus (its liveliness token)

    # ------------------------------------------------------------ Zenoh's threads

    def stage_declared(self, camera_id: str) -> None:
        """A feature stage of `camera_id` is on the bus: its features are taken from now on."""
        with self._lock:
            self._declared.add(camera_id)

    def stage_left(self, camera_id: str) -> None:
        """The camera's feature stage left the bus: its frames are received again, its features refused
        until a stage is declared again, and then taken from whichever source states itself first."""
        with self._lock:
            self._declared.discard(camera_id)
            if self._stages.pop(camera_id, None) is not None:
                log.info("camera %r: its feature stage left; receiving its frames again", camera_id)

    def features_arrived(self, camera_id: str, now_s: float, source: str | None = None) -> str | None:
        """Take features of `camera_id` that state `source` (None: none); why not, when they are foreign."""
        with self._lock:
            if camera_id not in self._declared:
                return "no feature stage of the camera is on the bus"
            stage = self._stages.get(camera_id)
            if stage is None:
                self._stages[camera_id] = _Stage(now_s, source)
                log.info("camera %r: features from its own stage (source %s); its frames are no longer received "
                         "here", camera_id, source or "not stated")
                return None
            if stage.source is None and source is not None:
                stage.source = source
                log.info("camera %r: its features are taken from source %s only", camera_id, source)
            elif source != stage.source:
                return f"its stage is source {stage.source}"
            stage.gaps_s.append(now_s - stage.last_s)
            stage.last_s = now_s
            return None

    def stage_source(self, camera_id: str) -> str | None:
        """The source the features of `camera_id` are taken from; None when none is known."""
        stage = self._stages.get(camera_id)
        return None if stage is None else stage.source

    def sends_features(self, camera_id: str) -> bool:
        return camera_id in self._stages  # a dict lookup is atomic: no lock on the frame path

    def arrivals(self, now_s: float) -> dict[str, tuple[float, float]]:
        """(seconds since its latest features, its interval between features) per camera whose stage sends them."""
        with self._lock:
            return {c: (now_s - stage.last_s, stage.interval_s()) for c, stage in self._stages.items()}

    @property
    def declared_cameras(self) -> frozenset[str]:
        """Cameras with a feature stage declared on the bus."""
        with self._lock:
            return frozenset(self._declared)

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
