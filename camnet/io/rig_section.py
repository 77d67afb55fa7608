"""Typed reads of one mapping of the rig file, with errors naming the field path.

A section knows its keys: a key it does not know is refused when the section
is made, before any of its values is read, and named with the known key it
most resembles (``unknown key 'baseline' in stereo (did you mean
'baseline_m'?)``), so that a typo never silently becomes a default, nor hides
behind the "missing" of the key it was meant to be.
"""

from __future__ import annotations

import difflib
import glob
from pathlib import Path
from typing import Any

import numpy as np

from camnet.errors import InputError
from camnet.io import validate as v
from camnet.model.camera import LensModel

YAML_IDS = v.Ids(yaml=True)


class Section:
    """A mapping at `path` whose keys are all among `known`.

    A key that is absent or null takes `default` (required when none is given).
    `base_dir`: the directory a relative path in it is relative to (the rig
    file's), None to keep paths as given. `ids`: how its ids are read (YAML's
    syntax, with the rig file's spellings where known).
    """

    def __init__(self, data: Any, path: str, known: tuple[str, ...], *, base_dir: Path | None = None,
                 ids: v.Ids = YAML_IDS) -> None:
        if not isinstance(data, dict):
            raise InputError(f"{path or 'rig file'}: expected a mapping, got {v.kind(data)}")
        unknown = [key for key in data if key not in known]
        if unknown:  # a typo first: the stray key most like a known one
            typos = [k for k in unknown if difflib.get_close_matches(str(k), known, n=1, cutoff=v.TYPO_CUTOFF)]
            raise v.unknown_key_error((typos or unknown)[0], path, known)
        self.data = data
        self.path = path
        self.known = known
        self.base_dir = base_dir
        self.ids = ids

    def field(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def raw(self, key: str, default: Any = ..., *, required: bool = False) -> Any:
        if key not in self.known:
            raise AssertionError(f"{self.path}: {key!r} is read but not among its known keys")
        if key not in self.data or self.data[key] is None:
            if required or default is ...:
                raise InputError(f"{self.field(key)}: missing")
            return default
        return self.data[key]

    def section(self, key: str, known: tuple[str, ...], *, required: bool = True) -> Section:
        value = self.raw(key, {} if not required else ..., required=required)
        return Section(value, self.field(key), known, base_dir=self.base_dir, ids=self.ids)

    def _read(self, key: str, default: Any, check, *args, **kwargs) -> Any:
        value = self.raw(key, default)
        if value is default and default is not ...:
            return value
        return check(value, self.field(key), *args, **kwargs)

    def number(self, key: str, default: Any = ..., *, positive: bool = False, minimum: float | None = None) -> float:
        return self._read(key, default, v.number, positive=positive, minimum=minimum)

    def integer(self, key: str, default: Any = ..., *, positive: bool = False) -> int:
        return self._read(key, default, v.integer, positive=positive)

    def side(self, key: str, default: Any = ...) -> int:
        """An image width or height (1 to camnet.io.validate.MAX_SIDE_PX)."""
        return self._read(key, default, v.image_side)

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] = ()) -> str:
        return self._read(key, default, v.string, choices=choices)

    def path_string(self, key: str, default: Any = ..., *, pattern: bool = False) -> str:
        """A file path (a glob `pattern`): a relative one is taken relative to `base_dir`."""
        value = self.string(key, default)
        if value is None or self.base_dir is None or Path(value).is_absolute():
            return value
        base = glob.escape(str(self.base_dir)) if pattern else str(self.base_dir)
        return str(Path(base) / value)

    def identifier(self, key: str) -> str:
        """A required id (a camera's, the rig's): a non-empty string; a number is refused saying to quote it."""
        return self.ids.read(self.raw(key, required=True), self.field(key))

    def boolean(self, key: str, default: bool) -> bool:
        return v.boolean(self.raw(key, default), self.field(key))

    def matrix(self, key: str, rows: int, cols: int, default: Any = ...) -> np.ndarray:
        return self._read(key, default, lambda value, path: v.matrix(value, rows, cols, path))

    def rotation(self, key: str, default: Any = ...) -> np.ndarray:
        return self._read(key, default, v.rotation)

    def dist(self, key: str, model: LensModel, default: Any = ...) -> np.ndarray:
        """OpenCV distortion in `model`'s order (camnet.io.validate.lens_dist)."""
        return self._read(key, default, lambda value, path: v.lens_dist(value, model, path))

    def vector(self, key: str, size: int, default: Any = ...) -> tuple[float, ...]:
        return self._read(key, default, lambda value, path: tuple(v.vector(value, path, size=size).tolist()))
