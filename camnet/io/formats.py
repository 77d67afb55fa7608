"""The observation and calibration documents (``camnet.observations/1``,
``camnet.calibration/1``): parsing with errors that name the offending path,
and writing.

Parsing is strict about what the contract requires and ignores unknown keys.
Every error is an `InputError` whose message starts with the JSON path, e.g.
``tracks[12].observations.mono_a: expected [u, v]``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.geometry.camera import Camera
from camnet.geometry.projection import full_dist

OBSERVATIONS_FORMAT = "camnet.observations/1"
CALIBRATION_FORMAT = "camnet.calibration/1"
FIXABLE = ("K", "dist")


@dataclass(frozen=True)
class CameraInfo:
    """What an observations document says of one camera."""

    id: str
    width: int
    height: int
    K: np.ndarray | None = None  # 3x3, pixels, if known
    dist: np.ndarray | None = None  # [k1, k2, p1, p2, k3], if known
    fixed: frozenset[str] = frozenset()  # subset of {"K", "dist"} to hold as given


@dataclass(frozen=True)
class Stereo:
    left: str
    right: str
    baseline_m: float


@dataclass(frozen=True)
class Observations:
    """Multi-view correspondences in flat arrays, one row per observation.

    ``uv[k]`` is the pixel (u right, v down, origin at the centre of the
    top-left pixel) at which camera ``cameras[cam_index[k]]`` sees track
    ``track_ids[track_index[k]]``.
    """

    cameras: tuple[CameraInfo, ...]
    stereo: Stereo
    track_ids: np.ndarray  # (T,) int
    cam_index: np.ndarray  # (n,) int
    track_index: np.ndarray  # (n,) int
    uv: np.ndarray  # (n, 2) float pixels

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def index_of(self, camera_id: str) -> int:
        return self.camera_ids.index(camera_id)


@dataclass
class Calibration:
    """A solved network: cameras in the left stereo camera's frame, metric points."""

    cameras: list[Camera]
    point_ids: np.ndarray  # (N,) int, the track ids kept
    points: np.ndarray  # (N, 3) metres, world frame
    rms_reprojection_px: float
    world_frame: str
    extra: dict[str, Any] = field(default_factory=dict)  # documented further keys


# ---------------------------------------------------------------- parsing helpers


def _fail(path: str, message: str) -> InputError:
    return InputError(f"{path}: {message}")


