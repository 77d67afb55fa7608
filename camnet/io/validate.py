"""Typed reads of parsed documents (JSON, YAML) with errors that name the field.

Every check raises an `InputError` whose message starts with the field's path,
e.g. ``cameras[2].K: expected a 3x3 array``. Used by the observation and
calibration codecs, the rig file and the report.
"""

from __future__ import annotations

import difflib
import json
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.model.camera import LensModel
from camnet.model.observations import Baseline
from camnet.model.projection import full_dist

# R R^T = I to this, per entry: loose enough for a rotation typed into a rig file with
# six decimals, tight enough that a scaled or sheared matrix is refused.
ROTATION_TOLERANCE = 1e-5


MAX_INTEGER = 2**63 - 1  # ids and sizes are int64 wherever they go


def decode_json(data: bytes | str, source: str) -> Any:
    """The JSON value of `data` from `source` (a path, a bus key); anything that is not JSON is an InputError.

    json's own failures are many kinds: malformed text, bytes that are not
    UTF-8, nesting deep enough to exhaust the stack, integers longer than
    Python converts. Each is one line naming the source, so a file gets a
    clean refusal and a node can count it and go on.
    """
    try:
        return json.loads(data)
    except json.JSONDecodeError as exc:
        raise InputError(f"{source}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{source}: not UTF-8 text (byte {exc.start}); JSON must be UTF-8") from None
    except RecursionError:
        raise InputError(f"{source}: JSON nested too deeply for a camnet document") from None
    except ValueError as exc:  # e.g. an integer of thousands of digits
        raise InputError(f"{source}: not usable JSON ({str(exc).split(';')[0]})") from None


def fail(path: str, message: str) -> InputError:
    """The error for the field at `path` (the document itself when empty)."""
    return InputError(f"{path or 'document'}: {message}")


TYPO_CUTOFF = 0.6  # difflib's similarity from which an unknown key is taken for a typo of a known one


def unknown_key_error(key: Any, where: str, known: Collection[str]) -> InputError:
    """The error for `key` in the mapping at `where` (its path; "" for the whole file) of `known` keys,
    naming the known key it most resembles: ``unknown key 'baseline' in stereo (did you mean 'baseline_m'?)``."""
    close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=TYPO_CUTOFF)
    hint = f"did you mean {close[0]!r}?" if close else f"known: {', '.join(known)}"
    return InputError(f"unknown key {key!r} in {where or 'the rig file'} ({hint})")


def show(value: Any) -> str:
    """A short rendering of an offending value."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def kind(value: Any) -> str:
    return "nothing" if value is None else type(value).__name__


def mapping(value: Any, path: str) -> dict:
    if not isinstance(value, dict):
        raise fail(path, f"expected an object, got {kind(value)}")
    return value


def require(obj: Any, key: str, path: str) -> Any:
    """`obj[key]`; the error names `path.key` when it is missing."""
    mapping(obj, path)
    if key not in obj:
        raise fail(f"{path}.{key}" if path else key, "missing")
    return obj[key]


def non_empty_list(value: Any, path: str) -> list:
    """`value`, a list with at least one item."""
    if not isinstance(value, list) or not value:
        raise fail(path, "expected a non-empty list")
    return value


def number(value: Any, path: str, *, positive: bool = False, minimum: float | None = None) -> float:
    """A finite number (not a boolean): an integer beyond a float's range is none."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(_float(value)):
        raise fail(path, f"expected a finite number, got {show(value)}")
    if positive and value <= 0:
        raise fail(path, f"must be positive, got {value!r}")
    if minimum is not None and value < minimum:
        raise fail(path, f"must be at least {minimum}, got {value!r}")
    return float(value)


def _float(value: int | float) -> float:
    """`value` as a float; infinity for an integer too large for one (float() raises there)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def optional_number(value: Any, path: str) -> float | None:
    """A finite number, or None for null."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise fail(path, f"expected a number or null, got {show(value)}")
    return number(value, path)


