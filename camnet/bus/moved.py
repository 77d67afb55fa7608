"""The attachments that tell of moved cameras: the calibrator's, naming the cameras it found moved, and the
matcher's, saying from which track on it pooled each camera's views afresh.

The matcher forgets what it pooled of a moved camera (its old-pose views
would otherwise judge its new ones, `camnet.matching.pool.TrackPool.forget_camera`).
Told in a Zenoh attachment rather than read from the document: the matcher
parses a calibration (thousands of points) at most once per period, while
this is read on Zenoh's thread as each one arrives, and none is missed when a
newer calibration replaces one the matcher has not taken. The document itself
stays as the formats contract says (its ``moved`` key names the moves found
by that solve; the attachment also those of solves not published).

Until the matcher has forgotten a moved camera, its new views are judged
against its pairs' old epipolar geometry: the few that pass can fit a wrong
pose well (docs/benchmarks.md, "A moved camera"). Each observations
message the matcher publishes therefore says, in its attachment
``{"forgotten": {camera id: track id}}``, from which track on it pooled each
camera's views afresh (after the calibrator named it, or after its own pool
found it moved), and the calibrator places a moved camera again only from
those (`camnet.live.tracker`). Always sent, empty where none was forgotten:
observations without it (a recording, another version) come from a source
that says nothing of this, and are solved as before.
"""

from __future__ import annotations

import json

from camnet.bus.json_payload import decode_json_payload
from camnet.errors import InputError
from camnet.ids import validate_id

KEY = "moved"
FORGOTTEN_KEY = "forgotten"
MAX_TRACK_ID = 2**53  # track ids are JSON numbers: exact up to here


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


def forgotten_attachment(first_ids) -> bytes:
    """The observations' attachment: per camera whose views the matcher forgot, the first track id pooled
    since (JSON ``{"forgotten": {camera id: id}}``, UTF-8; empty where none was)."""
    return json.dumps({FORGOTTEN_KEY: {validate_id(c, what="camera id"): int(first_ids[c])
                                       for c in sorted(first_ids)}}).encode()


def parse_forgotten_attachment(data: bytes | None) -> dict[str, int] | None:
    """Per camera, the first track id pooled since its views were forgotten (`forgotten_attachment`); None
    where there is no attachment (a source that says nothing of it). InputError where it is not one of ours."""
    if data is None:
        return None
    try:
        doc = decode_json_payload(data)
    except InputError as exc:
        raise InputError(f"observations attachment: {exc}") from None
    first_ids = doc.get(FORGOTTEN_KEY) if isinstance(doc, dict) else None
    if not isinstance(first_ids, dict) or not all(
            type(i) is int and 0 <= i < MAX_TRACK_ID for i in first_ids.values()):
        raise InputError(f"observations attachment: expected {{{FORGOTTEN_KEY!r}: {{camera id: track id}}}}, "
                         f"got {str(doc)[:80]!r}")
    return {validate_id(c, what="forgotten camera id"): i for c, i in first_ids.items()}
