"""The V4L2 device listing of `camnet cameras`: the kernel's answers read right, and no device said cleanly.

No V4L2 device is needed: a fake `ioctl` answers as a webcam's driver would
(a capture node with MJPG at discrete sizes and rates and YUYV stepwise, and
a metadata node that is not listed).
"""

from __future__ import annotations

import errno
import struct

import pytest
from camnet.drivers import v4l2_devices as vd


def fourcc(text: str) -> int:
    return int.from_bytes(text.encode(), "little")


class FakeWebcam:
    """ioctl answers of /dev/video0 (a capture node) and /dev/video1 (its metadata node)."""

    def __init__(self) -> None:
        self.fds = {}

    def open(self, path, flags):
        fd = 100 + len(self.fds)
        self.fds[fd] = str(path)
        return fd

    def close(self, fd):
        self.fds.pop(fd)

    def ioctl(self, fd, request, buffer):
        capture = self.fds[fd].endswith("video0")
        index = struct.unpack_from("I", buffer)[0]
        if request == vd.VIDIOC_QUERYCAP:
            caps = vd.CAP_VIDEO_CAPTURE if capture else 0x00800000  # V4L2_CAP_META_CAPTURE
            vd._CAP.pack_into(buffer, 0, b"uvcvideo", b"HD Webcam", b"usb-0000:00:14.0-1", 0,
                              caps | vd.CAP_DEVICE_CAPS, caps, 0, 0, 0)
        elif request == vd.VIDIOC_ENUM_FMT:
            formats = [("MJPG", b"Motion-JPEG"), ("YUYV", b"YUYV 4:2:2")]
            if index >= len(formats):
                raise OSError(errno.EINVAL, "end")
            vd._FMT.pack_into(buffer, 0, index, 1, 0, formats[index][1], fourcc(formats[index][0]), 0, 0, 0, 0)
        elif request == vd.VIDIOC_ENUM_FRAMESIZES:
            pixelformat = struct.unpack_from("I", buffer, 4)[0]
            if pixelformat == fourcc("MJPG") and index < 2:
                size = [(1920, 1080), (640, 480)][index]
                vd._SIZE.pack_into(buffer, 0, index, pixelformat, vd.DISCRETE, *size, 0, 0, 0, 0, 0, 0)
            elif pixelformat == fourcc("YUYV") and index == 0:
                vd._SIZE.pack_into(buffer, 0, 0, pixelformat, 3, 160, 1280, 16, 120, 720, 8, 0, 0)
            else:
                raise OSError(errno.EINVAL, "end")
        elif request == vd.VIDIOC_ENUM_FRAMEINTERVALS:
            _, pixelformat, width, height = struct.unpack_from("4I", buffer)
            rates = [30, 15] if width == 1920 else [60]
            if index >= len(rates):
                raise OSError(errno.EINVAL, "end")
            vd._IVAL.pack_into(buffer, 0, index, pixelformat, width, height, vd.DISCRETE, 1, rates[index],
                               0, 0, 0, 0, 0, 0)
        else:
            raise OSError(errno.ENOTTY, "not a V4L2 ioctl")


def test_a_webcam_is_listed_with_its_modes_and_its_metadata_node_is_not(tmp_path, monkeypatch):
    for name in ("video1", "video0", "video10", "videoX"):
        (tmp_path / name).touch()
    webcam = FakeWebcam()
    monkeypatch.setattr(vd.os, "open", webcam.open)
    monkeypatch.setattr(vd.os, "close", webcam.close)
    monkeypatch.setattr(vd.fcntl, "ioctl", webcam.ioctl)
    assert [p.name for p in vd.device_paths(tmp_path)] == ["video0", "video1", "video10"]
    found = [vd.probe(tmp_path / "video0"), vd.probe(tmp_path / "video1")]
    assert found[1] is None
    cam = found[0]
    assert cam.device == str(tmp_path / "video0") and cam.suggested_id.endswith("video0")
    assert cam.description == "HD Webcam (uvcvideo, usb-0000:00:14.0-1)" and cam.problem is None
    assert cam.modes == ("MJPG 1920x1080 at 30, 15 fps", "MJPG 640x480 at 60 fps", "YUYV 160x120 to 1280x720")
    assert cam.pixel_formats == ("MJPG", "YUYV")
    assert webcam.fds == {}, "a device was left open"


def test_a_device_that_cannot_be_opened_is_listed_with_why(tmp_path, monkeypatch):
    def refuse(path, flags):
        raise OSError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(vd.os, "open", refuse)
    cam = vd.probe(tmp_path / "video0")
    assert cam.problem == "cannot open: Permission denied (add your user to group 'video')"


def test_no_device_is_an_empty_list(tmp_path):
    assert vd.discover(tmp_path) == []


@pytest.mark.parametrize(("request_", "number"), [(vd.VIDIOC_QUERYCAP, 0x80685600),
                                                  (vd.VIDIOC_ENUM_FMT, 0xC0405602),
                                                  (vd.VIDIOC_ENUM_FRAMESIZES, 0xC02C564A),
                                                  (vd.VIDIOC_ENUM_FRAMEINTERVALS, 0xC034564B)])
def test_request_numbers_are_the_kernels(request_, number):
    assert request_ == number  # linux/videodev2.h on 64-bit Linux
