"""The recorder node: everything under a rig's prefix into one MCAP session file.

Zenoh callbacks only stamp each sample with its receive time and append it to
a queue bounded in bytes (a full queue refuses the sample and counts it);
the node's own thread decodes frame headers, tracks sequence numbers, and
writes. Receive times are taken under the queue's lock and never go back, so
the file is written in log-time order.

Every frame is accounted for: per camera, frames written plus the missing
ones reported on the gaps channel equal the span of sequence numbers seen
(a driver restart starts a new span and is reported too). Chunks are flushed
at least every `flush_period_s`, so a recorder killed outright leaves a file
that mcap's stream reader (and `camnet.io.session_file`) reads up to the last
flush; a stopped recorder (SIGTERM, Ctrl-C, duration) writes the summary and
footer, on time: what is still queued is written for at most `stop_grace_s`,
the rest dropped and counted. Missing frames are told in one warning a
period, with their likely causes (`camnet.services.recording_gaps`).
Calibrations are written only from the rig's calibrator (published, or its
answer at start: `camnet.bus.source.CalibratorSources`); those of any other
publisher are counted and not written. Layout: docs/session-format.md.
"""

from __future__ import annotations

import contextlib
import enum
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from camnet.services.recording_gaps import ByteBoundedQueue, GapTracker, QueueItem
from mcap.writer import CompressionType, Writer

from camnet import __version__
from camnet.bus import keys
from camnet.bus.frame import FrameError, FrameHeader
from camnet.bus.node import Presence, Tally, guarded, stop_on_signals
from camnet.bus.source import FOREIGN_CALIBRATIONS, CalibratorSources, reply_source, sample_source
from camnet.bus.stats import Activity, RateMeter
from camnet.errors import CamnetError, InputError
from camnet.io import session_file as sf
from camnet.io.validate import decode_json

log = logging.getLogger(__name__)

NODE_KIND = "recorder"


class ChunkCompression(enum.StrEnum):
    """How the file's chunks are compressed (mcap's names)."""

    LZ4 = "lz4"
    # Level 3 in mcap: files of noisy frames smaller than lz4's, but too slow for a rig's frames on a small
    # host (docs/benchmarks.md, "Bus, recording, Rerun"; "Evidence behind the nodes' choices").
    ZSTD = "zstd"
    NONE = "none"


@dataclass(frozen=True)
class RecorderConfig:
    """What to record where; `duration_s` 0 records until stopped."""

    rig: str
    path: Path
    duration_s: float = 0.0
    compression: ChunkCompression = ChunkCompression.LZ4
    chunk_size_bytes: int = 4 << 20
    flush_period_s: float = 1.0
    queue_capacity_bytes: int = 512 << 20
    node_id: str = "recorder"
    stats_period_s: float = 1.0
    overwrite: bool = False
    stop_grace_s: float = 1.0  # on stopping, write what is queued for at most this long, then drop the rest
    report_period_s: float = 5.0  # at most one line on missing frames per period
    stall_s: float = 2.0  # a camera silent this long has stalled

    def __post_init__(self) -> None:
        keys.validate_id(self.rig, what="rig")
        keys.validate_id(self.node_id, what="node id")
        if not isinstance(self.compression, ChunkCompression):
            raise InputError(f"compression: expected a ChunkCompression, got {self.compression!r}")
        if not self.duration_s >= 0:
            raise InputError(f"duration_s: must be >= 0, got {self.duration_s}")
        for name in ("flush_period_s", "stats_period_s", "report_period_s", "stall_s"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name}: must be > 0, got {getattr(self, name)}")
        if not self.stop_grace_s >= 0:
            raise InputError(f"stop_grace_s: must be >= 0, got {self.stop_grace_s}")
        if self.chunk_size_bytes < 1 or self.queue_capacity_bytes < 1:
            raise InputError("chunk size and queue capacity must be positive")


@dataclass(frozen=True)
class CameraTally:
    """One camera's frames in the file: written, missing from the sequence, restarts, bytes."""

    frames: int = 0
    missing: int = 0
    gaps: int = 0
    restarts: int = 0
    payload_bytes: int = 0
    first_seq: int = -1
    last_seq: int = -1
    dropped_by_recorder: int = 0


