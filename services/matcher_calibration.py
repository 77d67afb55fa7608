"""The rig's latest calibration, as the matcher takes it: subscribed, and asked for once at start.

The calibrator publishes each good calibration on ``keys.calibration`` and
answers queries there with the latest one. A matcher that starts after it
(restarted, or joining a running rig) would otherwise match every pair until
the next calibration is published; it asks once, without waiting for the
answer, so that its view graph applies from its first frame sets. A
calibration published meanwhile is newer than the answer and wins.
"""

from __future__ import annotations

import threading

from camnet.bus import keys
from camnet.bus.node import Tally, guarded
from camnet.errors import InputError
from camnet.geometry.model import Calibration
from camnet.io.formats import parse_calibration
from camnet.io.validate import decode_json

QUERY_TIMEOUT_S = 5.0  # the calibrator answers from memory; a rig with none yet answers nothing


class CalibrationInbox:
    """The latest calibration payload, for the worker to take; filled by the subscriber and the start query."""

    def __init__(self, rig_name: str, *, rejected: Tally) -> None:
        self.rig_name = rig_name
        self.rejected = rejected  # calibrations that do not parse are counted here
        self._payload: bytes | None = None
        self._published = False  # one came by subscription: a query's answer is no newer
        self._lock = threading.Lock()

    @property
    def waiting(self) -> bool:
        """Whether a calibration arrived that the worker has not taken yet."""
        return self._payload is not None

    def on_sample(self, sample) -> None:
        """Subscriber callback: the newest published calibration replaces any not yet taken."""
        with self._lock:
            self._payload, self._published = sample.payload.to_bytes(), True

    def on_reply(self, reply) -> None:
        """Query callback: the calibrator's latest, unless one was published since the matcher subscribed."""
        sample = reply.ok
        if sample is None:
            return
        with self._lock:
            if not self._published:
                self._payload = sample.payload.to_bytes()

    def declare(self, session, failures: Tally):
        """Subscribe to the rig's calibrations and ask for the latest (the answer arrives on Zenoh's thread)."""
        key = keys.calibration(self.rig_name)
        subscriber = session.declare_subscriber(key, guarded(self.on_sample, failures, "receiving a calibration"))
        session.get(key, guarded(self.on_reply, failures, "receiving the latest calibration"),
                    timeout=QUERY_TIMEOUT_S)
        return subscriber

    def take(self) -> Calibration | None:
        """The calibration that arrived since the last call, or None; one that does not parse is counted."""
        with self._lock:
            payload, self._payload = self._payload, None
        if payload is None:
            return None
        try:
            return parse_calibration(decode_json(payload, keys.calibration(self.rig_name)))
        except InputError as exc:
            self.rejected.count("calibration", "ignoring a calibration that does not parse (%s)", exc)
            return None
