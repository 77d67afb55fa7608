"""The observations and calibration messages on the bus: frozen values, and their JSON codec.

The matcher publishes an `ObservationsMessage` on ``keys.observations(rig)``,
the calibrator a `CalibrationMessage` on ``keys.calibration(rig)``. On the
wire each is the contract's document (``camnet.observations/1``,
``camnet.calibration/1``, `camnet.io.formats`) followed by its envelope: the
fields below but the first, as keys after the contract's, in the order given,
left out where None (``resumed`` also where false). Readers of the contract
ignore the envelope.

Any program may publish the contract's document alone (a file's content,
another matcher): its envelope fields decode as None. A document that is not
the contract's, or an envelope field of the wrong type, is malformed:
decoding raises a `MessageError` of one line, which a node counts and logs.

The Zenoh attachments beside the messages (the cameras found moved, and those
whose views the matcher forgot) are `camnet.bus.moved`'s.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camnet.bus.latency import MAX_NS, STAMPED, StageStamps
from camnet.errors import InputError
from camnet.ids import validate_id
from camnet.io import validate as v
from camnet.io.formats import calibration_to_doc, load_json, observations_to_doc, parse_calibration, parse_observations
from camnet.model.calibration import Calibration
from camnet.model.observations import Observations
from camnet.solve.report.verdict import Level


class MessageError(InputError):
    """A message that does not decode, said in one line; `kind` names what is wrong, for a node's tally:
    ``json`` where the payload is no JSON, else the path of the offending key."""

    def __init__(self, message: str, *, kind: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class ObservationsMessage:
    """The matcher's pooled tracks (``camnet.observations/1``) and where they come from."""

    # The pool's cameras, known distances and tracks: the contract's keys (of the stereo pair, its cameras and
    # distance; how the matcher matches it stays with the matcher).
    observations: Observations
    rig: str | None = None  # the rig's name
    # New whenever the pool starts afresh (a node start, or a camera whose image size became known later):
    # track ids start over.
    pool_id: str | None = None
    frame_sets: int | None = None  # how many frame sets contributed to the pool
    # Capture time of the newest of them (Unix epoch, ns), from which a consumer measures capture-to-result
    # latency; 0 before the first.
    latest_capture_ns: int | None = None
    latency_ns: StageStamps | None = None  # when that frame set was taken, detected, matched and pooled
    published_ns: int | None = None  # when this message was published (Unix epoch, ns)
    # Not on the wire: where decoding kept `max_tracks` of the message's tracks, how many it held (None: all).
    subsampled_from: int | None = None


@dataclass(frozen=True)
class CalibrationMessage:
    """The calibrator's calibration (``camnet.calibration/1``, with its report) and what it was solved from."""

    calibration: Calibration  # cameras, points, report: the contract's keys and docs/calibration-keys.md's
    rig: str | None = None  # the rig's name
    # The number of the solve that made it: every solve is counted, kept or not, and a calibrator resumed
    # from its state file numbers on from the solve it resumed, so that a number names one calibration.
    solve: int | None = None
    status: Level | None = None  # the verdict's level (camnet.solve.report.verdict): a poor result is never "good"
    warm_start: bool | None = None  # the solve started from the last good calibration
    moved: tuple[str, ...] | None = None  # the cameras this solve found moved
    solved_ns: int | None = None  # solved, judged and stamped for publication (Unix epoch, ns)
    # Those of the observations message solved: what ties the two (camnet.io.run_dir.source_key).
    latest_capture_ns: int | None = None
    frame_sets: int | None = None
    # The observations' stamps and their published_ns, then when the calibrator began to solve them and
    # when it received them.
    latency_ns: StageStamps | None = None
    resumed: bool = False  # published by a restarted calibrator from its state file, before its first solve


# ---------------------------------------------------------------- encoding


def observations_envelope_to_doc(message: ObservationsMessage) -> dict:
    """The keys that follow the contract's in `message`'s document."""
    return _given({"rig": message.rig, "pool_id": message.pool_id, "frame_sets": message.frame_sets,
                   "latest_capture_ns": message.latest_capture_ns, "latency_ns": _stamps_doc(message.latency_ns),
                   "published_ns": message.published_ns})


def observations_message_to_doc(message: ObservationsMessage) -> dict:
    """The JSON document of `message`: the contract's keys, then the envelope's."""
    return {**observations_to_doc(message.observations), **observations_envelope_to_doc(message)}


def encode_observations_message(message: ObservationsMessage) -> bytes:
    """The bytes of `message` on the wire (`camnet.io.observations_encoder` makes the same ones faster)."""
    return json.dumps(observations_message_to_doc(message)).encode()


