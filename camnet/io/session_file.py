"""The recorded session file: its MCAP layout, and reading it back up to any damage.

A session is an MCAP file (https://mcap.dev) with one channel per Zenoh key
that carried messages; docs/session-format.md describes the layout. This
module holds what the recorder and the replayer must agree on: topics, schema
names, encodings, and the frame header fields read without decoding pixels.

Reading never fails with a traceback on a bad file. `open_session_file`
refuses a file that is not MCAP or holds no camnet frames (InputError); a
file that is damaged (truncated, e.g. by a killed recorder, or with bytes
changed) is read up to the first damage, which `SessionFile.damage` then
describes. What is read is exactly what was written: chunk and summary CRCs
are checked, so a damaged part is never taken for data.
"""

from __future__ import annotations

import io
import json
import logging
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import zstandard
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC

from camnet.bus import keys
from camnet.bus.frame import (
    ENCODINGS,
    MAGIC,
    VERSION,
    Compression,
    decode_header,
)
from camnet.errors import InputError

log = logging.getLogger(__name__)

PROFILE = "camnet"
FRAME_SCHEMA = "camnet.frame/1"
FRAME_ENCODING = "camnet.frame/1"  # message encoding: the binary frame of docs/frame-format.md
FRAME_SCHEMA_ENCODING = "camnet.layout+json"
FEATURES_ENCODING = "camnet.features/1"  # message encoding: the binary features of docs/features-format.md
JSON_ENCODING = "json"
JSONSCHEMA_ENCODING = "jsonschema"
RAW_ENCODING = "application/octet-stream"  # keys camnet does not know (yet)
GAP_FORMAT = "camnet.recorder-gap/1"
NODE_EVENT_FORMAT = "camnet.node-event/1"
SESSION_METADATA = "camnet.session"
SUMMARY_METADATA = "camnet.recording-summary"

# A record longer than this is taken as damage (a changed length field must not
# make the reader allocate gigabytes).
RECORD_SIZE_LIMIT_BYTES = 1 << 30
_FOOTER = struct.Struct("<BQQQI")  # opcode, record length, summary_start, summary_offset_start, crc


def gaps_topic(rig: str) -> str:
    """The MCAP topic of the recorder's gap messages (not a bus key)."""
    return f"{keys.rig_prefix(rig)}/recorder/gaps"


# Camera id, seq and capture time of a wire frame, checked whole, without touching its pixels.
frame_header = decode_header


def frame_schema() -> bytes:
    """Schema data of camnet.frame/1: the byte layout as JSON (docs/frame-format.md)."""
    fields = [("magic", 0, 4, "bytes"), ("version", 4, 1, "u8"), ("encoding", 5, 1, "u8"),
              ("compression", 6, 1, "u8"), ("flags", 7, 1, "u8"), ("header_size", 8, 2, "u16"),
              ("id_len", 10, 2, "u16"), ("width", 12, 4, "u32"), ("height", 16, 4, "u32"),
              ("seq", 20, 8, "u64"), ("timestamp_ns", 28, 8, "u64"), ("payload_size", 36, 4, "u32")]
    doc = {
        "name": FRAME_SCHEMA,
        "description": "One camera image: fixed little-endian header, utf-8 camera id "
                       "(id_len bytes at offset 40), then payload_size bytes of pixels "
                       "at offset header_size. See camnet docs/frame-format.md.",
        "byte_order": "little",
        "magic": MAGIC.decode(),
        "version": VERSION,
        "fields": [{"name": n, "offset": o, "size": s, "type": t} for n, o, s, t in fields],
        "encodings": {name: spec.code for name, spec in ENCODINGS.items()},
        "compressions": {c.name.lower(): int(c) for c in Compression},
    }
    return json.dumps(doc, indent=1).encode()


def _object_schema(title: str, properties: dict, required: list[str]) -> bytes:
    return json.dumps({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title,
                       "type": "object", "properties": properties,
                       "required": required}).encode()


_NUM = {"type": "number"}
_INT = {"type": "integer"}
_STR = {"type": "string"}
_MATRIX = {"type": "array", "items": {"type": "array", "items": _NUM}}
_CAMERAS = {"type": "array", "items": {"type": "object", "properties": {
    "id": _STR, "width": _INT, "height": _INT, "K": _MATRIX, "dist": {"type": "array", "items": _NUM},
    "R": _MATRIX, "t": {"type": "array", "items": _NUM}}, "required": ["id"]}}

