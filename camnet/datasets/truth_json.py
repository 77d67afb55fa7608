"""The ``truth.json`` layout of data sets whose reference was converted to camnet's convention.

castle-P19, the webcams4 recording and the 220-degree fisheye rig carry
their reference as one JSON file: ``cameras``, each with ``id``, ``width``,
``height``, ``K`` (3x3, px, pixel centres at integers), ``dist`` (OpenCV's
order for its ``model``, empty: none), ``R`` and ``t`` (``x_cam = R @ X +
t``, metres, in the data set's world frame) and the image(s) it took, and a
``known_baseline_pair`` (``cameras``: two ids, ``baseline_m``). Camera ids
are strings as written there.

Images: a camera's ``images`` maps each frame name to its image; without
it, a data set's top-level ``frames`` name folders ``frames/<frame>/<id>.png``
(the webcams4 recording's extracted instants); without either, each
camera's ``image`` is one frame set. Paths are relative to the data set's
folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.model.camera import Camera, LensModel

TRUTH_FILE = "truth.json"
ONE_FRAME = "all"  # the frame name of a data set whose cameras each took one image


@dataclass(frozen=True)
class KnownPair:
    """Two cameras whose centre distance the data set names as the one to give."""

    left: str
    right: str
    baseline_m: float


@dataclass(frozen=True)
class TruthFile:
    """A data set's reference cameras (by id), its known pair and its frame sets' images."""

    root: Path
    cameras: dict[str, Camera]
    pair: KnownPair
    frames: dict[str, dict[str, Path]]  # frame name -> camera id -> image path, frames in the file's order


def _matrix(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected numbers") from None
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise InputError(f"{where}: expected {shape[0]}{'x' + str(shape[1]) if len(shape) > 1 else ''} "
                         "finite numbers")
    return array


def parse_camera(entry: Any, where: str) -> Camera:
    """One entry of ``cameras`` as a Camera (its lens model and dist as written)."""
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected an object")
    missing = [key for key in ("id", "width", "height", "K", "R", "t") if key not in entry]
    if missing:
        raise InputError(f"{where}: missing {', '.join(missing)}")
    try:
        model = LensModel(entry.get("model", LensModel.PINHOLE.value))
    except ValueError:
        raise InputError(f"{where}.model: expected pinhole or fisheye, got {entry.get('model')}") from None
    dist = np.array(entry.get("dist") or [], dtype=float)
    if model == LensModel.FISHEYE and len(dist) != model.dist_size:
        raise InputError(f"{where}.dist: a fisheye's dist is [k1, k2, k3, k4], got {len(dist)} numbers")
    if model == LensModel.PINHOLE:
        if len(dist) > model.dist_size:
            raise InputError(f"{where}.dist: at most [k1, k2, p1, p2, k3], got {len(dist)} numbers")
        dist = np.r_[dist, np.zeros(model.dist_size - len(dist))]
    return Camera(str(entry["id"]), int(entry["width"]), int(entry["height"]),
                  K=_matrix(entry["K"], (3, 3), f"{where}.K"), dist=dist,
                  R=_matrix(entry["R"], (3, 3), f"{where}.R"), t=_matrix(entry["t"], (3,), f"{where}.t"),
                  model=model)


def _frames(doc: dict, root: Path, ids: list[str], source: str) -> dict[str, dict[str, Path]]:
    entries = doc["cameras"]
    if all("images" in e for e in entries):
        names = list(doc.get("frames") or entries[0]["images"])
        try:
            return {f: {str(e["id"]): root / e["images"][f] for e in entries} for f in names}
        except KeyError as exc:
            raise InputError(f"{source}: a camera has no image of frame {exc.args[0]}") from None
    if doc.get("frames"):
        return {f: {c: root / "frames" / f / f"{c}.png" for c in ids} for f in doc["frames"]}
    if all("image" in e for e in entries):
        return {ONE_FRAME: {str(e["id"]): root / e["image"] for e in entries}}
    raise InputError(f"{source}: no images named (cameras[*].images, frames, or cameras[*].image)")


def parse_truth(doc: Any, root: Path, *, source: str = TRUTH_FILE) -> TruthFile:
    """The reference of a parsed ``truth.json`` whose data set lies in `root`."""
    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), list) or not doc["cameras"]:
        raise InputError(f"{source}: expected an object with a non-empty 'cameras' list")
    if doc.get("convention", "x_cam = R X + t") != "x_cam = R X + t" or doc.get("units", "m") != "m":
        raise InputError(f"{source}: convention {doc.get('convention')!r}, units {doc.get('units')!r}; "
                         "expected 'x_cam = R X + t' in metres")
    cameras = {}
    for k, entry in enumerate(doc["cameras"]):
        camera = parse_camera(entry, f"{source}: cameras[{k}]")
        if camera.id in cameras:
            raise InputError(f"{source}: cameras[{k}]: camera {camera.id!r} again")
        cameras[camera.id] = camera
    pair = doc.get("known_baseline_pair")
    if not isinstance(pair, dict) or len(pair.get("cameras") or []) != 2 or "baseline_m" not in pair:
        raise InputError(f"{source}: known_baseline_pair: expected {{cameras: [A, B], baseline_m: ...}}")
    left, right = (str(c) for c in pair["cameras"])
    unknown = [c for c in (left, right) if c not in cameras]
    if unknown:
        raise InputError(f"{source}: known_baseline_pair names camera {', '.join(unknown)}, which it does not hold")
    frames = _frames(doc, root, list(cameras), source)
    return TruthFile(root, cameras, KnownPair(left, right, float(pair["baseline_m"])), frames)


def read_truth(root: str | Path) -> TruthFile:
    """The reference of the data set in folder `root` (its ``truth.json``)."""
    path = Path(root) / TRUTH_FILE
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    return parse_truth(doc, Path(root), source=str(path))
