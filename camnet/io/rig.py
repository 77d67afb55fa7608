"""The rig file (YAML): which cameras a rig has, how to drive each, and the stereo pair.

Parsed into frozen, validated dataclasses; one config dataclass per driver.
Every error is an InputError naming the field, e.g.
``cameras[2].driver: unknown driver 'foo' (expected sim, aravis, v4l2)``.
Unknown keys are refused too, named with the key they most resemble, so that
a typo never silently falls back to a default (camnet.io.rig_section). Paths
in a rig file are relative to the rig file. The format is documented in
config/README.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.ids import validate_id
from camnet.io import validate as v
from camnet.io.rig_section import Section
from camnet.model.camera import Camera, CameraInfo, LensModel
from camnet.model.observations import Baseline, Stereo
from camnet.sim.clock import MAX_DRIFT_PPM, SimClock, free_run_phase
from camnet.sim.config import SceneConfig, SimConfig
from camnet.solve.options import World

SIM_ENCODINGS = ("mono8", "mono16", "bgr8", "rgb8")
V4L2_ENCODINGS = ("bgr8", "mono8")


@dataclass(frozen=True)
class AravisConfig:
    """A GigE Vision / USB3 Vision camera through Aravis.

    `device_id`: Aravis device id ("<vendor>-<serial>"), serial, or IP address; None
    picks the first camera found. Optional features are set only when given and
    when the camera has them.
    """

    device_id: str | None
    pixel_format: str
    width: int | None
    height: int | None
    fps: float | None
    exposure_us: float | None
    gain_db: float | None
    packet_size: int | None
    n_buffers: int
    enable_fake_interface: bool


@dataclass(frozen=True)
class V4l2Config:
    """A V4L2 device path, a video file, or an image-sequence glob pattern, via OpenCV.

    `fps` paces files and sequences (and is requested from devices); `loop`
    restarts a file or sequence at its end. An image sequence with a
    `timestamps` file (KITTI's format, one line per frame index) is stamped
    with the recorded capture times and, without `fps`, published at the
    recorded pace times `speed`; `frame_range` (first, last frame index) is
    one pass of it (see drivers/v4l2.py).
    """

    source: str
    width: int | None
    height: int | None
    fps: float | None
    fourcc: str | None
    encoding: str
    loop: bool
    timestamps: str | None = None
    speed: float = 1.0
    frame_range: tuple[int, int] | None = None


@dataclass(frozen=True)
class KnownIntrinsics:
    """What is known of a camera's intrinsics before calibrating (the observations' K, dist, fixed).

    K in pixels (pixel origin at the centre of the top-left pixel), dist in
    the camera's lens model's order (pinhole [k1, k2, p1, p2, k3], fisheye
    [k1, k2, k3, k4]); `fixed` names what the solver holds.
    """

    K: np.ndarray | None
    dist: np.ndarray | None
    fixed: frozenset[str]


@dataclass(frozen=True)
class SyncSettings:
    """How the matcher forms frame sets of this rig (its flags override these)."""

    tolerance_ms: float | None
    max_wait_s: float | None
    free_run: bool | None = None  # the cameras are not triggered together (None: the matcher's default)


@dataclass(frozen=True)
class CameraEntry:
    """One camera; `driver` and `config` are None for a camera known only from its images (`camnet match`)."""

    id: str
    driver: str | None
    config: SimConfig | AravisConfig | V4l2Config | None
    intrinsics: KnownIntrinsics | None = None
    model: LensModel = LensModel.PINHOLE  # the lens model of its distortion (the sim's and the intrinsics')


@dataclass(frozen=True)
class Rig:
    name: str
    cameras: tuple[CameraEntry, ...]
    stereo: Stereo | None
    scene: SceneConfig
    source: str = "<memory>"
    sync: SyncSettings | None = None
    baselines: tuple[Baseline, ...] = ()  # known distances beyond the stereo pair's (a second head, a tape)
    world: World = World.LEFT_CAMERA  # the frame its calibrations are written in

    def camera(self, camera_id: str) -> CameraEntry:
        for entry in self.cameras:
            if entry.id == camera_id:
                return entry
        known = ", ".join(c.id for c in self.cameras)
        raise InputError(f"{self.source}: no camera {camera_id!r} in rig {self.name!r} "
                         f"(cameras: {known})")

    def simulated_truth(self) -> list[Camera]:
        """The simulated cameras' ground truth in the left stereo camera's frame (a calibration's world).

        Empty unless every camera is simulated and the rig has a stereo pair.
        """
        if self.stereo is None or any(entry.driver != "sim" for entry in self.cameras):
            return []
        cameras = [entry.config.camera(entry.id) for entry in self.cameras]
        left = next(c for c in cameras if c.id == self.stereo.left)
        # x_left = R_l X + t_l, so X = R_l^T (x_left - t_l) and x_cam = R R_l^T x_left + (t - R R_l^T t_l).
        out = []
        for cam in cameras:
            R = cam.R @ left.R.T
            out.append(replace(cam, R=R, t=cam.t - R @ left.t))
        return out


# The keys of each section of a rig file (config/README.md).
SIM_KEYS = ("width", "height", "encoding", "fps", "f_px", "fx_px", "fy_px", "cx_px", "cy_px", "dist", "centre_m",
            "look_at_m", "up", "noise_sigma_dn", "clock")
CLOCK_KEYS = ("offset_ms", "drift_ppm", "latency_ms", "free_run")
ARAVIS_KEYS = ("device_id", "pixel_format", "width", "height", "fps", "exposure_us", "gain_db", "packet_size",
               "n_buffers", "enable_fake_interface")
V4L2_KEYS = ("source", "width", "height", "fps", "fourcc", "encoding", "loop", "timestamps", "speed", "frame_range")
INTRINSICS_KEYS = ("K", "dist", "fixed")
SYNC_KEYS = ("tolerance_ms", "max_wait_s", "free_run")
SCENE_KEYS = ("seed", "box_centre_m", "box_size_m", "box_rotation_deg_per_s", "wall_z_m", "wall_x_range_m",
              "wall_y_range_m", "floor_y_m", "floor_z_range_m", "object")
CAMERA_KEYS = ("id", "driver", "model", "intrinsics")  # and the section named after its driver
STEREO_KEYS = ("left", "right", "baseline_m", "sigma_m", "parallel", "R", "t", "tolerance_deg")
TOP_KEYS = ("rig", "stereo", "baselines", "scene", "sync", "cameras", "world", v.ANY_DISTANCE_FLAG)


def _sim(s: Section, model: LensModel = LensModel.PINHOLE, camera_id: str = "") -> SimConfig:
    if "f_px" in s.data:
        both = [key for key in ("fx_px", "fy_px") if key in s.data]
        if both:
            raise InputError(f"{s.field(both[0])}: give f_px, or fx_px and fy_px, not both")
        fx = fy = s.number("f_px", positive=True)
    else:
        fx, fy = s.number("fx_px", positive=True), s.number("fy_px", positive=True)
    width, height = s.side("width"), s.side("height")
    dist = s.dist("dist", model, np.zeros(model.dist_size))
    config = SimConfig(
        width=width, height=height,
        encoding=s.string("encoding", "mono8", choices=SIM_ENCODINGS),
        fps=s.number("fps", 30.0, positive=True),
        fx_px=fx, fy_px=fy,
        cx_px=s.number("cx_px", (width - 1) / 2.0),
        cy_px=s.number("cy_px", (height - 1) / 2.0),
        dist=tuple(dist.tolist()),
        centre_m=s.vector("centre_m", 3, (0.0, 0.0, 0.0)),
        look_at_m=s.vector("look_at_m", 3, None),
        up=s.vector("up", 3, (0.0, -1.0, 0.0)),
        noise_sigma_dn=s.number("noise_sigma_dn", 2.0, minimum=0.0),
        model=model,
        clock=_clock(s.section("clock", CLOCK_KEYS), camera_id) if s.raw("clock", None) is not None else None,
    )
    return config


def _clock(s: Section, camera_id: str) -> SimClock:
    drift_ppm = s.number("drift_ppm", 0.0)
    if abs(drift_ppm) > MAX_DRIFT_PPM:
        raise InputError(f"{s.field('drift_ppm')}: must be within +-{MAX_DRIFT_PPM:g} ppm, got {drift_ppm:g}")
    free_run = s.boolean("free_run", False)
    return SimClock(offset_ms=s.number("offset_ms", 0.0), drift_ppm=drift_ppm,
                    latency_ms=s.number("latency_ms", 0.0, minimum=0.0), free_run=free_run,
                    phase=free_run_phase(camera_id) if free_run else 0.0)


def _optional_positive(s: Section, key: str, *, integer: bool = False):
    return s.integer(key, None, positive=True) if integer else s.number(key, None, positive=True)


def _aravis(s: Section) -> AravisConfig:
    device_id = s.raw("device_id", None)
    if device_id is not None and not isinstance(device_id, str):
        device_id = str(device_id)
    config = AravisConfig(
        device_id=device_id,
        pixel_format=s.string("pixel_format", "Mono8"),
        width=s.side("width", None),
        height=s.side("height", None),
        fps=_optional_positive(s, "fps"),
        exposure_us=_optional_positive(s, "exposure_us"),
        gain_db=s.number("gain_db", None, minimum=0.0),
        packet_size=_optional_positive(s, "packet_size", integer=True),
        n_buffers=s.integer("n_buffers", 8, positive=True),
        enable_fake_interface=s.boolean("enable_fake_interface", False),
    )
    return config


def _v4l2(s: Section) -> V4l2Config:
    fourcc = s.raw("fourcc", None)
    if fourcc is not None and (not isinstance(fourcc, str) or len(fourcc) != 4):
        raise InputError(f"{s.field('fourcc')}: expected 4 characters such as MJPG, "
                         f"got {fourcc!r}")
    config = V4l2Config(
        source=_v4l2_source(s),
        width=s.side("width", None),
        height=s.side("height", None),
        fps=_optional_positive(s, "fps"),
        fourcc=fourcc,
        encoding=s.string("encoding", "bgr8", choices=V4L2_ENCODINGS),
        loop=s.boolean("loop", False),
        timestamps=s.path_string("timestamps", None),
        speed=s.number("speed", 1.0, positive=True),
        frame_range=_frame_range(s),
    )
    if config.timestamps is None:
        for key in ("speed", "frame_range"):
            if key in s.data:
                raise InputError(f"{s.field(key)}: only for an image sequence with a 'timestamps' file")
    elif not is_image_pattern(config.source):
        raise InputError(f"{s.field('timestamps')}: only for an image sequence (a glob 'source'), "
                         f"not {config.source!r}")
    if config.fps is not None and "speed" in s.data:
        raise InputError(f"{s.field('speed')}: scales the recorded pace; with 'fps' the pace is fixed "
                         "(give one of them)")
    return config


def _v4l2_source(s: Section) -> str:
    """The v4l2 source: a device as given, a file or a glob relative to the rig file."""
    source = s.string("source")
    if source.isdigit() or source.startswith("/dev/"):
        return source
    return s.path_string("source", pattern=is_image_pattern(source))


def is_image_pattern(source: str) -> bool:
    """Whether a v4l2 `source` is a glob of image files (else a device or a video file)."""
    return any(ch in source for ch in "*?[")


def _frame_range(s: Section) -> tuple[int, int] | None:
    value = s.raw("frame_range", None)
    if value is None:
        return None
    ok = isinstance(value, list) and len(value) == 2 and all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value)
    if not ok or value[0] > value[1]:
        raise InputError(f"{s.field('frame_range')}: expected [first, last] frame indices with "
                         f"0 <= first <= last, got {value!r}")
    return int(value[0]), int(value[1])


def _intrinsics(s: Section, model: LensModel) -> KnownIntrinsics:
    K = s.matrix("K", 3, 3, None)
    upper_triangular = K is None or (K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and np.array_equal(K[2], [0, 0, 1]))
    if not upper_triangular:
        raise InputError(f"{s.field('K')}: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with "
                         f"fx, fy > 0, got {K.tolist()}")
    dist = s.dist("dist", model, None)
    given = [name for name, value in (("K", K), ("dist", dist)) if value is not None]
    if not given:
        raise InputError(f"{s.path}: give K, dist or both")
    fixed = s.raw("fixed", given)
    if not isinstance(fixed, list) or not all(name in given for name in fixed):
        raise InputError(f"{s.field('fixed')}: expected a list drawn from the given {given}, got {fixed!r}")
    return KnownIntrinsics(K=K, dist=dist, fixed=frozenset(fixed))


def _sync(s: Section) -> SyncSettings:
    free_run = s.boolean("free_run", False) if s.raw("free_run", None) is not None else None
    settings = SyncSettings(tolerance_ms=s.number("tolerance_ms", None, minimum=0.0),
                            max_wait_s=s.number("max_wait_s", None, minimum=0.0), free_run=free_run)
    return settings


_DRIVER_PARSERS = {"sim": _sim, "aravis": _aravis, "v4l2": _v4l2}
DRIVERS = tuple(_DRIVER_PARSERS)  # the camera drivers, one config section each (camnet.drivers has their modules)


_SECTION_KEYS = {"sim": SIM_KEYS, "aravis": ARAVIS_KEYS, "v4l2": V4L2_KEYS}


def _camera(data: Any, path: str, base_dir: Path | None, ids: v.Ids) -> CameraEntry:
    driver = data.get("driver") if isinstance(data, dict) else None
    if driver is not None and driver not in DRIVERS:
        raise InputError(f"{path}.driver: unknown driver {driver!r} (expected {', '.join(DRIVERS)})")
    s = Section(data, path, CAMERA_KEYS + ((driver,) if driver else ()), base_dir=base_dir, ids=ids)
    camera_id = validate_id(s.identifier("id"), what=s.field("id"))
    model = LensModel(s.string("model", LensModel.PINHOLE.value, choices=tuple(LensModel)))
    config = None
    if driver is not None:
        section = s.section(driver, _SECTION_KEYS[driver])
        config = _sim(section, model, camera_id) if driver == "sim" else _DRIVER_PARSERS[driver](section)
    intrinsics = None
    if s.raw("intrinsics", None) is not None:
        intrinsics = _intrinsics(s.section("intrinsics", INTRINSICS_KEYS), model)
    return CameraEntry(id=camera_id, driver=driver, config=config, intrinsics=intrinsics, model=model)


def _range(s: Section, key: str, default: tuple[float, float]) -> tuple[float, float]:
    lo, hi = s.vector(key, 2, default)
    if not lo < hi:
        raise InputError(f"{s.field(key)}: expected [low, high] with low < high, got {[lo, hi]}")
    return lo, hi


def _scene(s: Section) -> SceneConfig:
    size = s.vector("box_size_m", 3, (0.10, 0.17, 0.08))
    if min(size) <= 0:
        raise InputError(f"{s.field('box_size_m')}: sizes must be positive, got {list(size)}")
    scene = SceneConfig(
        seed=s.integer("seed", 7),
        box_centre_m=s.vector("box_centre_m", 3, (0.0625, 0.0, 0.65)),
        box_size_m=size,
        box_rotation_deg_per_s=s.number("box_rotation_deg_per_s", 5.0),
        wall_z_m=s.number("wall_z_m", 1.2, positive=True),
        wall_x_range_m=_range(s, "wall_x_range_m", (-1.5, 1.6)),
        wall_y_range_m=_range(s, "wall_y_range_m", (-0.8, 0.25)),
        floor_y_m=s.number("floor_y_m", 0.25),
        floor_z_range_m=_range(s, "floor_z_range_m", (0.2, 1.2)),
        object=s.string("object", "box", choices=("box", "person")),
    )
    return scene


def parse_rig(data: Any, *, source: str = "<memory>", base_dir: Path | None = None,
              spellings: Mapping[str, str] | None = None) -> Rig:
    """The Rig described by `data` (the YAML document as Python objects).

    A relative path in it (a v4l2 source or timestamps file) is taken relative
    to `base_dir` (the rig file's directory); None keeps it as given.
    `spellings`: the text of the unquoted scalars by path (`yaml_spellings`),
    so that an id YAML read as a number is shown as written.
    """
    try:
        return _parse_rig(data, source, base_dir, v.Ids(yaml=True, spellings=spellings or {}))
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def _parse_rig(data: Any, source: str, base_dir: Path | None, ids: v.Ids) -> Rig:
    top = Section(data, "", TOP_KEYS, ids=ids)
    any_distance = top.boolean(v.ANY_DISTANCE_FLAG, False)
    name = validate_id(top.identifier("rig"), what="rig")
    raw_cameras = top.raw("cameras", required=True)
    if not isinstance(raw_cameras, list) or not raw_cameras:
        raise InputError(f"cameras: expected a non-empty list, got {raw_cameras!r}")
    cameras = tuple(_camera(c, f"cameras[{i}]", base_dir, ids) for i, c in enumerate(raw_cameras))
    seen: dict[str, int] = {}
    for i, cam in enumerate(cameras):
        if cam.id in seen:
            raise InputError(f"cameras[{i}].id: duplicate id {cam.id!r} "
                             f"(also cameras[{seen[cam.id]}])")
        seen[cam.id] = i
    stereo = None
    if top.raw("stereo", None) is not None:
        st = top.section("stereo", STEREO_KEYS)
        left, right = st.identifier("left"), st.identifier("right")
        for key, cid in (("left", left), ("right", right)):
            if cid not in seen:
                raise InputError(f"{st.field(key)}: no camera {cid!r} in cameras "
                                 f"(have {', '.join(seen)})")
        if left == right:
            raise InputError(f"{st.field('right')}: must differ from stereo.left")
        baseline_m = v.plausible_distance(st.number("baseline_m", positive=True), st.field("baseline_m"),
                                          keep=v.KEEP_IN_RIG_FILE, any_distance=any_distance)
        pair = Stereo(left=left, right=right, baseline_m=baseline_m,
                      sigma_m=st.number("sigma_m", 0.0, minimum=0.0), parallel=st.boolean("parallel", False),
                      tolerance_deg=st.number("tolerance_deg", None, minimum=0.0))
        stereo = _stereo_pose(st, pair, cameras)
    pair_ids = None if stereo is None else (stereo.left, stereo.right)
    baselines = v.baselines(top.raw("baselines", []), "baselines", seen, pair_ids, strict=True,
                            keep=v.KEEP_IN_RIG_FILE, any_distance=any_distance, ids=ids)
    scene = _scene(top.section("scene", SCENE_KEYS, required=False))
    sync = _sync(top.section("sync", SYNC_KEYS)) if top.raw("sync", None) is not None else None
    world = World(top.string("world", World.LEFT_CAMERA.value, choices=tuple(w.value for w in World)))
    return Rig(name=name, cameras=cameras, stereo=stereo, scene=scene, source=source, sync=sync, baselines=baselines,
               world=world)


def _stereo_pose(st: Section, pair: Stereo, cameras: tuple[CameraEntry, ...]) -> Stereo:
    """The pair with its known pose (stereo.R, stereo.t), checked, when the rig file gives one."""
    R, t = st.rotation("R", None), st.vector("t", 3, None)
    if R is None and t is None:
        return pair
    if R is None or t is None:
        raise InputError(f"{st.field('R' if R is None else 't')}: missing; a known stereo pose needs both R and t "
                         "(the right camera's pose in the left's frame, x_right = R x_left + t)")
    t = np.array(t)
    if abs(np.linalg.norm(t) - pair.baseline_m) > 1e-3 * pair.baseline_m:
        raise InputError(f"{st.field('t')}: its length {np.linalg.norm(t):.6g} m differs from "
                         f"stereo.baseline_m {pair.baseline_m:.6g} m")
    for cam in cameras:
        if cam.id in (pair.left, pair.right) and (cam.intrinsics is None or cam.intrinsics.K is None):
            raise InputError(f"{st.field('R')}: a known stereo pose needs intrinsics.K of camera {cam.id!r}")
    return replace(pair, R=R, t=t)


def configured_size(rig: Rig, camera_id: str) -> tuple[int, int] | None:
    """(width, height) the rig file gives for a camera, if it gives one."""
    config = rig.camera(camera_id).config
    width, height = getattr(config, "width", None), getattr(config, "height", None)
    return (width, height) if width and height else None


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file."""
    import yaml

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read rig file: {exc.strerror}") from exc
    loader = yaml.SafeLoader(text)  # yaml.safe_load's steps, keeping the nodes for their spellings
    try:
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from exc
    finally:
        loader.dispose()
    return parse_rig(data, source=str(path), base_dir=path.parent, spellings=yaml_spellings(node))


def yaml_spellings(node, path: str = "") -> dict[str, str]:
    """The text of every unquoted scalar that YAML did not read as a string (6 from ``0006``, true from
    ``on``), by its path in the document as the rig's errors name it (``cameras[0].id``)."""
    import yaml

    out: dict[str, str] = {}
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            out.update(yaml_spellings(value, f"{path}.{key.value}" if path else str(key.value)))
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            out.update(yaml_spellings(item, f"{path}[{i}]"))
    elif isinstance(node, yaml.ScalarNode) and node.style is None and node.tag != "tag:yaml.org,2002:str":
        out[path] = node.value
    return out


def camera_info(rig: Rig, camera_id: str, width: int, height: int) -> CameraInfo:
    """What the observations say of a camera: its size and the intrinsics the rig file knows."""
    entry = rig.camera(camera_id)
    known = entry.intrinsics
    if known is None:
        return CameraInfo(camera_id, width, height, model=entry.model)
    return CameraInfo(camera_id, width, height, K=known.K, dist=known.dist, fixed=known.fixed, model=entry.model)
