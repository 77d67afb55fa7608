"""The V4L2 capture devices of this host and their modes, asked of the kernel (`camnet cameras`).

OpenCV opens a device but cannot list what it offers, so the modes come from
the V4L2 ioctls themselves: VIDIOC_QUERYCAP (name, and whether the node
captures video: a webcam's second node often carries only metadata),
VIDIOC_ENUM_FMT, VIDIOC_ENUM_FRAMESIZES and VIDIOC_ENUM_FRAMEINTERVALS.
Nothing is streamed and nothing is changed on the device.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import struct
from pathlib import Path

from camnet.drivers.base import FoundCamera


def _iowr(nr: int, size: int, *, read_only: bool = False) -> int:
    direction = 2 if read_only else 3  # _IOR, _IOWR
    return (direction << 30) | (size << 16) | (ord("V") << 8) | nr


_CAP = struct.Struct("16s32s32sIII3I")  # struct v4l2_capability
_FMT = struct.Struct("III32sII3I")  # struct v4l2_fmtdesc
_SIZE = struct.Struct("III6I2I")  # struct v4l2_frmsizeenum
_IVAL = struct.Struct("IIIII6I2I")  # struct v4l2_frmivalenum
VIDIOC_QUERYCAP = _iowr(0, _CAP.size, read_only=True)
VIDIOC_ENUM_FMT = _iowr(2, _FMT.size)
VIDIOC_ENUM_FRAMESIZES = _iowr(74, _SIZE.size)
VIDIOC_ENUM_FRAMEINTERVALS = _iowr(75, _IVAL.size)
BUF_TYPE_VIDEO_CAPTURE = 1
CAP_VIDEO_CAPTURE = 0x1
CAP_DEVICE_CAPS = 0x80000000
DISCRETE = 1
MAX_ENTRIES = 64  # per enumeration: a driver that never ends its list is cut off here


def device_paths(dev_dir: Path = Path("/dev")) -> list[Path]:
    """/dev/video0, /dev/video1, ... in numeric order."""
    found = [p for p in dev_dir.glob("video*") if re.fullmatch(r"video\d+", p.name)]
    return sorted(found, key=lambda p: int(p.name[5:]))


def _enumerate(fd: int, request: int, layout: struct.Struct, head: tuple) -> list[tuple]:
    """The entries of one V4L2 enumeration: index 0, 1, ... until the driver says EINVAL."""
    entries = []
    for index in range(MAX_ENTRIES):
        buffer = bytearray(layout.size)  # the request's leading u32 fields: index, then `head`
        struct.pack_into(f"{1 + len(head)}I", buffer, 0, index, *head)
        try:
            fcntl.ioctl(fd, request, buffer)
        except OSError as exc:
            if exc.errno == errno.EINVAL:
                break
            raise
        entries.append(layout.unpack(buffer))
    return entries


def _fps(fd: int, fourcc: int, width: int, height: int) -> str:
    intervals = _enumerate(fd, VIDIOC_ENUM_FRAMEINTERVALS, _IVAL, (fourcc, width, height))
    if not intervals:
        return ""
    if intervals[0][4] != DISCRETE:  # stepwise or continuous: min interval = max rate
        (_, _, _, _, _, min_num, min_den, max_num, max_den, *_) = intervals[0]
        return f" at {max_den / max(max_num, 1):g}-{min_den / max(min_num, 1):g} fps"
    rates = [den / num for (_, _, _, _, _, num, den, *_) in intervals if num]
    return " at " + ", ".join(f"{r:g}" for r in rates) + " fps"


def _modes(fd: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(mode lines, fourccs) of a capture device."""
    lines, fourccs = [], []
    for _, _, _, description, pixelformat, *_ in _enumerate(fd, VIDIOC_ENUM_FMT, _FMT, (BUF_TYPE_VIDEO_CAPTURE,)):
        fourcc = pixelformat.to_bytes(4, "little").decode("ascii", "replace").strip()
        fourccs.append(fourcc)
        name = _text(description)
        sizes = _enumerate(fd, VIDIOC_ENUM_FRAMESIZES, _SIZE, (pixelformat,))
        if not sizes:
            lines.append(f"{fourcc} ({name})")
        for _, _, kind, *dims in sizes:
            if kind == DISCRETE:
                lines.append(f"{fourcc} {dims[0]}x{dims[1]}{_fps(fd, pixelformat, dims[0], dims[1])}")
            else:
                min_w, max_w, _, min_h, max_h, _ = dims[:6]
                lines.append(f"{fourcc} {min_w}x{min_h} to {max_w}x{max_h}")
    return tuple(lines), tuple(fourccs)


def _text(field: bytes) -> str:
    """A NUL-terminated string of a V4L2 struct."""
    return field.split(b"\0", 1)[0].decode(errors="replace")


def probe(path: Path) -> FoundCamera | None:
    """The device at `path` with its modes; None for a node that captures no video (metadata)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    except OSError as exc:
        hint = " (add your user to group 'video')" if exc.errno == errno.EACCES else ""
        return FoundCamera("v4l2", str(path), "?", problem=f"cannot open: {exc.strerror}{hint}")
    try:
        buffer = bytearray(_CAP.size)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, buffer)
        driver, card, bus, _, capabilities, device_caps, *_ = _CAP.unpack(buffer)
        caps = device_caps if capabilities & CAP_DEVICE_CAPS else capabilities
        if not caps & CAP_VIDEO_CAPTURE:
            return None
        description = f"{_text(card)} ({_text(driver)}, {_text(bus)})"
        modes, fourccs = _modes(fd)
        return FoundCamera("v4l2", str(path), description, modes=modes, pixel_formats=fourccs)
    except OSError as exc:
        return FoundCamera("v4l2", str(path), "?", problem=f"cannot ask it its modes: {exc.strerror}")
    finally:
        os.close(fd)


def discover(dev_dir: Path = Path("/dev")) -> list[FoundCamera]:
    """Every V4L2 video capture device under `dev_dir`, each with its modes or what failed."""
    return [found for found in map(probe, device_paths(dev_dir)) if found is not None]
