"""The observation and calibration documents (``camnet.observations/1``,
``camnet.calibration/1``): parsing with errors that name the offending path,
and writing.

The types are camnet.model.calibration's; the further keys of a calibration (its
SolveReport) are read and written by camnet.io.solve_report. Parsing is strict
about what the contract requires and ignores unknown keys.
Every error is an `InputError` whose message starts with the JSON path, e.g.
``tracks[12].observations.mono_a: expected [u, v]``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from camnet.errors import InputError, in_words
from camnet.io import validate as v
from camnet.io.solve_report import parse_report, report_to_doc, verdict_to_doc
from camnet.model.calibration import FLOOR_FRAME, Calibration, FloorFrame, in_world_frame
from camnet.model.camera import FIXABLE, Camera, CameraInfo, LensModel, in_frame
from camnet.model.observations import Baseline, Observations, Stereo
from camnet.solve.report.verdict import judge

OBSERVATIONS_FORMAT = "camnet.observations/1"
CALIBRATION_FORMAT = "camnet.calibration/1"


def check_format(doc: Any, expected: str) -> None:
    """Raise unless `doc` is a JSON object whose "format" is `expected`."""
    if not isinstance(doc, dict):
        raise InputError("document: expected a JSON object")
    fmt = v.require(doc, "format", "")
    if fmt != expected:
        raise v.fail("format", f"unsupported format {json.dumps(fmt)[:60]}; expected {expected!r}")


def load_json(path: str | Path) -> Any:
    """Read a JSON file; a missing or malformed file is an `InputError`."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return v.decode_json(data, str(path))


# ---------------------------------------------------------------- observations


def _parse_camera(value: Any, path: str) -> CameraInfo:
    cam_id = v.JSON_IDS.read(v.require(value, "id", path), f"{path}.id")
    width = v.image_side(v.require(value, "width", path), f"{path}.width")
    height = v.image_side(v.require(value, "height", path), f"{path}.height")
    K = v.intrinsic_matrix(value["K"], f"{path}.K") if "K" in value else None
    model = v.lens_model(value["model"], f"{path}.model") if "model" in value else LensModel.PINHOLE
    dist = v.lens_dist(value["dist"], model, f"{path}.dist") if "dist" in value else None
    fixed_raw = value.get("fixed", [])
    if not isinstance(fixed_raw, list):
        raise v.fail(f"{path}.fixed", f"expected a list drawn from {in_words(FIXABLE)}")
    for i, name in enumerate(fixed_raw):
        if name not in FIXABLE:
            raise v.fail(f"{path}.fixed[{i}]",
                         f"unknown {json.dumps(name)[:30]}; expected {in_words(FIXABLE, last='or')}")
        if value.get(name) is None:
            raise v.fail(f"{path}.fixed[{i}]", f"{name} is fixed but not given")
    return CameraInfo(cam_id, width, height, K, dist, frozenset(fixed_raw), model)


def _parse_stereo(stereo_raw: Any, index: dict[str, int], any_distance: bool) -> Stereo:
    """The `stereo` section; `index`: the camera ids."""
    left = v.JSON_IDS.read(v.require(stereo_raw, "left", "stereo"), "stereo.left")
    right = v.JSON_IDS.read(v.require(stereo_raw, "right", "stereo"), "stereo.right")
    for key, cam_id in (("left", left), ("right", right)):
        if cam_id not in index:
            raise v.fail(f"stereo.{key}", f"unknown camera id {cam_id!r}")
    if left == right:
        raise v.fail("stereo.right", "the stereo pair needs two different cameras")
    baseline = v.number(v.require(stereo_raw, "baseline_m", "stereo"), "stereo.baseline_m")
    if baseline <= 0:
        raise v.fail("stereo.baseline_m", f"must be positive, got {baseline:g}")
    v.plausible_distance(baseline, "stereo.baseline_m", keep=v.KEEP_BY_FLAG, any_distance=any_distance)
    sigma = stereo_raw.get("sigma_m")
    stereo_sigma_m = 0.0 if sigma is None else v.number(sigma, "stereo.sigma_m", minimum=0.0)
    return Stereo(left, right, baseline, sigma_m=stereo_sigma_m)


