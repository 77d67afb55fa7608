"""`camnet cameras` and `camnet init` against Aravis's GigE Vision camera emulator (and its in-process Fake).

The emulator is a real GenICam camera on 127.0.0.1 (tests/test_aravis.py
starts it, serialises its use among test runs and always stops it); no V4L2
device is present on a CI machine, which the listing must say cleanly.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
from camnet.drivers.base import FoundCamera

from camnet.commands.init import _ask, parse_length_m, pick_pair
from camnet.errors import InputError
from camnet.io.rig import AravisConfig, load_rig
from tests.test_aravis import _MISSING, emulator  # noqa: F401  (the fixture)
from tests.test_own_cameras import OPENCV_LOG_MARKS
from tests.test_viz import read_rrd

EMULATED = "Aravis-Fake-GV01"  # the emulator's device id: "<vendor>-<serial>"
IMAGES = f"/world/cameras/{EMULATED}/image"
needs_aravis = pytest.mark.skipif(_MISSING is not None, reason=_MISSING or "")


def camnet(*args: str, cwd: Path, stdin: str = "", timeout_s: float = 90.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], cwd=cwd, input=stdin, capture_output=True,
                          text=True, timeout=timeout_s)


def no_v4l2_device() -> bool:
    return not list(Path("/dev").glob("video*"))


@needs_aravis
def test_cameras_lists_the_emulated_camera_with_its_modes(emulator, tmp_path):  # noqa: F811
    proc = camnet("cameras", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    lines = proc.stdout.splitlines()
    if no_v4l2_device():
        assert lines[0] == "V4L2 devices: none found (no video capture device under /dev/video*)"
    at = next(i for i, line in enumerate(lines) if line.split()[:1] == [EMULATED])
    assert "Aravis Fake (serial GV01, GigEVision, 127.0.0.1)" in lines[at]
    assert lines[at + 1].split() == ["rig", "file:", "driver", "aravis,", "device_id:", f"{EMULATED},",
                                     "pixel_format:", "Mono8"]
    modes = lines[at + 2:at + 5]
    assert modes[0].split(": ")[0].strip() == "pixel formats" and "Mono8" in modes[0] and "RGB8" in modes[0]
    assert modes[1].strip() == "size: 512x512 now, 1x1 to 2048x2048"
    assert modes[2].strip().startswith("frame rate: 25 fps now, ")
    assert not any(mark in proc.stdout for mark in OPENCV_LOG_MARKS)


@needs_aravis
def test_preview_streams_the_cameras_to_rerun_and_stops_after_its_duration(emulator, tmp_path):  # noqa: F811
    rrd = tmp_path / "preview.rrd"
    proc = camnet("cameras", "--preview", "--duration-s", "4", "--rerun", f"save={rrd}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    shown = [line for line in proc.stdout.splitlines() if line.startswith(f"preview: {EMULATED}: ")]
    assert len(shown) == 1, proc.stdout
    # What it says it showed is what the recording holds. How many that is depends on how long the camera
    # took to open on this machine: that it streams is the next test's, waited for by progress.
    images = read_rrd(rrd)[IMAGES]["EncodedImage:blob"]
    assert len(images) == int(shown[0].split()[2]), proc.stdout
    assert (f"preview: streaming {EMULATED}" in proc.stdout) == (len(images) > 0), proc.stdout


@needs_aravis
def test_preview_stops_at_ctrl_c(emulator, tmp_path):  # noqa: F811
    rrd = tmp_path / "preview.rrd"
    proc = subprocess.Popen([sys.executable, "-m", "camnet", "cameras", "--preview", "--duration-s", "120",
                             "--rerun", f"save={rrd}"], cwd=tmp_path, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        lines = []
        # Progress, not a fixed delay: the camera streams, however long it took to open (within 120 s).
        while f"preview: streaming {EMULATED}\n" not in lines:
            line = proc.stdout.readline()
            assert line, f"camnet cameras ended early: {proc.wait(timeout=30)}; {lines} {proc.stderr.read()}"
            lines.append(line)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)  # past this, it did not stop at Ctrl-C
        assert proc.returncode == 0, stderr
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    shown = [line for line in stdout.splitlines() if line.startswith(f"preview: {EMULATED}: ")]
    images = read_rrd(rrd)[IMAGES]["EncodedImage:blob"]
    assert len(shown) == 1 and len(images) == int(shown[0].split()[2]) >= 1, stdout


@needs_aravis
def test_init_writes_a_rig_file_that_loads_and_never_overwrites_one(emulator, tmp_path):  # noqa: F811
    out = tmp_path / "rigs" / "lab.yaml"
    out.parent.mkdir()
    args = ("init", "--aravis-fake", "--pair", EMULATED, "Fake_1", "--baseline", "120mm", "-o", str(out))
    proc = camnet(*args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rig = load_rig(out)
    assert rig.name == "lab" and {c.id for c in rig.cameras} == {EMULATED, "Fake_1"}
    assert (rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m) == (EMULATED, "Fake_1", pytest.approx(0.12))
    emulated, fake = rig.camera(EMULATED).config, rig.camera("Fake_1").config
    assert isinstance(emulated, AravisConfig) and emulated.device_id == EMULATED
    assert fake.enable_fake_interface and not emulated.enable_fake_interface
    written = out.read_text()

    again = camnet(*args[:-2], "--baseline", "0.2 m", "-o", str(out), cwd=tmp_path)
    assert again.returncode == 2 and again.stdout == "", again.stdout
    assert again.stderr == f"camnet init: error: {out} exists; give --force to replace it, or -o another file\n"
    assert out.read_text() == written

    forced = camnet(*args[:-4], "--baseline", "20 cm", "-o", str(out), "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert load_rig(out).stereo.baseline_m == pytest.approx(0.2)


@needs_aravis
def test_init_asks_for_the_pair_and_a_baseline_with_its_unit(emulator, tmp_path):  # noqa: F811
    answers = "1\n1 2\n120\n120 mm\n"  # one camera named, then a bare number: each asked again
    proc = camnet("init", "--aravis-fake", cwd=tmp_path, stdin=answers)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "'120' has no unit; give it with one: 120 mm, 0.12 m or 12 cm" in proc.stdout
    assert "name two cameras" in proc.stdout
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.stereo.baseline_m == pytest.approx(0.12) and len(rig.cameras) == 2


@needs_aravis
def test_init_with_one_camera_says_a_rig_needs_two_and_writes_nothing(emulator, tmp_path):  # noqa: F811
    if not no_v4l2_device():
        pytest.skip("this host has V4L2 devices: the emulator is not its only camera")
    proc = camnet("init", "--pair", "1", "2", "--baseline", "12 cm", cwd=tmp_path)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("camnet init: error: found 1 camera(s) to use") and "needs two" in lines[0]
    assert not (tmp_path / "rig.yaml").exists()


@pytest.mark.parametrize(("flags", "message"), [
    (["--duration-s", "5"], "--duration-s: only with --preview"),
    (["--rerun", "spawn"], "--rerun: only with --preview"),
    (["--preview", "--duration-s", "0"], "--duration-s: must be positive, got 0.0"),
    (["--preview", "--rerun", "bogus"], "--rerun"),
])
def test_cameras_refuses_bad_flags_in_one_line_before_looking(tmp_path, flags, message):
    proc = camnet("cameras", *flags, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith(f"camnet cameras: error: {message}"), proc.stderr


def test_init_refuses_a_bare_baseline_before_looking_for_cameras(tmp_path):
    proc = camnet("init", "--pair", "a", "b", "--baseline", "120", cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == ("camnet init: error: --baseline: '120' has no unit; give it with one: "
                           "120 mm, 0.12 m or 12 cm\n")
    assert not (tmp_path / "rig.yaml").exists()


@pytest.mark.parametrize(("text", "metres"), [("120 mm", 0.12), ("120mm", 0.12), ("0.12 m", 0.12),
                                              ("12 cm", 0.12), (" 1.5e2 MM ", 0.15), (".5m", 0.5)])
def test_lengths_with_their_units(text, metres):
    assert parse_length_m(text) == pytest.approx(metres)


@pytest.mark.parametrize(("text", "why"), [("120", "has no unit"), ("12 in", "unknown unit 'in'"),
                                           ("0 mm", "longer than zero"), ("twelve cm", "is not a length"),
                                           ("-3 cm", "is not a length")])
def test_lengths_without_a_usable_unit_say_why(text, why):
    with pytest.raises(ValueError, match=why):
        parse_length_m(text)


def test_the_pair_is_named_by_ids_or_numbers():
    cams = [FoundCamera("v4l2", f"/dev/video{i}", "cam") for i in range(3)]
    assert pick_pair(["video2", "1"], cams) == (cams[2], cams[0])
    for words, why in ((["1"], "name two cameras"), (["1", "1"], "two different"), (["4", "1"], "no camera '4'")):
        with pytest.raises(ValueError, match=why):
            pick_pair(words, cams)


def test_asking_repeats_until_an_answer_parses_and_stops_at_the_end_of_input(monkeypatch, capsys):
    answers = iter(["120", "120 mm"])
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    assert _ask("baseline: ", parse_length_m) == pytest.approx(0.12)
    assert "has no unit" in capsys.readouterr().out

    def end(prompt):
        raise EOFError

    monkeypatch.setattr("builtins.input", end)
    with pytest.raises(InputError, match="give --pair LEFT RIGHT and --baseline LENGTH"):
        _ask("baseline: ", parse_length_m)


def test_cameras_without_any_camera_say_so_per_driver(tmp_path):
    if not no_v4l2_device():
        pytest.skip("this host has V4L2 devices")
    proc = camnet("cameras", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.splitlines()[0] == "V4L2 devices: none found (no video capture device under /dev/video*)"
    assert proc.stdout.splitlines()[1].startswith("GenICam cameras (Aravis): ")
