"""A live calibration in Rerun: plain functions on an explicit `rerun.RecordingStream`.

The calibrator opens a recording with `open_recording` (sinks from the
repeatable ``--rerun`` flag: `camnet.viz_sinks`), calls
`log_calibration` after every solve (`log_solve_failure` when a solve fails),
`log_frame` for the images it shows (at most every `FRAME_PERIOD_S` per
camera, `FrameSchedule`), and `close_recording` when it stops. With
no sink the recording is None, every function does nothing and Rerun is not
even imported. Visualization is a sidecar: a failure to log is warned about
once per kind and never raised into the caller.

Entity layout (application id ``camnet``, recording name = the rig)::

    world                                   view coordinates: RDF in the left stereo camera's frame; Z up
                                            (RIGHT_HAND_Z_UP) where the calibration has a floor frame
    world/floor                             with a floor frame only: LineStrips3D, a grid on the floor (z = 0)
    world/cameras/<id>                      Transform3D world_from_cam + Pinhole (K, resolution, RDF)
    world/cameras/<id>/image                the latest image (JPEG), not logged at every solve
    world/cameras/<id>/image/observations   Points2D: the camera's track observations, coloured
                                            by reprojection error; grey: tracks the solve rejected
    world/points                            Points3D: the cloud, coloured by reprojection error
    series/network/rms_px                   reprojection RMS of the whole network
    series/network/points                   number of points
    series/network/scale_sigma_pct          1-sigma relative scale uncertainty, %
    series/rms_px/<id>                      reprojection RMS per camera
    series/sigma_f_px/<id>                  1-sigma of the focal length, px
    series/sigma_centre_mm/<id>             1-sigma of the camera centre (norm over axes), mm
    series/network/scale_error_pct          with ground truth only: scale error, %
    series/focal_error_pct/<id>             with ground truth only: focal length error, %
    series/centre_error_mm/<id>             with ground truth only: camera centre error, mm
    log                                     TextLog: one line per solve, solver warnings, failures

Sites placed in one space (`camnet fuse`, `log_meeting`) are logged once, Z up, under
``world/sites/<name>/cameras/<id>`` and ``world/sites/<name>/points``, over one ``world/floor``.

Cameras and points are logged in the frame the calibration is written in
(`camnet.model.calibration.in_world_frame`): the floor's where it has one,
so that the cameras stand upright over the floor, the left camera's if not.

Timelines: ``capture_time`` (timestamp of the newest frame set a solve
includes, or of the frame) and ``solve`` (solve sequence number from 0,
counted per recording; frames carry the number of the latest solve).

Conventions: Rerun puts pixel (0, 0)'s corner at the image origin, camnet
(like OpenCV) puts its centre there, so pixels and principal points are
shifted by +0.5 px on the way to Rerun. Colours map the reprojection error
linearly onto OpenCV's turbo colormap over `ERROR_RANGE_PX` (0 px blue,
2 px and above dark red).
"""

from __future__ import annotations

import functools
import logging
import os
import socket
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from camnet.errors import CamnetError
from camnet.model.calibration import FLOOR_FRAME, Calibration, WorldPosed, in_world_frame
from camnet.model.camera import Camera
from camnet.model.observations import Observations
from camnet.viz_sinks import RerunSink

if TYPE_CHECKING:
    import rerun as rr

    from camnet.io.meeting import Meeting

log = logging.getLogger(__name__)

APPLICATION_ID = "camnet"
CAPTURE_TIMELINE = "capture_time"
SOLVE_TIMELINE = "solve"
ERROR_RANGE_PX = (0.0, 2.0)
REJECTED_RGB = (128, 128, 128)
JPEG_QUALITY = 80
OPEN_TIMEOUT_S = 5.0
# What `--rerun serve` keeps for viewers that connect later; static data is kept beyond it. Rerun's default
# of 1 GiB lets a calibrator grow with every solve for hours at a few solves a minute (docs/benchmarks.md,
# "Sixteen cameras across hosts"). A viewer that connects gets the latest solves, then the live stream.
SERVE_MEMORY_LIMIT = "16MiB"
# A recording that is only saved is read after the run: its log calls are batched for this long (or this
# many bytes), so that a solve's few dozen small calls (one chunk each per entity, each chunk framed with
# its own schema, about 1.3 kB) share their framing with the solves beside them: at Rerun's default of
# 200 ms the framing outweighs a small solve's data (docs/benchmarks.md, "Bus, recording, Rerun"). A viewer
# (spawn, connect, serve) keeps that default: it sees each solve as it comes. `close_recording` writes what
# is held.
SAVE_FLUSH_S = 30.0
SAVE_FLUSH_BYTES = 16 * 2**20
# A camera's latest frame is logged with a solve at most this often (capture time). Logged at every solve, the
# frames' JPEGs are most of a saved recording (docs/benchmarks.md, "Bus, recording, Rerun"), though a static
# camera's frame barely changes. The viewer draws a solve's observations over the camera's latest image at the
# time cursor, an older one included.
FRAME_PERIOD_S = 10.0

