"""Ids of rigs, cameras and nodes: single Zenoh key chunks, checked where they enter.

They may not be empty nor contain ``/`` or Zenoh's wildcard and verbatim
characters, nor leading or trailing spaces. Shared by the rig file (camnet.io)
and the key expressions (camnet.bus), neither of which imports the other.
"""

from __future__ import annotations

from camnet.errors import InputError

_FORBIDDEN = frozenset("/*$?#")


def validate_id(value: str, *, what: str = "id") -> str:
    """Return `value` if it is usable as one key chunk, else raise InputError naming `what`."""
    if not isinstance(value, str) or not value:
        raise InputError(f"{what}: expected a non-empty string, got {value!r}")
    bad = sorted(set(value) & _FORBIDDEN)
    if bad:
        raise InputError(f"{what}: {value!r} contains {''.join(bad)!r} (not allowed in ids)")
    if value != value.strip():
        raise InputError(f"{what}: {value!r} has leading or trailing spaces")
    return value