# schema name -> JSON Schema of the JSON messages camnet publishes (loose: the
# documents in shared/formats are the contract; these let generic tools browse).
JSON_SCHEMAS: dict[str, bytes] = {
    "camnet.observations/1": _object_schema(
        "camnet.observations/1",
        {"format": _STR, "cameras": _CAMERAS, "stereo": {"type": "object"},
         "tracks": {"type": "array", "items": {"type": "object"}}},
        ["format", "cameras", "tracks"]),
    "camnet.calibration/1": _object_schema(
        "camnet.calibration/1",
        {"format": _STR, "world_frame": _STR, "units": _STR, "cameras": _CAMERAS,
         "points": {"type": "array", "items": {"type": "object"}}, "rms_reprojection_px": _NUM},
        ["format", "cameras"]),
    "camnet.node-stats/1": _object_schema(
        "camnet.node-stats/1",
        {"format": _STR, "rig": _STR, "kind": _STR, "node_id": _STR, "fps": _NUM, "frames": _INT,
         "dropped": _INT, "timestamp_ns": _INT, "detail": _STR},
        ["format", "kind", "node_id"]),
    NODE_EVENT_FORMAT: _object_schema(
        NODE_EVENT_FORMAT,
        {"format": _STR, "event": {"enum": ["joined", "left"]}, "key": _STR, "kind": _STR,
         "node_id": _STR, "timestamp_ns": _INT},
        ["format", "event", "key"]),
    GAP_FORMAT: _object_schema(
        GAP_FORMAT,
        {"format": _STR, "camera_id": _STR, "kind": {"enum": ["gap", "restart"]},
         "last_seq": _INT, "seq": _INT, "missing": _INT, "dropped_by_recorder": _INT,
         "timestamp_ns": _INT},
        ["format", "camera_id", "kind", "last_seq", "seq"]),
}


@dataclass(frozen=True)
class SessionMessage:
    """One recorded message; times in ns since the Unix epoch."""

    topic: str
    message_encoding: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


@dataclass(frozen=True)
class Damage:
    """Where reading stopped: after `messages_before` good messages, for `reason`."""

    reason: str
    messages_before: int

    def describe(self, path: Path) -> str:
        return (f"{path}: damaged after {self.messages_before} message(s) ({self.reason}); "
                "only what precedes the damage is read")


# What the mcap readers raise on bad bytes: their own errors, CRC mismatches
# (ValueError), short reads (struct.error), bad utf-8 (ValueError), codec
# errors (zstandard's own, lz4's RuntimeError), and unknown ids from a changed record.
DAMAGE_ERRORS = (McapError, ValueError, struct.error, zstandard.ZstdError, RuntimeError, KeyError,
                 IndexError, EOFError, OverflowError, MemoryError)


@dataclass
class SessionFile:
    """An opened session: its channels, and its messages in log-time order.

    `topics` maps each topic to (message encoding, schema name) and
    `message_counts` the messages per topic that can be read.
    `damage` is set once damage has been met (up front when the file has no
    valid summary, else possibly only while reading `messages()`).
    """

    path: Path
    topics: dict[str, tuple[str, str]]
    message_counts: dict[str, int]
    damage: Damage | None = None
    _indexed: bool = field(default=False, repr=False)

    @property
    def rigs(self) -> list[str]:
        """Rig names of the frame topics."""
        return sorted({_parse_frame_topic(t)[0] for t in self.topics if _parse_frame_topic(t)})

    def frame_topics(self) -> list[str]:
        return sorted(t for t in self.topics if _parse_frame_topic(t))

    def messages(self) -> Iterator[SessionMessage]:
        """The messages in log-time order (ties: file order), stopping at the first damage."""
        count = 0
        limit = None if self.damage is None else self.damage.messages_before
        with open(self.path, "rb") as stream:
            try:
                if self._indexed:
                    reader = SeekingReader(stream, validate_crcs=True,
                                           record_size_limit=RECORD_SIZE_LIMIT_BYTES)
                    items = reader.iter_messages(log_time_order=True)
                else:
                    # A camnet recorder writes in log-time order, so file order is log-time order.
                    items = _stream_messages(stream)
                for schema, channel, message in items:
                    if limit is not None and count >= limit:
                        return
                    yield SessionMessage(channel.topic, channel.message_encoding,
                                         schema.name if schema is not None else "",
                                         message.log_time, message.publish_time, message.data)
                    count += 1
            except DAMAGE_ERRORS as exc:
                if self.damage is None:
                    self.damage = Damage(_reason(exc), count)
                    log.warning("%s", self.damage.describe(self.path))