@dataclass(frozen=True)
class RecordingSummary:
    path: Path
    duration_s: float
    messages: int
    file_bytes: int
    cameras: dict[str, CameraTally]
    queue_overflows: int
    malformed: dict[str, int]
    unwritten_at_stop: int = 0  # received, still queued when the recording stopped, not written
    foreign_calibrations: int = 0  # from another publisher than the rig's calibrator, not written

    def lines(self) -> list[str]:
        """A table of the recording, for the command's summary."""
        rows = [f"{'camera':<16}{'frames':>8}{'missing':>9}{'gaps':>6}{'restarts':>9}{'MB':>9}"]
        for camera_id, t in sorted(self.cameras.items()):
            rows.append(f"{camera_id:<16}{t.frames:>8}{t.missing:>9}{t.gaps:>6}{t.restarts:>9}"
                        f"{t.payload_bytes / 1e6:>9.1f}")
        rows.append(f"{self.messages} messages in {self.duration_s:.1f} s; file {self.file_bytes / 1e6:.1f} MB"
                    f" ({self.path}); queue overflows {self.queue_overflows}")
        if self.unwritten_at_stop:
            rows.append(f"not written: {self.unwritten_at_stop} message(s) still queued at the stop (the recorder "
                        "was behind: this machine cannot keep up with writing)")
        if self.foreign_calibrations:
            rows.append(f"calibrations from another publisher than the rig's calibrator (not written): "
                        f"{self.foreign_calibrations}")
        if self.malformed:
            rows.append("malformed (not written): " + ", ".join(
                f"{kind} {n}" for kind, n in sorted(self.malformed.items())))
        return rows


@dataclass
class _Channels:
    """MCAP schemas and channels registered so far, by name and topic."""

    writer: object
    schemas: dict[str, int] = field(default_factory=dict)
    channels: dict[str, int] = field(default_factory=dict)

    def channel(self, topic: str, message_encoding: str, schema_name: str) -> int:
        channel_id = self.channels.get(topic)
        if channel_id is None:
            schema_id = 0
            if schema_name:
                schema_id = self.schemas.get(schema_name, 0)
                if not schema_id:
                    if schema_name == sf.FRAME_SCHEMA:
                        encoding, data = sf.FRAME_SCHEMA_ENCODING, sf.frame_schema()
                    else:
                        encoding, data = sf.JSONSCHEMA_ENCODING, sf.JSON_SCHEMAS[schema_name]
                    schema_id = self.writer.register_schema(schema_name, encoding, data)
                    self.schemas[schema_name] = schema_id
            channel_id = self.writer.register_channel(topic, message_encoding, schema_id)
            self.channels[topic] = channel_id
        return channel_id


def channel_kind(rig: str, key: str) -> tuple[str, str]:
    """(message encoding, schema name) of the MCAP channel for bus key `key` of `rig`."""
    try:
        keys.parse_frame(key)
        return sf.FRAME_ENCODING, sf.FRAME_SCHEMA
    except InputError:
        pass
    try:
        keys.parse_features(key)
        return sf.FEATURES_ENCODING, ""
    except InputError:
        pass
    if key == keys.observations(rig):
        return sf.JSON_ENCODING, "camnet.observations/1"
    if key in (keys.calibration(rig), keys.groundtruth(rig)):
        return sf.JSON_ENCODING, "camnet.calibration/1"
    if key.endswith("/stats"):
        try:
            keys.parse_node(key.removesuffix("/stats"))
            return sf.JSON_ENCODING, "camnet.node-stats/1"
        except InputError:
            pass
    return sf.RAW_ENCODING, ""


