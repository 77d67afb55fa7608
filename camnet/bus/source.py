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
"""

from __future__ import annotations

import itertools
import re
import secrets

from camnet.errors import InputError

_SESSION_ID = re.compile(r"[0-9a-f]{32}")


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