# Tracks one solve takes: the adjustment's time and memory grow with the tracks, and beyond this a solve of
# 16 cameras takes minutes and gigabytes (docs/benchmarks.md, "Evidence behind the nodes' choices").
MAX_TRACKS = 20_000


def parse_observations(doc: Any, *, any_distance: bool = False, max_tracks: int | None = None,
                       subsample_seed: int | None = None) -> Observations:
    """Validate a ``camnet.observations/1`` document and return flat arrays.

    any_distance: accept known distances outside the plausible range for
    camera rigs (validate.PLAUSIBLE_DISTANCE_M), which are refused otherwise.
    max_tracks: refuse a document with more tracks (MAX_TRACKS for a solve),
    or, with `subsample_seed`, keep that many of them drawn at random.
    """
    check_format(doc, OBSERVATIONS_FORMAT)
    cams_raw = v.non_empty_list(v.require(doc, "cameras", ""), "cameras")
    cameras = tuple(_parse_camera(c, f"cameras[{i}]") for i, c in enumerate(cams_raw))
    ids = [c.id for c in cameras]
    for i, cam_id in enumerate(ids):
        if ids.index(cam_id) != i:
            raise v.fail(f"cameras[{i}].id", f"duplicate camera id {cam_id!r}")
    index = {cam_id: i for i, cam_id in enumerate(ids)}

    stereo = _parse_stereo(v.require(doc, "stereo", ""), index, any_distance)
    baselines = v.baselines(doc.get("baselines", []), "baselines", index, (stereo.left, stereo.right),
                            keep=v.KEEP_BY_FLAG, any_distance=any_distance)

    tracks_raw = v.require(doc, "tracks", "")
    if not isinstance(tracks_raw, list):
        raise v.fail("tracks", "expected a list")
    tracks_raw = _cap_tracks(tracks_raw, max_tracks, subsample_seed)
    # Checking value by value takes most of a second for a pool of 5000 tracks: all at once first, and
    # value by value only to say what is wrong.
    arrays = _track_arrays(tracks_raw, cameras, index) or _checked_track_arrays(tracks_raw, cameras, index)
    track_ids, cam_index, track_index, uv = arrays
    return Observations(
        cameras=cameras,
        stereo=stereo,
        track_ids=track_ids,
        cam_index=cam_index,
        track_index=track_index,
        uv=uv,
        baselines=baselines,
    )


TrackArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # track ids, camera and track index, uv (n, 2)


def _track_arrays(tracks_raw: list, cameras: tuple[CameraInfo, ...], index: dict[str, int]) -> TrackArrays | None:
    """The tracks' arrays when every track is valid, else None (`_checked_track_arrays` then says why)."""
    track_ids, cam_index, track_index, uv = [], [], [], []
    try:
        for ti, track in enumerate(tracks_raw):
            obs = track["observations"]
            if type(track["id"]) is not int or type(obs) is not dict:
                return None
            for cam_id, pixel in obs.items():
                if type(pixel) is not list or len(pixel) != 2:
                    return None
                cam_index.append(index[cam_id])
                uv.append(pixel)
            track_index.extend([ti] * len(obs))
            track_ids.append(track["id"])
    except (KeyError, TypeError):
        return None
    if ({type(x) for pixel in uv for x in pixel} - {float, int} or len(set(track_ids)) != len(track_ids)
            or any(abs(t) > v.MAX_INTEGER for t in track_ids)):
        return None
    try:
        uv_px = np.asarray(uv, dtype=float).reshape(-1, 2)
    except OverflowError:  # an integer beyond a float's range
        return None
    cam = np.asarray(cam_index, dtype=np.int64)
    size = np.array([(c.width, c.height) for c in cameras], dtype=float)[cam]
    margin = v.PIXEL_MARGIN_REL * size
    if not (np.all(np.isfinite(uv_px)) and np.all(-0.5 - margin <= uv_px) and np.all(uv_px <= size - 0.5 + margin)):
        return None
    return (np.asarray(track_ids, dtype=np.int64), cam, np.asarray(track_index, dtype=np.int64), uv_px)


