"""`camnet cameras`: the cameras this host sees, with their modes; `--preview` streams them to Rerun.

V4L2 devices are asked of the kernel (camnet.drivers.v4l2_devices), GenICam
cameras of Aravis (camnet.drivers.aravis.discover). Each camera is listed
with the id `camnet init` gives it in a rig file. A driver that is not
installed, or finds nothing, says so in its own line.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

PREVIEW_S = 60.0  # how long a preview runs unless told
PREVIEW_HZ = 5.0  # images per camera sent to Rerun: enough to frame, cheap to encode
GENICAM_FORMATS = ("Mono8", "BayerRG8", "BayerGR8", "BayerGB8", "BayerBG8", "RGB8", "BGR8", "Mono16")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from camnet.viz_sinks import add_rerun_arguments

    add_discovery_arguments(parser)
    parser.add_argument("--preview", action="store_true",
                        help="stream the cameras found to Rerun, for framing and overlap "
                             "(default sink: spawn a viewer)")
    parser.add_argument("--duration-s", type=float,
                        help=f"with --preview: stop after this many seconds (default {PREVIEW_S:g}; "
                             "Ctrl-C stops sooner)")
    add_rerun_arguments(parser)


def add_discovery_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--aravis-fake", action="store_true",
                        help="also find Aravis's in-process Fake camera (a test pattern, to try camnet "
                             "without a camera)")


@dataclass(frozen=True)
class Discovery:
    """What each driver found: the cameras, and a line per driver (how many, or why none)."""

    cameras: tuple  # camnet.drivers.base.FoundCamera, V4L2 first
    lines: tuple[str, ...]


def discover(*, aravis_fake: bool = False) -> Discovery:
    from camnet.drivers import v4l2_devices
    from camnet.drivers.base import INSTALL_HINTS

    v4l2 = v4l2_devices.discover()
    lines = [f"V4L2 devices: {len(v4l2)}" if v4l2 else "V4L2 devices: none found (no video capture "
             "device under /dev/video*)"]
    try:
        from camnet.drivers import aravis
    except (ImportError, ValueError) as exc:  # gi.require_version raises ValueError without the typelib
        genicam = []
        lines.append(f"GenICam cameras (Aravis): not available ({exc}); {INSTALL_HINTS['aravis']}")
    else:
        genicam = aravis.discover(fake=aravis_fake)
        lines.append(f"GenICam cameras (Aravis): {len(genicam)}" if genicam else
                     "GenICam cameras (Aravis): none found (GigE Vision on this host's subnets, USB3 Vision)")
    return Discovery(cameras=tuple(v4l2 + genicam), lines=tuple(lines))


def listing(found: Discovery) -> str:
    """The lines of `camnet cameras`: each driver's count, each camera with its id, device and modes."""
    out = []
    for driver, line in zip(("v4l2", "aravis"), found.lines, strict=True):
        out.append(line)
        for cam in (c for c in found.cameras if c.driver == driver):
            out.append(f"  {cam.suggested_id:<20} {cam.description}")
            settings = ", ".join(f"{key}: {str(value).lower() if isinstance(value, bool) else value}"
                                 for key, value in rig_section(cam).items())
            out.append(f"      rig file: driver {cam.driver}, {settings}")
            out += [f"      {mode}" for mode in cam.modes]
            if cam.problem:
                out.append(f"      problem: {cam.problem}")
    return "\n".join(out)


def rig_section(cam) -> dict:
    """The driver section of a rig file's entry for a found camera."""
    if cam.driver == "v4l2":
        return {"source": cam.device}
    formats = [name for name in GENICAM_FORMATS if name in cam.pixel_formats]
    section = {"device_id": cam.device, "pixel_format": formats[0] if formats else "Mono8"}
    if cam.fake:
        section["enable_fake_interface"] = True
    return section


def rig_document(name: str, cameras, stereo: dict | None = None) -> dict:
    """A rig file's document (camnet.io.rig) for found `cameras`, with `stereo` when given."""
    doc: dict = {"rig": name}
    if stereo is not None:
        doc["stereo"] = stereo
    doc["cameras"] = [{"id": c.suggested_id, "driver": c.driver, c.driver: rig_section(c)} for c in cameras]
    return doc


