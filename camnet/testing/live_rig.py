"""A rig's nodes started as processes on the bus and run until they calibrate every camera, for tests and
benchmarks that measure the live chain end to end (`camnet up` is the user's way to run a rig)."""

from __future__ import annotations

from pathlib import Path


def _decoded(decode, sample, log):
    """`decode` of a bus `sample`'s payload; None, logged, where it does not decode."""
    from camnet.io.messages import MessageError

    try:
        return decode(sample.payload.to_bytes())
    except MessageError as exc:
        log.warning("ignoring a message on %s that does not decode (%s)", sample.key_expr, exc)
        return None


def calibrate_live(rig_path: str | Path, *, run_dir: Path, endpoint: str, max_tracks: int = 3000,
                   min_frame_sets: int = 4, timeout_s: float = 120.0):
    """The rig's drivers, matcher and calibrator as processes on the bus, until they calibrate every camera.

    The nodes connect to `endpoint` (tcp on loopback), where this process
    listens; their logs go to `run_dir`, and the calibrator keeps no state.
    The calibrator holds the stereo pair's pose when the rig file gives it
    (a factory head, as in config/kitti.yaml); the matcher pools at most
    `max_tracks` tracks. Returns (Calibration, Observations, seconds): the
    first calibration of every camera in the rig from at least
    `min_frame_sets` pooled frame sets, the observations it was solved from,
    and the seconds since the nodes started. Raises CamnetError when a node
    exits or nothing comes within `timeout_s`.
    """
    import logging
    import threading
    import time

    from camnet.bus import keys
    from camnet.bus.launch import Launch, NetworkSpec, start_network
    from camnet.bus.session import BusOptions, open_session
    from camnet.errors import CamnetError
    from camnet.io.messages import decode_calibration_message, decode_observations_message
    from camnet.io.rig import load_rig
    from camnet.io.run_dir import source_key

    log = logging.getLogger(__name__)
    rig = load_rig(rig_path)
    run_dir.mkdir(parents=True, exist_ok=True)
    observed = {}  # observations messages by source_key
    calibrations = []  # calibration messages not looked at yet
    lock = threading.Lock()
    arrived = threading.Event()

    # Any peer may publish on these keys: only what decodes is kept.
    def on_observations(sample) -> None:
        message = _decoded(decode_observations_message, sample, log)
        if message is not None and message.frame_sets is not None and message.latest_capture_ns is not None:
            with lock:
                observed[source_key(message)] = message

    def on_calibration(sample) -> None:
        message = _decoded(decode_calibration_message, sample, log)
        if message is not None:
            with lock:
                calibrations.append(message)
            arrived.set()

    spec = NetworkSpec(rig_path=Path(rig_path), rig_name=rig.name,
                       cameras=tuple((e.id, e.driver) for e in rig.cameras), bus=("--connect", endpoint),
                       matcher=("--max-tracks", str(max_tracks)), calibrator=("--no-state",))
    want = {entry.id for entry in rig.cameras}
    with open_session(BusOptions(listen=(endpoint,))) as session, Launch(run_dir) as launch:
        session.declare_subscriber(keys.observations(rig.name), on_observations)
        session.declare_subscriber(keys.calibration(rig.name), on_calibration)
        start_network(launch, spec)
        start_s = time.monotonic()
        while time.monotonic() - start_s < timeout_s:
            launch.check()
            if not arrived.wait(timeout=0.5):
                continue
            arrived.clear()
            with lock:
                pending = calibrations[:]
                calibrations.clear()
            for message in pending:
                cameras = {c.id for c in message.calibration.cameras}
                log.info("calibration %s: cameras %s, %s frame sets, %.1f s", message.solve,
                         ",".join(sorted(cameras)), message.frame_sets, time.monotonic() - start_s)
                with lock:
                    source = observed.get(source_key(message))
                if cameras == want and (message.frame_sets or 0) >= min_frame_sets and source is not None:
                    return message.calibration, source.observations, time.monotonic() - start_s
    raise CamnetError(f"no calibration of cameras {sorted(want)} from {min_frame_sets} frame sets in "
                      f"{timeout_s:.0f} s; the nodes' logs are in {run_dir}")