def _number(value: Any, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(path, f"expected a number, got {json.dumps(value)[:40]}")
    if not math.isfinite(value):
        raise _fail(path, "expected a finite number")
    return float(value)


def _require(obj: dict, key: str, path: str) -> Any:
    if not isinstance(obj, dict):
        raise _fail(path, "expected an object")
    if key not in obj:
        raise _fail(f"{path}.{key}" if path else key, "missing")
    return obj[key]


def parse_matrix(value: Any, rows: int, cols: int, path: str) -> np.ndarray:
    """A rows x cols list of lists of finite numbers; InputError naming `path` otherwise."""
    if not isinstance(value, list) or len(value) != rows:
        raise _fail(path, f"expected a {rows}x{cols} array")
    out = np.empty((rows, cols))
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != cols:
            raise _fail(f"{path}[{i}]", f"expected {cols} numbers")
        for j, x in enumerate(row):
            out[i, j] = _number(x, f"{path}[{i}][{j}]")
    return out


def _vector(value: Any, path: str, *, max_size: int) -> np.ndarray:
    if not isinstance(value, list) or len(value) > max_size:
        raise _fail(path, f"expected a list of at most {max_size} numbers")
    return np.array([_number(x, f"{path}[{i}]") for i, x in enumerate(value)], dtype=float)


def _positive_int(value: Any, path: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise _fail(path, "expected a positive integer")
    return value


def _string(value: Any, path: str) -> str:
    if not isinstance(value, str) or not value:
        raise _fail(path, "expected a non-empty string")
    return value


def _check_format(doc: Any, expected: str) -> None:
    if not isinstance(doc, dict):
        raise InputError("document: expected a JSON object")
    fmt = _require(doc, "format", "")
    if fmt != expected:
        raise _fail("format", f"unsupported format {json.dumps(fmt)[:60]}; expected {expected!r}")


def load_json(path: str | Path) -> Any:
    """Read a JSON file; a missing or malformed file is an `InputError`."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


# ---------------------------------------------------------------- observations


def _parse_camera(value: Any, path: str) -> CameraInfo:
    if not isinstance(value, dict):
        raise _fail(path, "expected an object")
    cam_id = _string(_require(value, "id", path), f"{path}.id")
    width = _positive_int(_require(value, "width", path), f"{path}.width")
    height = _positive_int(_require(value, "height", path), f"{path}.height")
    K = parse_matrix(value["K"], 3, 3, f"{path}.K") if "K" in value else None
    if K is not None and (K[0, 0] <= 0 or K[1, 1] <= 0):
        raise _fail(f"{path}.K", "focal lengths must be positive")
    dist = full_dist(_vector(value["dist"], f"{path}.dist", max_size=5)) if "dist" in value else None
    fixed_raw = value.get("fixed", [])
    if not isinstance(fixed_raw, list):
        raise _fail(f"{path}.fixed", f"expected a list drawn from {list(FIXABLE)}")
    for i, name in enumerate(fixed_raw):
        if name not in FIXABLE:
            raise _fail(f"{path}.fixed[{i}]", f"unknown {json.dumps(name)[:30]}; expected one of {list(FIXABLE)}")
        if value.get(name) is None:
            raise _fail(f"{path}.fixed[{i}]", f"{name} is fixed but not given")
    return CameraInfo(cam_id, width, height, K, dist, frozenset(fixed_raw))


def parse_observations(doc: Any) -> Observations:
    """Validate a ``camnet.observations/1`` document and return flat arrays."""
    _check_format(doc, OBSERVATIONS_FORMAT)
    cams_raw = _require(doc, "cameras", "")
    if not isinstance(cams_raw, list) or not cams_raw:
        raise _fail("cameras", "expected a non-empty list")
    cameras = tuple(_parse_camera(c, f"cameras[{i}]") for i, c in enumerate(cams_raw))
    ids = [c.id for c in cameras]
    for i, cam_id in enumerate(ids):
        if ids.index(cam_id) != i:
            raise _fail(f"cameras[{i}].id", f"duplicate camera id {cam_id!r}")
    index = {cam_id: i for i, cam_id in enumerate(ids)}

    stereo_raw = _require(doc, "stereo", "")
    left = _string(_require(stereo_raw, "left", "stereo"), "stereo.left")
    right = _string(_require(stereo_raw, "right", "stereo"), "stereo.right")
    for key, cam_id in (("left", left), ("right", right)):
        if cam_id not in index:
            raise _fail(f"stereo.{key}", f"unknown camera id {cam_id!r}")
    if left == right:
        raise _fail("stereo.right", "the stereo pair needs two different cameras")
    baseline = _number(_require(stereo_raw, "baseline_m", "stereo"), "stereo.baseline_m")
    if baseline <= 0:
        raise _fail("stereo.baseline_m", f"must be positive, got {baseline:g}")

    tracks_raw = _require(doc, "tracks", "")
    if not isinstance(tracks_raw, list):
        raise _fail("tracks", "expected a list")
    track_ids, cam_index, track_index, uv = [], [], [], []
    seen: set[int] = set()
    for ti, track in enumerate(tracks_raw):
        path = f"tracks[{ti}]"
        track_id = _require(track, "id", path)
        if isinstance(track_id, bool) or not isinstance(track_id, int):
            raise _fail(f"{path}.id", "expected an integer")
        if track_id in seen:
            raise _fail(f"{path}.id", f"duplicate track id {track_id}")
        seen.add(track_id)
        obs = _require(track, "observations", path)
        if not isinstance(obs, dict):
            raise _fail(f"{path}.observations", "expected an object of camera id -> [u, v]")
        for cam_id, pixel in obs.items():
            opath = f"{path}.observations.{cam_id}"
            if cam_id not in index:
                raise _fail(opath, f"unknown camera id {cam_id!r}")
            if not isinstance(pixel, list) or len(pixel) != 2:
                raise _fail(opath, "expected [u, v]")
            u = _number(pixel[0], opath + "[0]")
            v = _number(pixel[1], opath + "[1]")
            cam_index.append(index[cam_id])
            track_index.append(len(track_ids))
            uv.append((u, v))
        track_ids.append(track_id)
    return Observations(
        cameras=cameras,
        stereo=Stereo(left, right, baseline),
        track_ids=np.asarray(track_ids, dtype=np.int64),
        cam_index=np.asarray(cam_index, dtype=np.int64),
        track_index=np.asarray(track_index, dtype=np.int64),
        uv=np.asarray(uv, dtype=float).reshape(-1, 2),
    )


def observations_to_doc(obs: Observations) -> dict:
    """The ``camnet.observations/1`` document of `obs`."""
    cameras = []
    for c in obs.cameras:
        entry: dict[str, Any] = {"id": c.id, "width": c.width, "height": c.height}
        if c.K is not None:
            entry["K"] = np.asarray(c.K).tolist()
        if c.dist is not None:
            entry["dist"] = np.asarray(c.dist).tolist()
        if c.fixed:
            entry["fixed"] = sorted(c.fixed)
        cameras.append(entry)
    tracks: list[dict] = [{"id": int(t), "observations": {}} for t in obs.track_ids]
    for cam, trk, (u, v) in zip(obs.cam_index, obs.track_index, obs.uv, strict=True):
        tracks[trk]["observations"][obs.cameras[cam].id] = [float(u), float(v)]
    return {
        "format": OBSERVATIONS_FORMAT,
        "cameras": cameras,
        "stereo": {
            "left": obs.stereo.left,
            "right": obs.stereo.right,
            "baseline_m": obs.stereo.baseline_m,
        },
        "tracks": tracks,
    }


# ---------------------------------------------------------------- calibration


def calibration_to_doc(cal: Calibration) -> dict:
    """The ``camnet.calibration/1`` document of `cal`; `cal.extra` adds further keys."""
    cameras = []
    for cam in cal.cameras:
        cameras.append(
            {
                "id": cam.id,
                "width": cam.width,
                "height": cam.height,
                "K": np.asarray(cam.K).tolist(),
                "dist": np.asarray(cam.dist).tolist(),
                "R": np.asarray(cam.R).tolist(),
                "t": np.asarray(cam.t).tolist(),
            }
        )
    doc = {
        "format": CALIBRATION_FORMAT,
        "world_frame": cal.world_frame,
        "units": "m",
        "cameras": cameras,
        "points": [
            {"id": int(i), "xyz": [float(x) for x in p]} for i, p in zip(cal.point_ids, cal.points, strict=True)
        ],
        # A calibration that no observation went into (a factory stereo head) has no RMS; JSON has no NaN.
        "rms_reprojection_px": float(cal.rms_reprojection_px) if np.isfinite(cal.rms_reprojection_px) else None,
    }
    doc.update(cal.extra)
    return doc


def parse_calibration(doc: Any) -> Calibration:
    """Validate a ``camnet.calibration/1`` document."""
    _check_format(doc, CALIBRATION_FORMAT)
    cams_raw = _require(doc, "cameras", "")
    if not isinstance(cams_raw, list) or not cams_raw:
        raise _fail("cameras", "expected a non-empty list")
    cameras = []
    for i, c in enumerate(cams_raw):
        path = f"cameras[{i}]"
        R = parse_matrix(_require(c, "R", path), 3, 3, f"{path}.R")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
            raise _fail(f"{path}.R", "not a rotation matrix")
        t = _vector(_require(c, "t", path), f"{path}.t", max_size=3)
        if t.size != 3:
            raise _fail(f"{path}.t", "expected 3 numbers")
        cameras.append(
            Camera(
                id=_string(_require(c, "id", path), f"{path}.id"),
                width=_positive_int(_require(c, "width", path), f"{path}.width"),
                height=_positive_int(_require(c, "height", path), f"{path}.height"),
                K=parse_matrix(_require(c, "K", path), 3, 3, f"{path}.K"),
                dist=full_dist(_vector(c.get("dist", []), f"{path}.dist", max_size=5)),
                R=R,
                t=t,
            )
        )
    points_raw = doc.get("points", [])
    if not isinstance(points_raw, list):
        raise _fail("points", "expected a list")
    ids, xyz = [], []
    for i, p in enumerate(points_raw):
        pid = _require(p, "id", f"points[{i}]")
        if isinstance(pid, bool) or not isinstance(pid, int):
            raise _fail(f"points[{i}].id", "expected an integer")
        v = _vector(_require(p, "xyz", f"points[{i}]"), f"points[{i}].xyz", max_size=3)
        if v.size != 3:
            raise _fail(f"points[{i}].xyz", "expected 3 numbers")
        ids.append(pid)
        xyz.append(v)
    rms = doc.get("rms_reprojection_px", float("nan"))
    known = {"format", "world_frame", "units", "cameras", "points", "rms_reprojection_px"}
    return Calibration(
        cameras=cameras,
        point_ids=np.asarray(ids, dtype=np.int64),
        points=np.asarray(xyz, dtype=float).reshape(-1, 3),
        rms_reprojection_px=float(rms) if isinstance(rms, int | float) else float("nan"),
        world_frame=str(doc.get("world_frame", cameras[0].id)),
        extra={k: v for k, v in doc.items() if k not in known},
    )


def write_json_atomic(path: str | Path, doc: Any) -> None:
    """Write `doc` as JSON so that `path` holds either the old file or the whole new one."""
    from camnet.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
