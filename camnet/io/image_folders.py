"""A folder of images as a rig's cameras: one camera per subfolder of frames, or one per image file.

The layouts camnet reads images in elsewhere:

- one subfolder per camera, named by its id, holding its frames (an image
  sequence of the v4l2 driver), or KITTI's layout: the frames in the
  subfolder's ``data/``; a ``timestamps.txt`` beside them (KITTI's format)
  gives their capture times;
- one image file per camera directly in the folder, its id the file name
  without its extension (`camnet match`).

Every image is read, so that its size is known and a file OpenCV cannot
read is named now, not when a driver meets it. Errors are InputErrors of one
line naming the file or folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from camnet.errors import InputError
from camnet.ids import validate_id

# What OpenCV's imread reads (the v4l2 driver's and camnet match's reader).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".pnm", ".webp", ".jp2")
TIMESTAMPS = "timestamps.txt"
KITTI_FRAMES = "data"  # KITTI raw: image_00/data/*.png beside image_00/timestamps.txt


@dataclass(frozen=True)
class ImageSource:
    """One camera's images: a sequence (`folder` holds its frames) or one image file (`folder` None)."""

    camera_id: str
    files: tuple[Path, ...]  # sorted by name
    width: int
    height: int
    colour: bool  # three or four channels in every image; else grey
    folder: Path | None
    timestamps: Path | None  # the sequence's timestamps file, when it has one


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _camera_id(name: str, where: Path) -> str:
    try:
        return validate_id(name, what=str(where))
    except InputError as exc:
        raise InputError(f"{exc}; a camera's id is its {'folder' if where.is_dir() else 'file'}'s name: rename it") \
            from None


def _measured(camera_id: str, files: list[Path], folder: Path | None, timestamps: Path | None) -> ImageSource:
    """The source of `files`, each read: InputError for one OpenCV cannot read, or sizes that differ."""
    import cv2

    types = sorted({p.suffix for p in files})
    if len(types) > 1:
        raise InputError(f"{folder}: images of several types ({', '.join(types)}); keep one type a camera (its "
                         "source is one file pattern)")
    first: tuple[Path, tuple[int, int]] | None = None
    colour = True
    for path in files:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"{path}: cannot be read as an image (OpenCV knows PNG, JPEG, TIFF, PGM, ...); "
                             "replace it or move it out of the folder")
        size = (image.shape[1], image.shape[0])
        colour = colour and image.ndim == 3 and image.shape[2] in (3, 4)
        if first is None:
            first = (path, size)
        elif size != first[1]:
            raise InputError(f"{folder}: images of two sizes, {first[0].name} {first[1][0]}x{first[1][1]} and "
                             f"{path.name} {size[0]}x{size[1]}; one camera's images share one size")
    return ImageSource(camera_id, tuple(files), first[1][0], first[1][1], colour, folder, timestamps)


def image_sources(directory: Path) -> tuple[ImageSource, ...]:
    """The cameras of the images in `directory`, in name order; InputError naming what is wrong."""
    if not directory.is_dir():
        raise InputError(f"{directory}: no such folder")
    files = _images(directory)
    folders = []
    for sub in sorted(p for p in directory.iterdir() if p.is_dir()):
        frames = sub / KITTI_FRAMES if not _images(sub) and (sub / KITTI_FRAMES).is_dir() else sub
        if _images(frames):
            folders.append((sub, frames))
    if files and folders:
        raise InputError(f"{directory}: holds both images ({files[0].name}, ...) and folders of images "
                         f"({folders[0][0].name}, ...); give one folder per camera, or one image per camera")
    if folders:
        sources = [_measured(_camera_id(sub.name, sub), _images(frames), frames,
                             sub / TIMESTAMPS if (sub / TIMESTAMPS).is_file() else None) for sub, frames in folders]
        stamped = [s.camera_id for s in sources if s.timestamps is not None]
        if stamped and len(stamped) < len(sources):
            bare = next(s for s in sources if s.timestamps is None)
            raise InputError(f"{bare.folder}: no {TIMESTAMPS}, while {', '.join(stamped)} have one: frames of "
                             "cameras replayed together pair by their capture times; give every camera one, or none")
        return tuple(sources)
    if files:
        ids: dict[str, Path] = {}
        for path in files:
            if path.stem in ids:
                raise InputError(f"{path}: a second image of camera {path.stem!r} (also {ids[path.stem].name}); "
                                 "one image per camera here, or one folder per camera for several")
            ids[path.stem] = path
        return tuple(_measured(_camera_id(path.stem, path), [path], None, None) for path in files)
    raise InputError(f"{directory}: no images ({', '.join(s[1:] for s in IMAGE_SUFFIXES[:4])}, ...); give a folder "
                     "with one subfolder of images per camera, or one image per camera")