# Solves counted per recording; weak keys so a dropped recording leaves nothing behind.
_solve_counts: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# Whether a recording's world is the floor frame (Z up, a floor drawn): the view coordinates are static, so they are
# logged again only when this changes.
_on_floor: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_warned: set[tuple[str, str]] = set()


# ---------------------------------------------------------------- recording


def open_recording(
    *, rig: str, sinks: Sequence[RerunSink], recording_id: str | None = None
) -> rr.RecordingStream | None:
    """A recording streaming to `sinks`, or None (and Rerun not imported) when there are none.

    Raises CamnetError when a sink cannot be opened (a port in use, no viewer
    to spawn or connect to): better to fail at start than to run unseen. The
    sinks' descriptions (`RerunSink.describe`, with the web viewer's URL) are
    logged at INFO; a command may print them. Rerun cannot stop the web viewer's
    HTTP server: it lives as long as the process.
    """
    if not sinks:
        return None
    # Rerun's allocator (mimalloc) with its default purge delay keeps much of what each solve's logging
    # frees, and a served process grows (docs/benchmarks.md, "Sixteen cameras across hosts"). Read once, as
    # Rerun loads; an operator's setting stands.
    os.environ.setdefault("MIMALLOC_PURGE_DELAY", "0")
    import rerun as rr

    saved_only = all(sink.kind == "save" for sink in sinks)
    batching = rr.ChunkBatcherConfig(flush_tick=SAVE_FLUSH_S, flush_num_bytes=SAVE_FLUSH_BYTES) if saved_only else None
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id, batcher_config=batching)
    targets: list[Any] = []
    try:
        for sink in sinks:
            if sink.kind == "save":
                targets.append(rr.FileSink(sink.path))
            elif sink.kind == "connect":
                targets.append(rr.GrpcSink(sink.url))
            elif sink.kind == "spawn":
                rr.spawn(port=sink.grpc_port, connect=False, recording=rec)
                targets.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{sink.grpc_port}/proxy"))
            else:
                # The page is served from the rig's host name: let it reach the gRPC server from there.
                server = rr.GrpcServerSink(port=sink.grpc_port, cors_allow_origin=[f"http://*:{sink.web_port}"],
                                           server_memory_limit=SERVE_MEMORY_LIMIT)
                targets.append(server)
        rec.set_sinks(*targets)
        # A gRPC server that cannot bind, or a viewer that cannot be reached, shows only here.
        rec.flush(timeout_sec=OPEN_TIMEOUT_S)
        for sink in sinks:
            if sink.kind == "serve":
                rr.serve_web_viewer(web_port=sink.web_port, open_browser=False)
    except Exception as exc:  # Rerun raises plain RuntimeError/ValueError for bind, connect and spawn failures
        rec.disconnect()
        raise CamnetError(f"--rerun {' '.join(s.kind for s in sinks)}: cannot open: {exc}") from exc
    rec.send_recording_name(rig)
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    _solve_counts[rec] = -1
    for sink in sinks:
        log.info(sink.describe(host=socket.gethostname()))
    return rec


def close_recording(rec: rr.RecordingStream | None, *, timeout_s: float = 10.0) -> None:
    """Flush and disconnect every sink: a saved .rrd is complete afterwards. None is a no-op."""
    if rec is None:
        return
    try:
        rec.flush(timeout_sec=timeout_s)
    except Exception as exc:
        log.warning("Rerun: flush failed, the recording may be incomplete: %s", exc)
    rec.disconnect()