def integer(value: Any, path: str, *, positive: bool = False) -> int:
    """An integer (not a boolean)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise fail(path, f"expected an integer, got {show(value)}")
    if abs(value) > MAX_INTEGER:
        raise fail(path, f"integer out of range (at most {MAX_INTEGER} in magnitude), got {show(value)}")
    if positive and value <= 0:
        raise fail(path, f"must be positive, got {value!r}")
    return int(value)


def string(value: Any, path: str, *, choices: tuple[str, ...] = ()) -> str:
    """A non-empty string, one of `choices` when given."""
    if not isinstance(value, str) or not value:
        raise fail(path, f"expected a non-empty string, got {show(value)}")
    if choices and value not in choices:
        raise fail(path, f"unknown value {value!r} (expected {', '.join(choices)})")
    return value


@dataclass(frozen=True)
class Ids:
    """Reads ids (of cameras, of a rig) from a document of one syntax: JSON, or YAML with `yaml`.

    A number or a boolean where an id belongs is refused saying to quote it,
    in that syntax. YAML reads an unquoted ``0006`` as the number 6 and
    ``on`` as true, and the spelling is gone from the value: `spellings`
    (the text of each unquoted scalar by its path, where the YAML text is
    at hand) lets the message show it as written.
    """

    yaml: bool = False
    spellings: Mapping[str, str] = field(default_factory=dict)

    def read(self, value: Any, path: str) -> str:
        """`value`, a non-empty string; else the error naming `path` and, for a number, how to quote it."""
        if isinstance(value, str) and value:
            return value
        if not isinstance(value, bool | int | float):
            raise fail(path, f"expected an id (a non-empty string), got {show(value)}")
        key = path.rsplit(".", 1)[-1]
        quoted = (lambda text: f'"{text}"') if "[" in key else (  # an item of a list: the item alone
            (lambda text: f'{key}: "{text}"') if self.yaml else (lambda text: f'"{key}": "{text}"'))
        read_as = ("true" if value else "false") if isinstance(value, bool) else f"the number {value!r}"
        if not self.yaml:
            raise fail(path, f"ids are strings, got {read_as}; quote it: {quoted(value)}")
        spelling = self.spellings.get(path)
        if spelling is not None:
            lost = ", losing how it was written" if spelling != str(value).lower() else ""
            raise fail(path, f"ids are strings, but YAML reads the unquoted {spelling} as {read_as}{lost}; quote it: "
                       f"{quoted(spelling)}")
        example = ("on", "an unquoted yes, no, on or off is a boolean") if isinstance(value, bool) else (
            "0006", "an unquoted 0006 is the number 6, its leading zeros dropped")
        raise fail(path, f"ids are strings, but YAML read this one as {read_as}, and how it was written is lost "
                   f"({example[1]}); quote it as written, e.g. {quoted(example[0])}")


JSON_IDS = Ids()


def boolean(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise fail(path, f"expected true or false, got {show(value)}")
    return value


def array(value: Any, path: str) -> list:
    if not isinstance(value, list):
        raise fail(path, f"expected a list, got {kind(value)}")
    return value


def strings(value: Any, path: str) -> tuple[str, ...]:
    """A list of strings (possibly empty)."""
    return tuple(string(x, f"{path}[{i}]") for i, x in enumerate(array(value, path)))


def vector(value: Any, path: str, *, size: int | None = None, max_size: int | None = None) -> np.ndarray:
    """A list of finite numbers: exactly `size` of them, or at most `max_size`."""
    if not isinstance(value, list | tuple) or (size is not None and len(value) != size):
        raise fail(path, f"expected {size} numbers, got {show(value)}")
    if max_size is not None and len(value) > max_size:
        raise fail(path, f"expected a list of at most {max_size} numbers, got {show(value)}")
    return np.array([number(x, f"{path}[{i}]") for i, x in enumerate(value)], dtype=float)


def lens_model(value: Any, path: str) -> LensModel:
    """A camera's lens model by name (pinhole or fisheye)."""
    return LensModel(string(value, path, choices=tuple(LensModel)))


# Distortion coefficients of real lenses in OpenCV's models (normalised image coordinates)
# stay within a few units; beyond these the number is a typo or another model's, and the
# projection would fold the image over itself.
MAX_RADIAL_COEFFICIENT = 100.0  # |k1|, |k2|, |k3| of a pinhole, |k1..k4| of a fisheye
MAX_TANGENTIAL_COEFFICIENT = 1.0  # |p1|, |p2|


