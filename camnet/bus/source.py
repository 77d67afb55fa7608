"""Who published a sample: Zenoh's source info, stated by a node's publisher and read by a listener.

Zenoh sends a sample's source (the publishing session's id and its
publisher's) only when the publisher states it. A node that others must tell
from any peer publishing on its key (the calibrator, for `camnet up`) is
given its session id (`--session-id`), so that its supervisor knows it
before it starts, and publishes through `SourcedPublisher`; so do feature
stages, whose camera's features the matcher takes from the first source it
hears (services/matcher_frames.py). On an open bus a
peer can state any source: this tells the rig's own node from a stray or
careless publisher, not from an attacker (a secured rig keeps those out).

The calibrator also declares a liveliness token that names its session
(`declare_calibrator`); every node that reads calibrations (the matcher, the
recorder) takes one only from a session a token names (`CalibratorSources`),
and counts the others as foreign. A calibration may arrive before its
calibrator's token (the two travel apart, and a node that starts learns of
the tokens already declared by asking): the latest few of each unknown source
are held for `HOLD_S` and taken when its token comes, so that the calibrator's
first calibration (the one it resumed, say) is not lost.
"""

from __future__ import annotations

import collections
import itertools
import re
import secrets
import threading
import time
from collections.abc import Callable

from camnet.errors import InputError

_SESSION_ID = re.compile(r"[0-9a-f]{32}")

FOREIGN_CALIBRATIONS = "foreign calibrations"  # the count's kind, in a node's statistics (`camnet status`)
HOLD_S = 10.0  # how long a calibration waits for its source's calibrator token before it is counted foreign
HELD_PER_SOURCE = 4  # calibrations held per source (the calibrator's answer and first ones); beyond, the oldest
HELD_SOURCES = 8  # sources with calibrations held at once; beyond, the longest held are counted foreign


def new_session_id() -> str:
    """A random Zenoh session id: 32 lowercase hex digits, the first not 0 (Zenoh prints none of those)."""
    return secrets.choice("123456789abcdef") + secrets.token_hex(16)[1:]


def check_session_id(value: str, *, what: str = "--session-id") -> str:
    """`value` if it is a session id `new_session_id` could have made; InputError naming `what` if not."""
    if not _SESSION_ID.fullmatch(value) or value[0] == "0":
        raise InputError(f"{what}: expected 32 lowercase hex digits, the first not 0, got {value!r}")
    return value


def declare_stage(session, rig: str, camera_id: str):
    """The liveliness token that declares a feature stage of `camera_id` on the bus: the matcher takes the
    camera's features only while one is declared (services/matcher_frames.py). Undeclare it to leave."""
    from camnet.bus import keys
    from camnet.bus.session import declare_liveliness

    return declare_liveliness(session, keys.features(rig, camera_id))


def declare_calibrator(session, rig: str):
    """The liveliness token that declares the calibrator of `rig` on `session`: nodes take calibrations only
    from a session so declared (`CalibratorSources`). Undeclare it to leave."""
    from camnet.bus import keys
    from camnet.bus.session import declare_liveliness

    return declare_liveliness(session, keys.calibrator(rig, str(session.info.zid())))


def reply_source(reply) -> str | None:
    """The session id of the node that answered a query with `reply`; None when Zenoh does not say."""
    replier = reply.replier_id
    return None if replier is None else str(replier.zid)


def sample_source(sample) -> str | None:
    """The session id a sample states as its source; None when it states none."""
    info = sample.source_info
    return None if info is None else str(info.source_id.zid)


class SourcedPublisher:
    """A Zenoh publisher whose every sample states it as its source, numbered."""

    def __init__(self, publisher) -> None:
        self._publisher = publisher
        self._numbers = itertools.count()

    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        import zenoh

        source = zenoh.SourceInfo(self._publisher.id, next(self._numbers))
        self._publisher.put(payload, attachment=attachment, source_info=source)

    def undeclare(self) -> None:
        self._publisher.undeclare()


class CalibratorSources:
    """The rig's declared calibrators, from their liveliness tokens: what is published or answered on the
    calibration key is taken (`admit`) only from one of them; the rest are counted in `foreign` (kind
    `FOREIGN_CALIBRATIONS`) and ignored.

    Thread-safe: tokens and calibrations arrive on Zenoh's threads. Calibrations are handed on under the
    lock, so that those held until their token came are handed on in order, before any newer one.
    """

    def __init__(self, foreign, *, hold_s: float = HOLD_S) -> None:
        self.foreign = foreign  # a camnet.bus.node.Tally
        self.hold_s = hold_s
        self._live: set[str] = set()
        # Source -> (monotonic time held since, hand on) of its latest calibrations, oldest first.
        self._held: dict[str, collections.deque[tuple[float, Callable[[], None]]]] = {}
        self._lock = threading.Lock()

    def declare(self, session, rig: str, failures):
        """Watch the calibrator tokens of `rig` (those already declared too); the liveliness subscriber."""
        from camnet.bus import keys
        from camnet.bus.node import guarded

        return session.liveliness().declare_subscriber(
            keys.all_calibrators(rig), guarded(self.on_token, failures, "watching the calibrators"), history=True)

    def on_token(self, sample) -> None:
        """Liveliness callback: a calibrator joins (what it published before is handed on) or leaves."""
        import zenoh

        from camnet.bus import keys

        try:
            _, source = keys.parse_calibrator(str(sample.key_expr))
        except InputError:
            return
        with self._lock:
            if sample.kind != zenoh.SampleKind.PUT:
                self._live.discard(source)
                return
            self._live.add(source)
            for _, hand_on in self._held.pop(source, ()):
                hand_on()

    def admit(self, source: str | None, hand_on: Callable[[], None], *, now_s: float | None = None) -> None:
        """Call `hand_on` (now, or when its token comes) for a calibration from session `source` (None: not
        stated) if a calibrator declares that session; count it as foreign if none does."""
        now_s = time.monotonic() if now_s is None else now_s
        with self._lock:
            self._expire(now_s)
            if source in self._live:
                hand_on()
                return
            if source is None:
                self._count(None, "it states none")
                return
            held = self._held.pop(source, None) or collections.deque()
            self._held[source] = held  # the newest source last: the first to go is the one longest held
            held.append((now_s, hand_on))
            if len(held) > HELD_PER_SOURCE:
                held.popleft()
                self._count(source, "no calibrator of the rig declares that session")
            if len(self._held) > HELD_SOURCES:
                oldest = next(iter(self._held))
                for _ in self._held.pop(oldest):
                    self._count(oldest, "no calibrator of the rig declares that session")

    def expire(self, now_s: float | None = None) -> None:
        """Count as foreign the held calibrations whose token did not come within `hold_s`."""
        with self._lock:
            self._expire(time.monotonic() if now_s is None else now_s)

    def _expire(self, now_s: float) -> None:
        for source, held in list(self._held.items()):
            while held and now_s - held[0][0] >= self.hold_s:
                held.popleft()
                self._count(source, f"no calibrator of the rig declared that session within {self.hold_s:g} s")
            if not held:
                del self._held[source]

    def _count(self, source: str | None, why: str) -> None:
        self.foreign.count(FOREIGN_CALIBRATIONS, "ignoring a calibration that is not the rig's calibrator's (its "
                           "source: %s; %s)", source or "not stated", why)