def _sidecar(fn):
    """Make a logging function a no-op on a None recording and never raise into the caller."""

    @functools.wraps(fn)
    def wrapper(rec, *args, **kwargs):
        if rec is None:
            return
        try:
            fn(rec, *args, **kwargs)
        except Exception as exc:
            key = (fn.__name__, type(exc).__name__)
            if key in _warned:
                log.debug("Rerun: %s failed again: %s", fn.__name__, exc)
            else:
                _warned.add(key)
                log.warning("Rerun: %s failed (%s); visualization goes on without it", fn.__name__, exc)

    return wrapper


def _set_times(rec: rr.RecordingStream, *, time_ns: int, solve_index: int) -> None:
    rec.set_time(CAPTURE_TIMELINE, timestamp=np.datetime64(int(time_ns), "ns"))
    rec.set_time(SOLVE_TIMELINE, sequence=max(solve_index, 0))


def _next_solve(rec: rr.RecordingStream, given: int | None = None) -> int:
    index = _solve_counts.get(rec, -1) + 1 if given is None else given
    _solve_counts[rec] = index
    return index


def _entity(*parts: str) -> str:
    import rerun as rr

    return "/".join(rr.escape_entity_path_part(p) for p in parts)


# ---------------------------------------------------------------- geometry to colours


def error_colors(error_px: np.ndarray) -> np.ndarray:
    """RGB uint8 (n, 3) of reprojection errors (n,) px over `ERROR_RANGE_PX`; NaN is grey."""
    import cv2

    lo, hi = ERROR_RANGE_PX
    error_px = np.asarray(error_px, dtype=float)
    level = np.clip((np.nan_to_num(error_px, nan=lo) - lo) / (hi - lo), 0.0, 1.0)
    bgr = cv2.applyColorMap(np.round(255 * level).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_TURBO)
    rgb = np.ascontiguousarray(bgr[:, 0, ::-1])
    rgb[np.isnan(error_px)] = REJECTED_RGB
    return rgb


@dataclass(frozen=True)
class ReprojectionErrors:
    """What the colours show: obs_error_px (n,) per observation, NaN for tracks the
    calibration rejected; point_rms_px (N,) RMS over each point's views, NaN for a
    point no observation sees."""

    obs_error_px: np.ndarray
    point_rms_px: np.ndarray


def reprojection_errors(calibration: Calibration, observations: Observations) -> ReprojectionErrors:
    """Per observation and per point, from `camnet.solve.report.reprojection.reprojection_residuals` (pixels)."""
    from camnet.solve.report.reprojection import reprojection_residuals

    residuals = reprojection_residuals(calibration, observations)
    obs_error = np.full(len(observations.uv), np.nan)
    obs_error[residuals.obs_row] = residuals.error_px
    n_points = len(calibration.points)
    sq = np.bincount(residuals.point_index, weights=residuals.error_px**2, minlength=n_points)
    count = np.bincount(residuals.point_index, minlength=n_points)
    with np.errstate(invalid="ignore", divide="ignore"):
        return ReprojectionErrors(obs_error, np.sqrt(sq / count))


def _degenerate(calibration: Calibration) -> str:
    """Why `calibration` cannot be shown, or "" when it can."""
    if not calibration.cameras:
        return "no cameras"
    for cam in calibration.cameras:
        if not all(np.all(np.isfinite(a)) for a in (cam.K, cam.R, cam.t)) or cam.K[0, 0] <= 0:
            return f"camera {cam.id!r} has a non-finite or non-positive K, R or t"
    if calibration.points.size and not np.all(np.isfinite(calibration.points)):
        return "non-finite points"
    return ""


def shown(calibration: Calibration) -> tuple[WorldPosed, rr.ViewCoordinates]:
    """The cameras and points of `calibration` as the recording shows them, and the view coordinates of ``world``:
    in the floor frame, Z up, where it has one; in the left camera's frame, RDF, where not."""
    import rerun as rr

    view = rr.ViewCoordinates.RDF if calibration.floor_frame is None else rr.ViewCoordinates.RIGHT_HAND_Z_UP
    return in_world_frame(calibration), view