def _checked_track_arrays(tracks_raw: list, cameras: tuple[CameraInfo, ...], index: dict[str, int]) -> TrackArrays:
    """The tracks' arrays, every value checked: an InputError names the first that is wrong."""
    track_ids, cam_index, track_index, uv = [], [], [], []
    seen: set[int] = set()
    for ti, track in enumerate(tracks_raw):
        path = f"tracks[{ti}]"
        track_id = v.integer(v.require(track, "id", path), f"{path}.id")
        if track_id in seen:
            raise v.fail(f"{path}.id", f"duplicate track id {track_id}")
        seen.add(track_id)
        obs = v.require(track, "observations", path)
        if not isinstance(obs, dict):
            raise v.fail(f"{path}.observations", "expected an object of camera id -> [u, v]")
        for cam_id, pixel in obs.items():
            opath = f"{path}.observations.{cam_id}"
            if cam_id not in index:
                raise v.fail(opath, f"unknown camera id {cam_id!r}")
            if not isinstance(pixel, list) or len(pixel) != 2:
                raise v.fail(opath, "expected [u, v]")
            u_px = v.number(pixel[0], opath + "[0]")
            v_px = v.number(pixel[1], opath + "[1]")
            camera = cameras[index[cam_id]]
            v.pixel_in_image(u_px, v_px, camera.width, camera.height, opath)
            cam_index.append(index[cam_id])
            track_index.append(len(track_ids))
            uv.append((u_px, v_px))
        track_ids.append(track_id)
    return (np.asarray(track_ids, dtype=np.int64), np.asarray(cam_index, dtype=np.int64),
            np.asarray(track_index, dtype=np.int64), np.asarray(uv, dtype=float).reshape(-1, 2))


def _cap_tracks(tracks: list, max_tracks: int | None, seed: int | None) -> list:
    """`tracks`, or `max_tracks` of them drawn with `seed` (in their order); refused without a seed."""
    if max_tracks is None or len(tracks) <= max_tracks:
        return tracks
    if seed is None:
        raise v.fail("tracks", f"{len(tracks)} tracks, more than the {max_tracks} one solve takes; "
                     "subsample them (camnet calibrate --subsample-tracks)")
    keep = np.sort(np.random.default_rng(seed).choice(len(tracks), size=max_tracks, replace=False))
    return [tracks[i] for i in keep]


def observations_to_doc(obs: Observations) -> dict:
    """The ``camnet.observations/1`` document of `obs`."""
    doc = observations_head_to_doc(obs)
    tracks: list[dict] = [{"id": t, "observations": {}} for t in np.asarray(obs.track_ids).tolist()]
    # Lists of Python numbers made by numpy at once: a live pool holds tens of thousands of observations.
    names = [c.id for c in obs.cameras]
    uv = np.asarray(obs.uv, dtype=float).tolist()
    for cam, trk, uv_px in zip(np.asarray(obs.cam_index).tolist(), np.asarray(obs.track_index).tolist(), uv,
                               strict=True):
        tracks[trk]["observations"][names[cam]] = uv_px
    doc["tracks"] = tracks
    return doc


def observations_head_to_doc(obs: Observations) -> dict:
    """The ``camnet.observations/1`` document of `obs` but its tracks, which come last in the document."""
    cameras = []
    for c in obs.cameras:
        entry: dict[str, Any] = {"id": c.id, "width": c.width, "height": c.height}
        if c.model != LensModel.PINHOLE:  # the default stays implicit
            entry["model"] = c.model.value
        if c.K is not None:
            entry["K"] = np.asarray(c.K).tolist()
        if c.dist is not None:
            entry["dist"] = np.asarray(c.dist).tolist()
        if c.fixed:
            entry["fixed"] = sorted(c.fixed)
        cameras.append(entry)
    doc = {
        "format": OBSERVATIONS_FORMAT,
        "cameras": cameras,
        "stereo": _distance_doc({"left": obs.stereo.left, "right": obs.stereo.right}, obs.stereo),
    }
    if obs.baselines:
        doc["baselines"] = [_distance_doc({"cameras": [b.a, b.b]}, b) for b in obs.baselines]
    return doc


