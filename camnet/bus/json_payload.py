"""The JSON value of a bus message's payload or attachment, refused cleanly however malformed."""

from __future__ import annotations

import json

from camnet.errors import InputError


def decode_json_payload(payload: bytes) -> object:
    """The JSON value of `payload`; InputError for anything else, however malformed (nesting deep
    enough to exhaust the stack is a RecursionError, not a ValueError)."""
    try:
        return json.loads(payload)
    except (ValueError, RecursionError) as exc:
        raise InputError(f"not JSON ({type(exc).__name__})") from None