class Recorder:
    def __init__(self, session, config: RecorderConfig) -> None:
        self.session = session
        self.config = config
        self.stop = threading.Event()
        self._queue = ByteBoundedQueue(config.queue_capacity_bytes)
        self._tallies: dict[str, CameraTally] = {}
        self.malformed = Tally(log)  # messages not recorded, by kind
        self.failures = Tally(log)  # callbacks that raised, by what and exception type
        self.foreign = Tally(log)  # calibrations from another publisher than the rig's calibrator
        self._calibrators = CalibratorSources(self.foreign)
        self._messages = 0
        self._sequence: dict[str, int] = {}
        self._gaps = GapTracker(stall_s=config.stall_s)  # missing frames since the last report, and why
        self._unwritten_at_stop = 0
        self._meter = RateMeter()
        self._started = time.monotonic()

    # -- Zenoh callbacks: stamp and queue, nothing else ------------------------------------

    def _on_sample(self, sample) -> None:
        key = str(sample.key_expr)
        if key == keys.calibration(self.config.rig):  # queued when its calibrator is known: maybe later
            payload = sample.payload.to_bytes()
            self._calibrators.admit(sample_source(sample), lambda: self._queue.put(key, payload))
            return
        self._queue.put(key, sample.payload.to_bytes())

    def _on_liveliness(self, sample) -> None:
        import zenoh

        event = "joined" if sample.kind == zenoh.SampleKind.PUT else "left"
        self._queue.put(str(sample.key_expr), b"", event)

    def _on_reply(self, reply) -> None:
        if reply.ok is None:
            return
        key, payload = str(reply.ok.key_expr), reply.ok.payload.to_bytes()
        if key == keys.calibration(self.config.rig):
            self._calibrators.admit(reply_source(reply), lambda: self._queue.put(key, payload))
            return
        self._queue.put(key, payload)

    # -- writing (the node's thread) -------------------------------------------------------

    def _write(self, channels: _Channels, item: QueueItem) -> None:
        rig = self.config.rig
        if item.event:
            encoding, schema, publish_ns = sf.JSON_ENCODING, sf.NODE_EVENT_FORMAT, item.log_time_ns
            payload = self._node_event(item)
        else:
            encoding, schema = channel_kind(rig, item.key)
            payload, publish_ns = item.payload, item.log_time_ns
            if encoding == sf.FRAME_ENCODING:
                try:
                    header = sf.frame_header(payload)
                except FrameError as exc:
                    self._count_malformed(f"frame {exc.kind}", exc, item.key)
                    return
                publish_ns = header.timestamp_ns
                self._account(channels, item, header, len(payload))
            elif encoding == sf.JSON_ENCODING and not _is_json_object(payload):
                self._count_malformed("json", "not a JSON object", item.key)
                return
            elif schema == "camnet.node-stats/1":
                self._gaps.node_stats(payload)
        self._add(channels, item.key, encoding, schema, item.log_time_ns, publish_ns, payload)

    def _add(self, channels: _Channels, topic: str, encoding: str, schema: str, log_time_ns: int,
             publish_time_ns: int, data: bytes) -> None:
        sequence = self._sequence.get(topic, 0)
        self._sequence[topic] = sequence + 1
        channels.writer.add_message(channels.channel(topic, encoding, schema), log_time=log_time_ns,
                                    data=data, publish_time=publish_time_ns,
                                    sequence=sequence & 0xFFFFFFFF)
        self._messages += 1

    def _node_event(self, item: QueueItem) -> bytes:
        doc = {"format": sf.NODE_EVENT_FORMAT, "event": item.event, "key": item.key,
               "timestamp_ns": item.log_time_ns}
        with contextlib.suppress(InputError):
            _, doc["kind"], doc["node_id"] = keys.parse_node(item.key)
        if doc.get("kind") == "driver":
            self._gaps.driver_event(doc["node_id"], item.event)
        return json.dumps(doc).encode()

    def _account(self, channels: _Channels, item: QueueItem, header: FrameHeader, size: int) -> None:
        """Count the frame; write a gap or restart message if its seq does not follow."""
        camera = header.camera_id
        tally = self._tallies.get(camera, CameraTally())
        dropped_here = self._queue.take_refused(item.key)
        gap = None
        if tally.last_seq >= 0 and header.seq != tally.last_seq + 1:
            restart = header.seq <= tally.last_seq
            missing = 0 if restart else header.seq - tally.last_seq - 1
            gap = {"format": sf.GAP_FORMAT, "camera_id": camera,
                   "kind": "restart" if restart else "gap", "last_seq": tally.last_seq,
                   "seq": header.seq, "missing": missing, "dropped_by_recorder": dropped_here,
                   "timestamp_ns": header.timestamp_ns}
            tally = replace(tally, missing=tally.missing + missing,
                            gaps=tally.gaps + (not restart), restarts=tally.restarts + restart)
            self._gaps.gap(camera, missing=missing, refused=dropped_here, restart=restart)
        self._gaps.frame(camera, item.key, item.log_time_ns)
        self._tallies[camera] = replace(
            tally, frames=tally.frames + 1, payload_bytes=tally.payload_bytes + size,
            first_seq=header.seq if tally.first_seq < 0 else tally.first_seq, last_seq=header.seq,
            dropped_by_recorder=tally.dropped_by_recorder + dropped_here)
        self._meter.tick()
        if gap is not None:
            self._add(channels, sf.gaps_topic(self.config.rig), sf.JSON_ENCODING, sf.GAP_FORMAT,
                      item.log_time_ns, header.timestamp_ns, json.dumps(gap).encode())

    def _count_malformed(self, kind: str, problem: object, key: str) -> None:
        self.malformed.count(kind, "not recording a malformed message on %s (%s: %s)", key, kind, problem)

    # -- the node --------------------------------------------------------------------------

    def summary(self) -> RecordingSummary:
        path = self.config.path
        return RecordingSummary(
            path=path, duration_s=time.monotonic() - self._started, messages=self._messages,
            file_bytes=path.stat().st_size if path.exists() else 0, cameras=dict(self._tallies),
            queue_overflows=self._queue.refused,
            malformed=self.malformed.counts, unwritten_at_stop=self._unwritten_at_stop,
            foreign_calibrations=self.foreign.counts.get(FOREIGN_CALIBRATIONS, 0))

    def _activity(self) -> Activity:
        summary = self.summary()
        frames = sum(t.frames for t in summary.cameras.values())
        missing = sum(t.missing for t in summary.cameras.values())
        return Activity(fps=round(self._meter.rate(), 2), frames=frames, dropped=summary.queue_overflows,
                        detail=f"{self.config.path.name} {summary.file_bytes / 1e6:.0f} MB, {missing} missing")

    def _open_file(self):
        path = self.config.path
        if not path.parent.is_dir():
            raise InputError(f"{path}: directory {path.parent} does not exist")
        try:
            return open(path, "wb" if self.config.overwrite else "xb")
        except FileExistsError:
            raise InputError(f"{path}: exists (pass --force to overwrite)") from None
        except OSError as exc:
            raise InputError(f"{path}: cannot write: {exc.strerror or exc}") from exc

    def _start_writer(self, stream):
        cfg = self.config
        writer = Writer(stream, chunk_size=cfg.chunk_size_bytes,
                        compression=CompressionType[cfg.compression.name])
        writer.start(profile=sf.PROFILE, library=f"camnet {__version__}")
        writer.add_metadata(sf.SESSION_METADATA, {
            "rig": cfg.rig, "camnet_version": __version__, "recorder": cfg.node_id,
            "started_ns": str(time.time_ns()), "compression": cfg.compression.value})
        stream.flush()
        return writer

    def _loop(self, channels: _Channels, presence: Presence, on_progress, progress_period_s: float) -> None:
        cfg = self.config
        self._started = now = time.monotonic()
        deadline = now + cfg.duration_s if cfg.duration_s > 0 else float("inf")
        next_flush, next_progress = now + cfg.flush_period_s, now + progress_period_s
        next_report = now + cfg.report_period_s
        while not self.stop.is_set() and time.monotonic() < deadline:
            item = self._queue.get(timeout_s=min(0.05, max(0.0, deadline - time.monotonic())))
            if item is not None:
                self._write(channels, item)
            now = time.monotonic()
            if now >= next_flush:
                channels.writer.flush()
                next_flush = now + cfg.flush_period_s
            if now >= next_report:
                self._gaps.report(self._queue)
                self._calibrators.expire(now)
                next_report = now + cfg.report_period_s
            presence.publish_if_due()
            if on_progress is not None and now >= next_progress:
                on_progress(self.summary())
                next_progress = now + progress_period_s

    def run(self, *, on_progress: Callable[[RecordingSummary], None] | None = None,
            progress_period_s: float = 1.0) -> RecordingSummary:
        """Record until stopped (stop event, SIGTERM, Ctrl-C) or `duration_s`; the summary."""
        import zenoh

        cfg = self.config
        stream = self._open_file()
        try:
            channels = _Channels(self._start_writer(stream))
        except OSError as exc:
            raise CamnetError(f"{cfg.path}: cannot write ({exc.strerror or exc})") from exc
        prefix = keys.rig_prefix(cfg.rig)
        subscriber = self.session.declare_subscriber(
            f"{prefix}/**", guarded(self._on_sample, self.failures, "receiving a message"))
        nodes = self.session.liveliness().declare_subscriber(
            keys.all_nodes(cfg.rig), guarded(self._on_liveliness, self.failures, "receiving a node event"),
            history=True)
        calibrators = self._calibrators.declare(self.session, cfg.rig, self.failures)
        # Latest values published before we subscribed (the sim driver's ground truth, the
        # calibrator's latest calibration) are only reachable by query.
        # Every answer, not Zenoh's one per key: another peer answering must not hide the calibrator's.
        for key in (keys.groundtruth(cfg.rig), keys.calibration(cfg.rig)):
            self.session.get(key, guarded(self._on_reply, self.failures, "receiving a reply"), timeout=2.0,
                             consolidation=zenoh.ConsolidationMode.NONE)
        presence = Presence(self.session, rig=cfg.rig, kind=NODE_KIND, node_id=cfg.node_id, report=self._activity,
                            tallies=(self.malformed, self.failures, self.foreign), period_s=cfg.stats_period_s,
                            status_period_s=None)  # camnet record prints its own progress
        log.info("recording %s/** to %s", prefix, cfg.path)
        error = None
        with stop_on_signals(self.stop), presence:
            try:
                self._loop(channels, presence, on_progress, progress_period_s)
            except OSError as exc:
                error = exc
            finally:
                subscriber.undeclare()
                nodes.undeclare()
                calibrators.undeclare()
                error = self._finish(channels, stream, error)
        if error is not None:
            raise CamnetError(f"{cfg.path}: cannot write ({error.strerror or error}); the file is "
                              "readable up to the last flush") from error
        return self.summary()

    def _finish(self, channels: _Channels, stream, error: OSError | None) -> OSError | None:
        """Write what is still queued, the summary and the footer (unless writing failed); close the file."""
        try:
            if error is None:
                self._write_backlog(channels)
                channels.writer.add_metadata(sf.SUMMARY_METADATA, _summary_metadata(self.summary()))
                channels.writer.finish()
            stream.close()
        except OSError as exc:
            return error or exc
        return error


    def _write_backlog(self, channels: _Channels) -> None:
        """Write what is still queued for at most `stop_grace_s`, so that the stop is on time: a
        recorder that fell behind would otherwise take as long again as its queue holds (seconds of
        frames). What is left is counted and said."""
        give_up_s = time.monotonic() + self.config.stop_grace_s
        while time.monotonic() < give_up_s and (item := self._queue.get(timeout_s=0.0)) is not None:
            self._write(channels, item)
        _, _, lag_s = self._queue.backlog()
        self._unwritten_at_stop, unwritten_bytes = self._queue.clear()
        if self._unwritten_at_stop:
            log.warning("stopping on time: %d received message(s) (%.0f MB, the last %.1f s) not written; the "
                        "recorder was behind: this machine cannot keep up with writing (try --compression none, "
                        "or a faster disk)", self._unwritten_at_stop, unwritten_bytes / 1e6, lag_s)
        self._gaps.report(self._queue)


def _summary_metadata(summary: RecordingSummary) -> dict[str, str]:
    cameras = {cid: {"frames": t.frames, "missing": t.missing, "gaps": t.gaps,
                     "restarts": t.restarts, "first_seq": t.first_seq, "last_seq": t.last_seq,
                     "dropped_by_recorder": t.dropped_by_recorder, "payload_bytes": t.payload_bytes}
               for cid, t in summary.cameras.items()}
    return {"messages": str(summary.messages), "queue_overflows": str(summary.queue_overflows),
            "unwritten_at_stop": str(summary.unwritten_at_stop),
            "foreign_calibrations": str(summary.foreign_calibrations),
            "cameras": json.dumps(cameras), "malformed": json.dumps(summary.malformed)}


def _is_json_object(payload: bytes) -> bool:
    try:
        return isinstance(decode_json(payload, "message"), dict)
    except InputError:  # whatever json cannot take, deep nesting included
        return False
