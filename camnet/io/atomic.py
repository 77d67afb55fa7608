"""Writing output files so that a reader finds the old content or the whole new one, never a part."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from camnet.errors import InputError

NEW_FILE_MODE = 0o644
PRIVATE_FILE_MODE = 0o600  # state a node keeps (a rig's calibration): its owner's alone
NEW_DIRECTORY_MODE = 0o755


def _parent(path: Path) -> Path:
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"{path}: directory {parent} does not exist")
    return parent


def _write_replace(path: Path, text: str | bytes, *, private: bool = False) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes the file private; an output file gets the usual mode, or keeps the one it had.
        if not private:
            os.fchmod(fd, path.stat().st_mode & 0o777 if path.exists() else NEW_FILE_MODE)
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str | bytes, *, default_name: str | None = None,
                      private: bool = False) -> Path:
    """Write `text` (or bytes, as they are) to `path` (temp file + rename) and return where it went.

    An existing directory `path` gets the file `default_name` inside it. A
    `private` file is readable by its owner only (PRIVATE_FILE_MODE), whatever
    mode the file it replaces had.
    """
    path = Path(path)
    if path.is_dir():
        if default_name is None:
            raise InputError(f"{path}: is a directory; name a file")
        path = path / default_name
    _parent(path)
    _write_replace(path, text, private=private)
    return path


def write_directory_atomic(path: str | Path, files: dict[str, str | bytes]) -> list[Path]:
    """Write ``{name: text or bytes}`` into the directory `path` and return the files' paths.

    A new directory appears whole (written beside it, then renamed); in an
    existing one each file is replaced atomically and other files are left
    alone. An existing non-directory `path` is an `InputError`.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a directory")
    if path.is_dir():
        for name, text in files.items():
            _write_replace(path / name, text)
        return [path / name for name in files]
    tmp = Path(tempfile.mkdtemp(dir=_parent(path), prefix=f".{path.name}.", suffix=".tmp"))
    try:
        tmp.chmod(NEW_DIRECTORY_MODE)
        for name, content in files.items():
            if isinstance(content, bytes):
                (tmp / name).write_bytes(content)
            else:
                (tmp / name).write_text(content)
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [path / name for name in files]