def floor_grid(xy_m: np.ndarray, *, lines: int = 10) -> np.ndarray:
    """(L, 2, 3) line segments (metres) of a grid on the floor z = 0 covering the horizontal positions xy_m (n, 2)
    with a margin; its step a power of ten times 1, 2 or 5 giving about `lines` lines across the wider side."""
    xy_m = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    lo, hi = xy_m.min(axis=0), xy_m.max(axis=0)
    span = max(float(np.max(hi - lo)), 0.1)
    raw = span / lines
    step = min((m * 10.0 ** np.floor(np.log10(raw)) for m in (1.0, 2.0, 5.0, 10.0)), key=lambda s: abs(s - raw))
    lo, hi = np.floor((lo - step) / step) * step, np.ceil((hi + step) / step) * step
    xs, ys = np.arange(lo[0], hi[0] + step / 2, step), np.arange(lo[1], hi[1] + step / 2, step)
    along_y = [[[x, lo[1], 0.0], [x, hi[1], 0.0]] for x in xs]
    along_x = [[[lo[0], y, 0.0], [hi[0], y, 0.0]] for y in ys]
    return np.array(along_y + along_x)


# ---------------------------------------------------------------- logging


@_sidecar
def log_calibration(
    rec: rr.RecordingStream | None,
    calibration: Calibration,
    *,
    time_ns: int,
    observations: Observations | None = None,
    truth: Calibration | Sequence[Camera] | None = None,
    solve_index: int | None = None,
) -> None:
    """Log one solve: cameras, cloud, observations on the images, time series.

    time_ns: capture timestamp (ns since the epoch) of the newest frame set the
    solve includes. observations: what the solve was given; without them the
    cloud is white and no 2-D points are logged. truth: ground truth, as a
    Calibration (points by track id) or as cameras alone (then the scale error
    is that of the camera centres); adds the error series. A degenerate
    calibration is logged as an error line in ``log``, not as cameras.
    solve_index: the solve's number on the solve timeline, as its producer
    counts it (the calibrator's `solve`); by default, one more than the last.
    """
    import rerun as rr

    solve_index = _next_solve(rec, solve_index)
    _set_times(rec, time_ns=time_ns, solve_index=solve_index)
    problem = _degenerate(calibration)
    if problem:
        rec.log("log", rr.TextLog(f"solve {solve_index}: degenerate calibration, not shown: {problem}",
                                  level=rr.TextLogLevel.ERROR))
        return
    errors = reprojection_errors(calibration, observations) if observations is not None else None
    posed, view = shown(calibration)
    _log_world(rec, posed, view)
    _log_cameras(rec, posed)
    colors = error_colors(errors.point_rms_px) if errors is not None else None
    rec.log("world/points", rr.Points3D(posed.points, colors=colors, radii=rr.Radius.ui_points(2.5)))
    if errors is not None:
        _log_observations(rec, observations, errors)
    _log_series(rec, calibration, truth)
    _log_text(rec, calibration, solve_index)


def _log_world(rec: rr.RecordingStream, posed: WorldPosed, view: rr.ViewCoordinates) -> None:
    """The view coordinates where the world's frame changed since the last solve; with a floor, the floor."""
    import rerun as rr

    on_floor = posed.frame == FLOOR_FRAME
    if _on_floor.get(rec, False) != on_floor:
        rec.log("world", view, static=True)
        if not on_floor:
            rec.log("world/floor", rr.Clear(recursive=False))
        _on_floor[rec] = on_floor
    if on_floor:
        # The body of the cloud: a far point (no parallax, a false match) would stretch the floor to it.
        body = np.percentile(posed.points, (1.0, 99.0), axis=0) if len(posed.points) else np.empty((0, 3))
        xy = np.vstack([np.array([c.centre for c in posed.cameras]), body])[:, :2]
        rec.log("world/floor", rr.LineStrips3D(floor_grid(xy), colors=[(110, 110, 110)],
                                               radii=rr.Radius.ui_points(0.75)))


def log_meeting(rec: rr.RecordingStream | None, meeting: Meeting) -> None:
    """Log sites placed in one space (camnet.io.meeting), Z up over one floor grid: ``world/sites/<name>/cameras/
    <id>`` and ``world/sites/<name>/points`` in the meeting frame. Unlike a live rig's logging, it raises: the
    recording is what was asked for. None: nothing to do."""
    if rec is None:
        return
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    xy = []
    for site in meeting.sites:
        cameras, points = site.cameras(), site.points()
        _log_cameras(rec, WorldPosed(FLOOR_FRAME, cameras, points), root=("world", "sites", site.name))
        rec.log(_entity("world", "sites", site.name, "points"), rr.Points3D(points, radii=rr.Radius.ui_points(2.5)))
        body = np.percentile(points, (1.0, 99.0), axis=0) if len(points) else np.empty((0, 3))
        xy.append(np.vstack([np.array([c.centre for c in cameras]), body])[:, :2])
    rec.log("world/floor", rr.LineStrips3D(floor_grid(np.vstack(xy)), colors=[(110, 110, 110)],
                                           radii=rr.Radius.ui_points(0.75)))