def calibration_message_to_doc(message: CalibrationMessage) -> dict:
    """The JSON document of `message`: the contract's keys and the report's, then the envelope's."""
    envelope = _given({
        "rig": message.rig, "solve": message.solve, "status": message.status, "warm_start": message.warm_start,
        "moved": None if message.moved is None else list(message.moved), "solved_ns": message.solved_ns,
        "latest_capture_ns": message.latest_capture_ns, "frame_sets": message.frame_sets,
        "latency_ns": _stamps_doc(message.latency_ns), "resumed": message.resumed or None})
    return {**calibration_to_doc(message.calibration), **envelope}


def encode_calibration_message(message: CalibrationMessage) -> bytes:
    """The bytes of `message` on the wire."""
    return json.dumps(calibration_message_to_doc(message), allow_nan=False).encode()


def _given(envelope: dict) -> dict:
    return {key: value for key, value in envelope.items() if value is not None}


def _stamps_doc(stamps: StageStamps | None) -> dict | None:
    return None if stamps is None else stamps.by_stage()


# ---------------------------------------------------------------- decoding


def decode_observations_message(payload: bytes, *, max_tracks: int | None = None,
                                subsample_seed: int | None = None) -> ObservationsMessage:
    """The observations message of `payload`; `MessageError` where it is none.

    Its known distances are taken as they are: the matcher's come from the
    rig file, checked (or deliberately accepted) when it was loaded.
    max_tracks, subsample_seed: as `camnet.io.formats.parse_observations`.
    """
    doc = _json(payload, "observations")
    with _kind_of_error():
        obs = parse_observations(doc, any_distance=True, max_tracks=max_tracks, subsample_seed=subsample_seed)
        sent = len(doc["tracks"])
        return ObservationsMessage(
            obs, rig=_optional(doc, "rig", _rig), pool_id=_optional(doc, "pool_id", v.string),
            frame_sets=_optional(doc, "frame_sets", _count),
            latest_capture_ns=_optional(doc, "latest_capture_ns", _count),
            latency_ns=_optional(doc, "latency_ns", _stamps), published_ns=_optional(doc, "published_ns", _count),
            subsampled_from=sent if sent > len(obs.track_ids) else None)


def decode_calibration_message(payload: bytes) -> CalibrationMessage:
    """The calibration message of `payload`; `MessageError` where it is none."""
    return _calibration_message(_json(payload, "calibration"))


def load_calibration_message(path: str | Path) -> CalibrationMessage:
    """The calibration message a file holds (a calibrator's state, a run's calibration.json); InputError
    where it cannot be read or holds none."""
    return _calibration_message(load_json(path))


def _calibration_message(doc: Any) -> CalibrationMessage:
    with _kind_of_error():
        return CalibrationMessage(
            parse_calibration(doc), rig=_optional(doc, "rig", _rig), solve=_optional(doc, "solve", _count),
            status=_optional(doc, "status", _level), warm_start=_optional(doc, "warm_start", v.boolean),
            moved=_optional(doc, "moved", _camera_ids), solved_ns=_optional(doc, "solved_ns", _count),
            latest_capture_ns=_optional(doc, "latest_capture_ns", _count),
            frame_sets=_optional(doc, "frame_sets", _count), latency_ns=_optional(doc, "latency_ns", _stamps),
            resumed=_optional(doc, "resumed", v.boolean) or False)


def _json(payload: bytes, what: str) -> Any:
    try:
        return v.decode_json(payload, what)
    except InputError as exc:
        raise MessageError(str(exc), kind="json") from None


@contextmanager
def _kind_of_error():
    """Turns an InputError raised inside into a MessageError whose kind is the offending key's path."""
    try:
        yield
    except MessageError:
        raise
    except InputError as exc:
        raise MessageError(str(exc), kind=str(exc).split(":", 1)[0]) from None


def _optional(doc: dict, key: str, read) -> Any:
    """`read(doc[key], key)`, or None where `doc` has no `key` (null is a wrong type, not an absence)."""
    return read(doc[key], key) if key in doc else None


def _count(value: Any, path: str) -> int:
    """A non-negative integer: a count, or a time in Unix-epoch nanoseconds."""
    number = v.integer(value, path)
    if not 0 <= number < MAX_NS:
        raise v.fail(path, f"expected 0 to {MAX_NS - 1}, got {number}")
    return number


def _rig(value: Any, path: str) -> str:
    return validate_id(value, what=path)


def _level(value: Any, path: str) -> Level:
    return Level(v.string(value, path, choices=tuple(Level)))


def _camera_ids(value: Any, path: str) -> tuple[str, ...]:
    return tuple(validate_id(c, what=f"{path}[{i}]") for i, c in enumerate(v.array(value, path)))


def _stamps(value: Any, path: str) -> StageStamps:
    """A ``latency_ns`` object: stage -> Unix epoch, ns; other keys are ignored."""
    stamps = v.mapping(value, path)
    return StageStamps.from_stages({stage: _count(stamps[stage], f"{path}.{stage}") for stage in STAMPED
                                    if stage in stamps})