def _stream_messages(stream):
    """(schema, channel, message) in file order from mcap's StreamReader (no summary needed)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    reader = StreamReader(stream, validate_crcs=True, record_size_limit=RECORD_SIZE_LIMIT_BYTES)
    for record in reader.records:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels[record.channel_id]
            yield schemas.get(channel.schema_id), channel, record


def _parse_frame_topic(topic: str) -> tuple[str, str] | None:
    try:
        return keys.parse_frame(topic)
    except InputError:
        return None


def _reason(exc: BaseException) -> str:
    if isinstance(exc, EndOfFile | struct.error):
        return "the file ends in the middle of a record: truncated"
    text = str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {text}"


def open_session_file(path: str | Path) -> SessionFile:
    """Open a recorded session for reading; InputError if it cannot be replayed at all.

    With a valid summary (a recorder that finished), the channels come from it
    and messages are read through the chunk index. Without (killed recorder,
    truncated or changed bytes), the file is scanned once with mcap's stream
    reader to find its channels and where the damage starts.
    """
    path = Path(path)
    try:
        with open(path, "rb") as stream:
            head = stream.read(len(MCAP0_MAGIC))
            if head != MCAP0_MAGIC:
                raise InputError(f"{path}: not an MCAP file (starts with {head[:8]!r})")
            session = _from_summary(path, stream) or _from_scan(path, stream)
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if not session.frame_topics():
        if session.damage is not None and not session.topics:
            raise InputError(f"{path}: damaged before its first message ({session.damage.reason}); "
                             "nothing to replay")
        found = ", ".join(sorted(session.topics)[:5]) or "none"
        raise InputError(f"{path}: no camnet frame channels (camnet/<rig>/cam/<id>/frame) in this "
                         f"MCAP file; channels: {found}")
    if len(session.rigs) > 1:
        raise InputError(f"{path}: frames of several rigs ({', '.join(session.rigs)}); "
                         "a session holds one rig")
    if session.damage is not None:
        log.warning("%s", session.damage.describe(path))
    return session


def _from_summary(path: Path, stream) -> SessionFile | None:
    """The session from the file's summary section, or None if it has no valid one."""
    if not _summary_crc_ok(stream):
        return None
    stream.seek(0)
    try:
        summary = SeekingReader(stream, validate_crcs=True,
                                record_size_limit=RECORD_SIZE_LIMIT_BYTES).get_summary()
    except DAMAGE_ERRORS:
        return None
    if summary is None or not summary.chunk_indexes or summary.statistics is None:
        return None
    topics = {}
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        topics[channel.topic] = (channel.message_encoding, schema.name if schema else "")
    counts = {summary.channels[cid].topic: n
              for cid, n in summary.statistics.channel_message_counts.items()
              if cid in summary.channels}
    return SessionFile(path, topics, counts, _indexed=True)


def _summary_crc_ok(stream) -> bool:
    """True if the footer is present and its CRC matches the summary section (MCAP spec)."""
    stream.seek(0, io.SEEK_END)
    size = stream.tell()
    tail = _FOOTER.size + len(MCAP0_MAGIC)
    if size < len(MCAP0_MAGIC) + tail:
        return False
    stream.seek(size - tail)
    footer = stream.read(tail)
    opcode, length, summary_start, _offset_start, crc = _FOOTER.unpack_from(footer)
    if opcode != Opcode.FOOTER or length != 20 or footer[_FOOTER.size:] != MCAP0_MAGIC:
        return False
    if not len(MCAP0_MAGIC) <= summary_start < size - tail or crc == 0:
        return False
    stream.seek(summary_start)
    covered = stream.read(size - tail - summary_start) + footer[:_FOOTER.size - 4]
    return zlib.crc32(covered) == crc


def _from_scan(path: Path, stream) -> SessionFile:
    """The session from one pass of the stream reader, noting where damage starts."""
    stream.seek(0)
    topics: dict[str, tuple[str, str]] = {}
    counts: dict[str, int] = {}
    total = 0
    damage = None
    try:
        for schema, channel, _message in _stream_messages(stream):
            topics.setdefault(channel.topic, (channel.message_encoding,
                                              schema.name if schema is not None else ""))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            total += 1
    except DAMAGE_ERRORS as exc:
        damage = Damage(_reason(exc), total)
    return SessionFile(path, topics, counts, damage)