def _log_cameras(rec: rr.RecordingStream, posed: WorldPosed, *, root: tuple[str, ...] = ("world",)) -> None:
    import rerun as rr

    plane_m = None
    if len(posed.points):
        depth = posed.points @ posed.cameras[0].R[2] + posed.cameras[0].t[2]
        plane_m = 0.15 * float(np.median(np.abs(depth)))
    for cam in posed.cameras:
        K = np.array(cam.K, dtype=float)
        K[:2, 2] += 0.5  # pixel centre to pixel corner origin
        rec.log(
            _entity(*root, "cameras", cam.id),
            rr.Transform3D(translation=cam.centre, mat3x3=cam.R.T),  # world_from_cam
            rr.Pinhole(image_from_camera=K, resolution=[cam.width, cam.height], camera_xyz=rr.ViewCoordinates.RDF,
                       image_plane_distance=plane_m),
        )


def _log_observations(rec: rr.RecordingStream, observations: Observations, errors: ReprojectionErrors) -> None:
    import rerun as rr

    colors = error_colors(errors.obs_error_px)
    for c, info in enumerate(observations.cameras):
        rows = observations.cam_index == c
        rec.log(
            _entity("world", "cameras", info.id, "image", "observations"),
            rr.Points2D(observations.uv[rows] + 0.5, colors=colors[rows], radii=rr.Radius.ui_points(3.0)),
        )


def _scalar(rec: rr.RecordingStream, value: float, *parts: str) -> None:
    import rerun as rr

    if value is not None and np.isfinite(value):
        rec.log(_entity("series", *parts), rr.Scalars(float(value)))


def _log_series(rec: rr.RecordingStream, calibration: Calibration, truth) -> None:
    from camnet.model.accuracy import compare, compare_cameras, scale_sigma_rel

    stats = calibration.report.cameras if calibration.report is not None else {}
    sigmas = calibration.uncertainty.cameras if calibration.uncertainty is not None else {}
    _scalar(rec, calibration.rms_reprojection_px, "network", "rms_px")
    _scalar(rec, len(calibration.points), "network", "points")
    _scalar(rec, 100.0 * scale_sigma_rel(calibration), "network", "scale_sigma_pct")
    for cam in calibration.cameras:
        if cam.id in stats:
            _scalar(rec, stats[cam.id].rms_px, "rms_px", cam.id)
        sigma = sigmas.get(cam.id)
        if sigma is not None:
            _scalar(rec, sigma.f_px, "sigma_f_px", cam.id)
            _scalar(rec, 1e3 * float(np.linalg.norm(sigma.centre_m)), "sigma_centre_mm", cam.id)
    if truth is None:
        return
    if isinstance(truth, Calibration):
        size = 1 + int(max(truth.point_ids.max(initial=-1), calibration.point_ids.max(initial=-1)))
        truth_points = np.full((size, 3), np.nan)
        truth_points[truth.point_ids] = truth.points
        comparison = compare(calibration, truth.cameras, truth_points)
    else:
        comparison = compare_cameras(calibration, list(truth))
    _scalar(rec, 100.0 * comparison.scale_rel, "network", "scale_error_pct")
    for error in comparison.cameras:
        _scalar(rec, 100.0 * error.focal_rel, "focal_error_pct", error.id)
        _scalar(rec, error.centre_mm, "centre_error_mm", error.id)


def _log_text(rec: rr.RecordingStream, calibration: Calibration, solve_index: int) -> None:
    import rerun as rr

    report = calibration.report
    state = "" if report is None else (", converged" if report.converged else ", NOT converged")
    rec.log("log", rr.TextLog(
        f"solve {solve_index}: {len(calibration.cameras)} cameras, {len(calibration.points)} points, "
        f"RMS {calibration.rms_reprojection_px:.3f} px{state}", level=rr.TextLogLevel.INFO))
    for warning in calibration.warnings:
        rec.log("log", rr.TextLog(f"solve {solve_index}: {warning}", level=rr.TextLogLevel.WARN))