def run(args: argparse.Namespace) -> int:
    from camnet.errors import InputError
    from camnet.viz_sinks import parse_sink, sinks_from_args

    for flag, given in (("--duration-s", args.duration_s is not None), ("--rerun", bool(args.rerun))):
        if given and not args.preview:
            raise InputError(f"{flag}: only with --preview")
    duration_s = PREVIEW_S if args.duration_s is None else args.duration_s
    if not duration_s > 0:
        raise InputError(f"--duration-s: must be positive, got {duration_s}")
    sinks = sinks_from_args(args)
    found = discover(aravis_fake=args.aravis_fake)
    print(listing(found), flush=True)
    if not args.preview:
        if found.cameras:
            print("next: camnet cameras --preview (framing and overlap in Rerun); "
                  "camnet init -o rig.yaml (a rig file of these cameras)")
        return 0
    usable = [c for c in found.cameras if c.problem is None]
    if not usable:
        raise InputError("--preview: no camera to preview; check that each is powered and connected, and for "
                         "GigE that it is on this host's subnet")
    return preview(usable, sinks or (parse_sink("spawn"),), duration_s=duration_s)


def preview(cameras, sinks, *, duration_s: float) -> int:
    """Stream `cameras` to Rerun at `PREVIEW_HZ` each until `duration_s` or Ctrl-C; 1 if one could not stream.

    Each camera is opened, read and closed in a thread of its own (Aravis
    wants every call of a camera from one thread). A camera that fails is
    named with why, every one of them, and the others go on.
    """
    import threading
    import time

    from camnet.bus.node import stop_on_signals
    from camnet.io.rig import parse_rig
    from camnet.viz import close_recording, open_recording

    rig = parse_rig(rig_document("preview", cameras), source="the cameras found")
    rec = open_recording(rig="preview", sinks=sinks)
    for sink in sinks:
        print(f"preview: {sink.describe()}", flush=True)
    workers = [PreviewWorker(entry, rig, rec) for entry in rig.cameras]
    with stop_on_signals(threading.Event()) as stop:
        threads = [threading.Thread(target=w.run, args=(stop,), name=f"preview-{w.entry.id}") for w in workers]
        for thread in threads:
            thread.start()
        deadline = time.monotonic() + duration_s
        while time.monotonic() < deadline and not stop.is_set() and any(t.is_alive() for t in threads):
            stop.wait(0.2)
        stop.set()
        for thread in threads:
            thread.join()
    close_recording(rec)
    for w in workers:
        print(f"preview: {w.entry.id}: {w.shown} images shown of {w.read} frames read", flush=True)
    failed = [w for w in workers if w.problem is not None]
    for w in failed:
        print(f"camnet cameras: error: {w.problem}", file=sys.stderr, flush=True)
    return 1 if failed else 0


class PreviewWorker:
    """One camera's preview: read every frame, send one per 1 / `PREVIEW_HZ` s to Rerun."""

    def __init__(self, entry, rig, rec) -> None:
        self.entry, self.rig, self.rec = entry, rig, rec
        self.read = self.shown = 0
        self.problem: str | None = None

    def run(self, stop) -> None:
        import time

        from camnet.drivers.base import DeviceError, EndOfStream, ReadTimeout, create_camera
        from camnet.viz import log_frame

        next_mono = 0.0
        try:
            with create_camera(self.entry, self.rig) as camera:
                while not stop.is_set():
                    try:
                        frame = camera.read(timeout_s=0.5)
                    except ReadTimeout:
                        continue
                    self.read += 1
                    if time.monotonic() >= next_mono:
                        next_mono = time.monotonic() + 1.0 / PREVIEW_HZ
                        log_frame(self.rec, self.entry.id, frame.image, time_ns=frame.timestamp_ns,
                                  encoding=frame.encoding)
                        self.shown += 1
                        if self.shown == 1:  # opening a camera can take seconds: say when it streams
                            print(f"preview: streaming {self.entry.id}", flush=True)
        except EndOfStream:
            return
        except DeviceError as exc:
            self.problem = str(exc)