def _bounded_dist(dist: np.ndarray, model: LensModel, path: str) -> np.ndarray:
    tangential = (2, 3) if model == LensModel.PINHOLE else ()
    for i, k in enumerate(dist):
        bound = MAX_TANGENTIAL_COEFFICIENT if i in tangential else MAX_RADIAL_COEFFICIENT
        if abs(k) > bound:
            raise fail(f"{path}[{i}]", f"{k:g} is no distortion coefficient of a real lens (|value| <= {bound:g}); "
                       "check the order (OpenCV's) and the lens model")
    return dist


def lens_dist(value: Any, model: LensModel, path: str) -> np.ndarray:
    """A camera's distortion in `model`'s order: a fisheye's exactly [k1, k2, k3, k4], a pinhole's
    at most [k1, k2, p1, p2, k3] (padded with zeros); each within the bounds above."""
    if model == LensModel.FISHEYE:
        if not isinstance(value, list | tuple) or len(value) != model.dist_size:
            raise fail(path, f"a fisheye's dist is [k1, k2, k3, k4]: expected 4 numbers, got {show(value)}")
        return _bounded_dist(vector(value, path), model, path)
    if isinstance(value, list | tuple) and len(value) > model.dist_size:
        raise fail(path, f"a pinhole's dist is at most [k1, k2, p1, p2, k3], got {len(value)} numbers "
                         '(a fisheye lens: give "model": "fisheye" and [k1, k2, k3, k4])')
    return _bounded_dist(full_dist(vector(value, path)), model, path)


def intrinsic_matrix(value: Any, path: str) -> np.ndarray:
    """A camera matrix K: positive focal lengths, zero below the diagonal, last row [0, 0, 1]."""
    K = matrix(value, 3, 3, path)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise fail(path, "focal lengths must be positive")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise fail(path, f"not a camera matrix: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got rows 2-3 "
                   f"{K[1].tolist()}, {K[2].tolist()}")
    return K


# An image side fits the frame header's 16 bits (camnet.bus.frame.MAX_SIDE_PX).
MAX_SIDE_PX = 65535


def image_side(value: Any, path: str) -> int:
    """An image width or height in pixels: 1 to MAX_SIDE_PX."""
    side = integer(value, path, positive=True)
    if side > MAX_SIDE_PX:
        raise fail(path, f"{side} px is larger than any camera's image (at most {MAX_SIDE_PX})")
    return side


# A measured pixel lies in its image; sub-pixel refinement may put one a little outside.
PIXEL_MARGIN_REL = 0.05  # of the image's side


def pixel_in_image(u_px: float, v_px: float, width: int, height: int, path: str) -> None:
    """Refuse a pixel outside its width x height image by more than PIXEL_MARGIN_REL of a side."""
    mu, mv = PIXEL_MARGIN_REL * width, PIXEL_MARGIN_REL * height
    if not (-0.5 - mu <= u_px <= width - 0.5 + mu and -0.5 - mv <= v_px <= height - 0.5 + mv):
        raise fail(path, f"pixel ({u_px:g}, {v_px:g}) is outside the camera's {width}x{height} image "
                   f"(u from -0.5 to {width - 0.5:g}, v from -0.5 to {height - 0.5:g}, give or take "
                   f"{100 * PIXEL_MARGIN_REL:g}%); were the pixels measured in an image of another size?")


def matrix(value: Any, rows: int, cols: int, path: str) -> np.ndarray:
    """A rows x cols list of lists of finite numbers."""
    if not isinstance(value, list) or len(value) != rows:
        raise fail(path, f"expected a {rows}x{cols} array")
    out = np.empty((rows, cols))
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != cols:
            raise fail(f"{path}[{i}]", f"expected {cols} numbers")
        for j, x in enumerate(row):
            out[i, j] = number(x, f"{path}[{i}][{j}]")
    return out