@_sidecar
def log_solve_failure(rec: rr.RecordingStream | None, reason: str, *, time_ns: int,
                      solve_index: int | None = None) -> None:
    """Log a solve that failed (e.g. a SolveError's message) as an error line; counts as a solve."""
    import rerun as rr

    solve_index = _next_solve(rec, solve_index)
    _set_times(rec, time_ns=time_ns, solve_index=solve_index)
    rec.log("log", rr.TextLog(f"solve {solve_index} failed: {reason}", level=rr.TextLogLevel.ERROR))


_BAYER = {
    "bayer_rggb8": "COLOR_BayerRGGB2BGR",
    "bayer_bggr8": "COLOR_BayerBGGR2BGR",
    "bayer_gbrg8": "COLOR_BayerGBRG2BGR",
    "bayer_grbg8": "COLOR_BayerGRBG2BGR",
}


def _jpeg_input(image: np.ndarray, encoding: str) -> np.ndarray:
    """`image` as 8-bit grey or BGR, what cv2.imencode takes."""
    import cv2

    if encoding == "mono16":
        # Stretch by the frame's maximum: 10- and 12-bit cameras would look black if shifted by 8 bits.
        top = max(int(image.max()), 1)
        return (image.astype(np.float32) * (255.0 / top)).astype(np.uint8)
    if encoding == "rgb8":
        return cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if encoding in _BAYER:
        return cv2.cvtColor(image, getattr(cv2, _BAYER[encoding]))
    if encoding in ("mono8", "bgr8"):
        return image
    raise ValueError(f"unknown encoding {encoding!r}")


def _infer_encoding(image: np.ndarray) -> str:
    if image.ndim == 2:
        return "mono16" if image.dtype == np.uint16 else "mono8"
    return "bgr8"


@dataclass
class FrameSchedule:
    """Which cameras' latest frames a solve logs: each at most every `period_s` seconds of capture time (0:
    at every solve), and always a camera's first frame and that of a camera taken for moved (its view changed).
    """

    period_s: float = FRAME_PERIOD_S
    _logged_ns: dict[str, int] = field(default_factory=dict)

    def take(self, camera_id: str, time_ns: int, *, moved: bool = False) -> bool:
        """Whether to log `camera_id`'s frame with the solve of capture time `time_ns` (ns); if so, it
        counts as logged then. Time going back (a replay started over) makes it due."""
        last = self._logged_ns.get(camera_id)
        if not moved and last is not None and 0 <= time_ns - last < self.period_s * 1e9:
            return False
        self._logged_ns[camera_id] = time_ns
        return True


@_sidecar
def log_frame(
    rec: rr.RecordingStream | None,
    camera_id: str,
    image: np.ndarray,
    *,
    time_ns: int,
    encoding: str | None = None,
) -> None:
    """Log a camera's latest image at `world/cameras/<id>/image`.

    encoding: mono8, mono16, bgr8, rgb8 or bayer_*8 (camnet.bus.frame names);
    None infers mono8/mono16 from a 2-D array and bgr8 (OpenCV's order) from
    a 3-channel one. The image is sent as a JPEG (quality `JPEG_QUALITY`) at
    full resolution: 10-25x smaller than raw pixels, so a few Hz per camera
    stay cheap, while it keeps lining up with the camera's pinhole and its
    observations (a downscaled image would not). mono16 is stretched to 8 bits
    by the frame's maximum.
    """
    import cv2
    import rerun as rr

    image = np.asarray(image)
    pixels = _jpeg_input(image, encoding or _infer_encoding(image))
    ok, jpeg = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"cannot JPEG-encode a {image.shape} {image.dtype} image")
    _set_times(rec, time_ns=time_ns, solve_index=_solve_counts.get(rec, 0))
    rec.log(_entity("world", "cameras", camera_id, "image"),
            rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))


__all__ = [
    "ERROR_RANGE_PX",
    "FRAME_PERIOD_S",
    "FrameSchedule",
    "ReprojectionErrors",
    "close_recording",
    "error_colors",
    "log_calibration",
    "log_frame",
    "log_solve_failure",
    "open_recording",
    "reprojection_errors",
]