def _distance_doc(entry: dict, known: Stereo | Baseline) -> dict:
    """`entry` with the distance of `known` (baseline_m, and sigma_m unless exact, as the format has it)."""
    entry["baseline_m"] = known.baseline_m
    if known.sigma_m > 0:
        entry["sigma_m"] = known.sigma_m
    return entry


# ---------------------------------------------------------------- calibration


LEFT_FRAME = "left"  # the left stereo camera's frame, whatever its id (in memory: the id)
# A camera the document's world_from_left brings to within this of the origin, unturned, is the left camera.
LEFT_POSE_TOLERANCE = 1e-6


def _floor_frame_to_doc(frame: FloorFrame) -> dict:
    floor = ({"normal_sigma_deg": frame.normal_sigma_deg, "height_sigma_m": frame.height_sigma_m,
              **({"ambiguity": frame.ambiguity} if frame.ambiguity else {})} if frame.found
             else {"found": False, "reason": frame.reason})
    return {"world_from_left": {"R": np.asarray(frame.R).tolist(), "t": np.asarray(frame.t).tolist()},
            "floor": floor}


def calibration_to_doc(cal: Calibration) -> dict:
    """The ``camnet.calibration/1`` document of `cal`; its report adds the further keys.

    A calibration with a floor frame is written in it: cameras and points in the floor's frame, ``world_frame``
    "floor", then ``world_from_left`` and ``floor``, as the contract defines them.
    """
    frame = cal.floor_frame
    posed = in_world_frame(cal)
    cameras = []
    for cam in posed.cameras:
        model = {} if cam.model == LensModel.PINHOLE else {"model": cam.model.value}  # the default stays implicit
        cameras.append(
            {
                "id": cam.id,
                "width": cam.width,
                "height": cam.height,
                **model,
                "K": np.asarray(cam.K).tolist(),
                "dist": np.asarray(cam.dist).tolist(),
                "R": np.asarray(cam.R).tolist(),
                "t": np.asarray(cam.t).tolist(),
            }
        )
    doc = {
        "format": CALIBRATION_FORMAT,
        "world_frame": LEFT_FRAME if frame is None else FLOOR_FRAME,
        **({} if frame is None else _floor_frame_to_doc(frame)),
        "units": "m",
        "cameras": cameras,
        "points": [
            {"id": int(i), "xyz": [float(x) for x in p]} for i, p in zip(cal.point_ids, posed.points, strict=True)
        ],
        # A calibration that no observation went into (a factory stereo head) has no RMS; JSON has no NaN.
        "rms_reprojection_px": float(cal.rms_reprojection_px) if np.isfinite(cal.rms_reprojection_px) else None,
    }
    if cal.report is not None:
        doc.update(report_to_doc(cal.report))
        # Derived from the report (camnet.solve.report.verdict), so a reader never parses it back: it judges again.
        doc["verdict"] = verdict_to_doc(judge(cal))
    return doc


def _parse_camera_pose(c: Any, path: str) -> Camera:
    t = v.vector(v.require(c, "t", path), f"{path}.t", size=3)
    model = v.lens_model(c["model"], f"{path}.model") if "model" in c else LensModel.PINHOLE
    return Camera(
        id=v.JSON_IDS.read(v.require(c, "id", path), f"{path}.id"),
        width=v.image_side(v.require(c, "width", path), f"{path}.width"),
        height=v.image_side(v.require(c, "height", path), f"{path}.height"),
        K=v.intrinsic_matrix(v.require(c, "K", path), f"{path}.K"),
        dist=v.lens_dist(c["dist"], model, f"{path}.dist") if "dist" in c else np.zeros(model.dist_size),
        R=v.rotation(v.require(c, "R", path), f"{path}.R"),
        t=t,
        model=model,
    )


