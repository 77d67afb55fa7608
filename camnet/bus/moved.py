"""The attachment of a published calibration that names the cameras found moved since the one before.

The matcher forgets what it pooled of a moved camera (its old-pose views
would otherwise judge its new ones, `camnet.matching.pool.TrackPool.forget_camera`).
Told in a Zenoh attachment rather than read from the document: the matcher
parses a calibration (thousands of points) at most once per period, while
this is read on Zenoh's thread as each one arrives, and none is missed when a
newer calibration replaces one the matcher has not taken. The document itself
stays as the formats contract says (its ``moved`` key names the moves found
by that solve; the attachment also those of solves not published).
"""

from __future__ import annotations

import json

from camnet.bus.json_payload import decode_json_payload
from camnet.errors import InputError
from camnet.ids import validate_id

KEY = "moved"


def moved_attachment(camera_ids) -> bytes | None:
    """The attachment naming `camera_ids` (JSON ``{"moved": [...]}``, UTF-8), or None where none moved."""
    ids = sorted(camera_ids)
    return json.dumps({KEY: [validate_id(c, what="camera id") for c in ids]}).encode() if ids else None


def parse_moved_attachment(data: bytes | None) -> tuple[str, ...]:
    """The camera ids an attachment names (none for None); InputError where it is not one of ours."""
    if data is None:
        return ()
    try:
        doc = decode_json_payload(data)
    except InputError as exc:
        raise InputError(f"calibration attachment: {exc}") from None
    ids = doc.get(KEY) if isinstance(doc, dict) else None
    if not isinstance(ids, list):
        raise InputError(f"calibration attachment: expected {{{KEY!r}: [camera ids]}}, got {str(doc)[:80]!r}")
    return tuple(validate_id(c, what="moved camera id") for c in ids)
