"""The rig's latest calibration, as the matcher takes it: subscribed, and asked for until one comes.

The calibrator publishes each good calibration on ``keys.calibration`` and
answers queries there with the latest one. A matcher that starts after it
(restarted, or joining a running rig) would otherwise match every pair until
the next calibration is published; it asks at start, without waiting for the
answer, so that its view graph applies from its first frame sets. A
calibration published meanwhile is newer than the answer and wins. A query
sent before the session has learnt of the calibrator's queryable (a loaded
machine, a router still connecting) gets no answer, so it asks again every
`ASK_PERIOD_S` until a calibration has come.

A published calibration's attachment names the cameras found moved since
the one before (`camnet.bus.moved`); they are gathered here as they arrive,
whether or not their calibration is ever taken, for the worker to forget
(`take_moved`, `camnet.matching.engine.MatchingEngine.forget_moved`) once each
time the calibrator names them. Each observations
message then says from which track on the pool holds a forgotten camera's
views afresh (`pool_attachment`): the calibrator places it only from those.

Calibrations are taken only from the rig's calibrator, published or answered
(`camnet.bus.source.CalibratorSources`): one from any other publisher is
counted as foreign, its attachment ignored too.

Each calibration is parsed as it arrives, so that every one that does not
parse is counted (the worker takes one at most every few seconds, and most
are replaced before then), and one that does not parse never replaces a good
one not taken yet.
"""

from __future__ import annotations

import threading

from camnet.bus import keys
from camnet.bus.moved import forgotten_attachment, parse_moved_attachment
from camnet.bus.node import Tally, guarded
from camnet.bus.source import CalibratorSources, reply_source, sample_source
from camnet.errors import InputError
from camnet.io.messages import decode_calibration_message
from camnet.matching.pool import TrackPool
from camnet.model.calibration import Calibration

QUERY_TIMEOUT_S = 5.0  # the calibrator answers from memory; a rig with none yet answers nothing
ASK_PERIOD_S = 3.0  # asked again this often while no calibration has come


class CalibrationInbox:
    """The latest calibration payload, for the worker to take; filled by the subscriber and the start query."""

    def __init__(self, rig_name: str, *, rejected: Tally, foreign: Tally) -> None:
        self.rig_name = rig_name
        self.rejected = rejected  # calibrations that do not parse are counted here
        self.sources = CalibratorSources(foreign)  # those from another publisher than the calibrator, there
        self._latest: Calibration | None = None  # parsed, not taken yet
        self._published = False  # one came by subscription: a query's answer is no newer
        self._received = False  # one came, by subscription or answer: no more asking
        self._asked_s = float("-inf")  # monotonic time of the latest query
        self._ask = None  # sends the query, once declared
        self.asked = 0  # queries sent
        self._moved: set[str] = set()  # cameras named moved, not yet taken
        self._lock = threading.Lock()

    @property
    def waiting(self) -> bool:
        """Whether a calibration arrived that the worker has not taken yet."""
        return self._latest is not None

    def on_sample(self, sample) -> None:
        """Subscriber callback: the newest published calibration replaces any not yet taken; the cameras
        its attachment names moved are added to those not yet taken."""
        attachment = sample.attachment
        try:
            moved = parse_moved_attachment(None if attachment is None else attachment.to_bytes())
        except InputError as exc:
            moved = ()
            self.rejected.count("calibration attachment", "ignoring a calibration's attachment (%s); is the "
                                "calibrator of another camnet version?", exc)
        calibration = self._parse(sample.payload.to_bytes())
        with self._lock:
            self._moved.update(moved)
            if calibration is not None:
                self._latest, self._published, self._received = calibration, True, True

    def take_moved(self) -> tuple[str, ...]:
        """The cameras named moved since the last call (sorted), each once."""
        with self._lock:
            moved, self._moved = self._moved, set()
        return tuple(sorted(moved))

    def on_reply(self, reply) -> None:
        """Query callback: the calibrator's latest, unless one was published since the matcher subscribed."""
        sample = reply.ok
        if sample is None:
            return
        calibration = self._parse(sample.payload.to_bytes())
        with self._lock:
            if not self._published and calibration is not None:
                self._latest, self._received = calibration, True

    def declare(self, session, failures: Tally, now_s: float) -> tuple:
        """Watch the rig's calibrators, subscribe to their calibrations and ask for the latest (the answer
        arrives on Zenoh's thread); the entities declared."""
        import zenoh

        key = keys.calibration(self.rig_name)
        calibrators = self.sources.declare(session, self.rig_name, failures)
        # Handed on when the calibrator is known: maybe later, on the thread of its token.
        on_sample = guarded(self.on_sample, failures, "receiving a calibration")
        on_reply = guarded(self.on_reply, failures, "receiving the latest calibration")
        subscriber = session.declare_subscriber(
            key, lambda sample: self.sources.admit(sample_source(sample), lambda: on_sample(sample)))
        # Every answer, not Zenoh's one per key: another peer answering must not hide the calibrator's.
        self._ask = lambda: session.get(key, lambda reply: self.sources.admit(reply_source(reply),
                                                                              lambda: on_reply(reply)),
                                        timeout=QUERY_TIMEOUT_S, consolidation=zenoh.ConsolidationMode.NONE)
        self.ask_until_answered(now_s)
        return calibrators, subscriber

    def ask_until_answered(self, now_s: float) -> None:
        """Ask for the latest calibration if none has come and `ASK_PERIOD_S` passed since the last query;
        count as foreign what waited too long for its calibrator."""
        self.sources.expire(now_s)
        if self._ask is None or self._received or now_s < self._asked_s + ASK_PERIOD_S:
            return
        self._asked_s = now_s
        self.asked += 1
        self._ask()

    def take(self) -> Calibration | None:
        """The calibration that arrived since the last call, or None."""
        with self._lock:
            calibration, self._latest = self._latest, None
        return calibration

    def _parse(self, payload: bytes) -> Calibration | None:
        """The calibration of `payload`; None for one that does not parse (counted)."""
        try:
            return decode_calibration_message(payload).calibration
        except InputError as exc:
            self.rejected.count("calibration", "ignoring a calibration that does not parse (%s)", exc)
            return None


def pool_attachment(pool: TrackPool) -> bytes:
    """The attachment of the observations `pool` is published as: from which track on it pooled each forgotten
    camera's views afresh (`camnet.bus.moved.forgotten_attachment`)."""
    return forgotten_attachment(pool.forgotten)