def parse_calibration(doc: Any) -> Calibration:
    """Validate a ``camnet.calibration/1`` document; its further keys, when present, become the report."""
    check_format(doc, CALIBRATION_FORMAT)
    cams_raw = v.non_empty_list(v.require(doc, "cameras", ""), "cameras")
    cameras = tuple(_parse_camera_pose(c, f"cameras[{i}]") for i, c in enumerate(cams_raw))
    ids, xyz = [], []
    for i, p in enumerate(v.array(doc.get("points", []), "points")):
        ids.append(v.integer(v.require(p, "id", f"points[{i}]"), f"points[{i}].id"))
        xyz.append(v.vector(v.require(p, "xyz", f"points[{i}]"), f"points[{i}].xyz", size=3))
    rms = doc.get("rms_reprojection_px", float("nan"))
    points = np.asarray(xyz, dtype=float).reshape(-1, 3)
    world_frame, frame = v.string(doc.get("world_frame", LEFT_FRAME), "world_frame"), None
    if world_frame == FLOOR_FRAME:
        frame = _parse_floor_frame(doc)
        # Back to the left camera's frame, in which a calibration is solved: X_left = R^T (X_world - t).
        cameras = tuple(in_frame(cam, frame.R.T, -frame.R.T @ frame.t) for cam in cameras)
        points = (points - frame.t) @ frame.R
        world_frame = _left_camera(cameras, "world_from_left: no camera lands at the left camera's origin, unturned, "
                                            "when the cameras are taken back with it (X_left = R^T (X_world - t)); "
                                            "it must map the left camera's frame to the world's")
    elif world_frame not in {c.id for c in cameras}:  # a camera's id: as earlier versions wrote it
        if world_frame != LEFT_FRAME:
            raise InputError(f'world_frame: "{world_frame}" is neither "{LEFT_FRAME}", "{FLOOR_FRAME}" nor a camera\'s '
                             "id; see the calibration format")
        world_frame = _left_camera(cameras, f'world_frame "{LEFT_FRAME}": no camera is at the origin, unturned '
                                            "(R = I, t = 0), as the left stereo camera must be")
    return Calibration(
        cameras=cameras,
        point_ids=np.asarray(ids, dtype=np.int64),
        points=points,
        rms_reprojection_px=float(rms) if isinstance(rms, int | float) else float("nan"),
        world_frame=world_frame,
        report=parse_report(doc),
        floor_frame=frame,
    )


def _parse_floor_frame(doc: Any) -> FloorFrame:
    pose = v.require(doc, "world_from_left", "")
    R = v.rotation(v.require(pose, "R", "world_from_left"), "world_from_left.R")
    t = v.vector(v.require(pose, "t", "world_from_left"), "world_from_left.t", size=3)
    floor = v.mapping(v.require(doc, "floor", ""), "floor")
    if "found" in floor and not v.boolean(floor["found"], "floor.found"):
        return FloorFrame(R, t, reason=v.string(floor.get("reason", ""), "floor.reason"))
    return FloorFrame(R, t, v.number(v.require(floor, "normal_sigma_deg", "floor"), "floor.normal_sigma_deg",
                                     minimum=0.0),
                      v.number(v.require(floor, "height_sigma_m", "floor"), "floor.height_sigma_m", minimum=0.0),
                      ambiguity=v.string(floor["ambiguity"], "floor.ambiguity") if "ambiguity" in floor else "")


def _left_camera(cameras: tuple[Camera, ...], wrong: str) -> str:
    """The id of the camera at the origin of the left camera's frame, unturned; InputError(`wrong`) without."""
    for cam in cameras:
        if np.allclose(cam.R, np.eye(3), atol=LEFT_POSE_TOLERANCE) and np.allclose(cam.t, 0.0,
                                                                                   atol=LEFT_POSE_TOLERANCE):
            return cam.id
    raise InputError(wrong)


def write_json_atomic(path: str | Path, doc: Any, *, private: bool = False) -> None:
    """Write `doc` as JSON so that `path` holds either the old file or the whole new one
    (readable by its owner only when `private`)."""
    from camnet.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(doc, indent=1, allow_nan=False) + "\n", private=private)