def rotation(value: Any, path: str) -> np.ndarray:
    """A 3x3 rotation matrix (orthonormal to ROTATION_TOLERANCE, determinant +1)."""
    R = matrix(value, 3, 3, path)
    if not np.allclose(R @ R.T, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(R) <= 0:
        raise fail(path, "not a rotation matrix (R R^T = I, det R = 1)")
    return R


BASELINE_KEYS = ("cameras", "baseline_m", "sigma_m")


# Distances between the centres of cameras that calibrate together: a phone's stereo pair
# (about 1 cm) to a hall's (tens of metres). Outside, the number is almost surely in
# other units (125 for 125 mm): the solve would put every point that many times too far.
PLAUSIBLE_DISTANCE_M = (0.005, 50.0)
# Beyond these even a distance kept on purpose is refused: the solve's squares and products of lengths
# would leave the floats' range, and no rig spans them.
SOLVABLE_DISTANCE_M = (1e-6, 1e6)
ANY_DISTANCE_FLAG = "accept_any_distance"
# How to keep such a distance on purpose, by where it was read. A rig file says so itself, so that every
# node reading it agrees (`camnet up`, `camnet match` and the nodes take no flag for it); an observations
# file is kept by the command that solves it.
KEEP_IN_RIG_FILE = f"write `{ANY_DISTANCE_FLAG}: true` at the top level of the rig file"
KEEP_BY_FLAG = "give --accept-any-distance"


def plausible_distance(distance_m: float, path: str, *, keep: str, any_distance: bool = False) -> float:
    """`distance_m`, refused with the range and the unit when it is no distance between cameras; the
    error ends with `keep`, how to keep it all the same (KEEP_IN_RIG_FILE, KEEP_BY_FLAG)."""
    low, high = SOLVABLE_DISTANCE_M
    if not low <= distance_m <= high:
        raise fail(path, f"{distance_m:g} m is no distance between cameras that camnet can solve with "
                   f"({low:g} to {high:g} m, even kept on purpose)")
    low, high = PLAUSIBLE_DISTANCE_M
    if any_distance or low <= distance_m <= high:
        return distance_m
    hint = (f"{distance_m:g} mm = {distance_m / 1000:g}" if distance_m > high
            else f"{distance_m:g} km = {distance_m * 1000:g}")
    raise fail(path, f"{distance_m:g} m is not a distance between cameras (expected {low:g} to {high:g} m); "
               f"distances are given in metres ({hint}); to keep it, {keep}")


def baselines(
    value: Any, path: str, camera_ids: Collection[str], stereo: tuple[str, str] | None, *, keep: str,
    strict: bool = False, any_distance: bool = False, ids: Ids = JSON_IDS,
) -> tuple[Baseline, ...]:
    """Known distances between camera centres: a list of ``{cameras: [a, b], baseline_m, sigma_m}``.

    sigma_m (metres, optional, absent or null: 0, exact). camera_ids: the
    cameras they may name; stereo: the stereo pair (left, right), whose
    distance is given by the stereo section; strict: refuse unknown keys (rig
    files) instead of ignoring them (JSON documents); any_distance: accept
    distances outside PLAUSIBLE_DISTANCE_M; keep: how to (`plausible_distance`);
    ids: how the document's syntax reads camera ids.
    """
    given = {frozenset(stereo): "stereo.baseline_m"} if stereo is not None else {}
    out = []
    for i, entry in enumerate(array(value, path)):
        here = f"{path}[{i}]"
        mapping(entry, here)
        unknown = sorted(set(entry) - set(BASELINE_KEYS), key=str) if strict else []
        if unknown:
            raise unknown_key_error(unknown[0], here, BASELINE_KEYS)
        cameras = require(entry, "cameras", here)
        if not isinstance(cameras, list) or len(cameras) != 2:
            raise fail(f"{here}.cameras", f"expected [a, b], two camera ids, got {show(cameras)}")
        a, b = (ids.read(c, f"{here}.cameras[{j}]") for j, c in enumerate(cameras))
        for cam_id in (a, b):
            if cam_id not in camera_ids:
                raise fail(f"{here}.cameras", f"unknown camera {cam_id!r}")
        if a == b:
            raise fail(f"{here}.cameras", f"the same camera {a!r} twice; a distance needs two cameras")
        if frozenset((a, b)) in given:
            raise fail(f"{here}.cameras", f"the distance of {a!r} and {b!r} is already given by "
                       f"{given[frozenset((a, b))]}; give it once")
        given[frozenset((a, b))] = here
        distance_m = plausible_distance(number(require(entry, "baseline_m", here), f"{here}.baseline_m",
                                               positive=True), f"{here}.baseline_m", keep=keep,
                                        any_distance=any_distance)
        sigma = entry.get("sigma_m")
        sigma_m = 0.0 if sigma is None else number(sigma, f"{here}.sigma_m", minimum=0.0)
        out.append(Baseline(a, b, distance_m, sigma_m))
    return tuple(out)
