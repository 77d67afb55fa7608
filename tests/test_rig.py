import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from camnet.errors import InputError
from camnet.io.rig import AravisConfig, V4l2Config, load_rig, parse_rig
from camnet.model.projection import look_at
from camnet.sim.config import SimConfig
from camnet.solve.options import World

CONFIG = Path(__file__).resolve().parent.parent / "config"


def base() -> dict:
    return {
        "rig": "r",
        "stereo": {"left": "a", "right": "b", "baseline_m": 0.1},
        "cameras": [
            {"id": "a", "driver": "sim", "sim": {"width": 64, "height": 48, "f_px": 50}},
            {"id": "b", "driver": "sim", "sim": {"width": 64, "height": 48, "f_px": 50}},
            {"id": "c", "driver": "v4l2", "v4l2": {"source": "/dev/video0"}},
        ],
    }


def refused(change, match: str) -> None:
    data = copy.deepcopy(base())
    change(data)
    with pytest.raises(InputError, match=match):
        parse_rig(data, source="rig.yaml")


def test_default_sim_rig_is_the_papers():
    rig = load_rig(CONFIG / "sim.yaml")
    assert rig.name == "sim"
    assert [c.id for c in rig.cameras] == ["left", "right", "mono_a", "mono_b"]
    assert (rig.stereo.left, rig.stereo.right, rig.stereo.baseline_m) == ("left", "right", 0.125)
    cams = {c.id: c.config.camera(c.id) for c in rig.cameras}
    for entry in rig.cameras:
        cfg = entry.config
        assert isinstance(cfg, SimConfig)
        assert (cfg.width, cfg.height, cfg.encoding, cfg.fps) == (1280, 1024, "mono8", 30.0)
        assert (cfg.cx_px, cfg.cy_px) == (639.5, 511.5)
    focal = {cid: cam.K[0, 0] for cid, cam in cams.items()}
    assert focal == {"left": 1500, "right": 1500, "mono_a": 1300, "mono_b": 1400}
    assert all(cam.K[0, 0] == cam.K[1, 1] for cam in cams.values())
    assert np.allclose(cams["left"].R, np.eye(3)) and np.allclose(cams["left"].centre, 0)
    assert np.allclose(cams["right"].R, np.eye(3))
    assert np.allclose(cams["right"].centre, [0.125, 0, 0])
    for cid, centre in (("mono_a", [-0.30, 0.0, 0.05]), ("mono_b", [0.425, 0.0, 0.05])):
        R, t = look_at(np.array(centre), np.array([0.0625, 0.0, 0.65]))
        assert np.allclose(cams[cid].R, R) and np.allclose(cams[cid].t, t)
    assert rig.scene.box_centre_m == (0.0625, 0.0, 0.65)


@pytest.mark.parametrize("name", ["sim.yaml", "fisheye.yaml", "aravis-example.yaml", "v4l2-example.yaml"])
def test_example_rigs_load(name):
    rig = load_rig(CONFIG / name)
    assert rig.cameras


def test_per_driver_dataclasses():
    data = base()
    data["cameras"].append({"id": "d", "driver": "aravis",
                            "aravis": {"device_id": "Basler-123", "fps": 20, "gain_db": 3}})
    rig = parse_rig(data)
    assert isinstance(rig.camera("c").config, V4l2Config)
    aravis = rig.camera("d").config
    assert isinstance(aravis, AravisConfig)
    assert (aravis.device_id, aravis.fps, aravis.gain_db, aravis.pixel_format) == \
        ("Basler-123", 20.0, 3.0, "Mono8")
    with pytest.raises(InputError, match="no camera 'zz'"):
        rig.camera("zz")


def test_errors_name_the_field():
    refused(lambda d: d["cameras"][2].update(driver="foo"),
            r"cameras\[2\]\.driver: unknown driver 'foo' \(expected sim, aravis, v4l2\)")
    refused(lambda d: d["cameras"][1].update(id="a"),
            r"cameras\[1\]\.id: duplicate id 'a' \(also cameras\[0\]\)")
    refused(lambda d: d["cameras"][0]["sim"].update(f_px="big"),
            r"cameras\[0\]\.sim\.f_px: expected a finite number")
    refused(lambda d: d["cameras"][0]["sim"].update(width=-3),
            r"cameras\[0\]\.sim\.width: must be positive")
    refused(lambda d: d["cameras"][0]["sim"].update(fps=float("nan")),
            r"cameras\[0\]\.sim\.fps: expected a finite number")
    refused(lambda d: d["stereo"].update(right="nope"),
            r"stereo\.right: no camera 'nope'")
    refused(lambda d: d["stereo"].update(baseline_m=0),
            r"stereo\.baseline_m: must be positive")
    refused(lambda d: d["cameras"][0].pop("sim"), r"cameras\[0\]\.sim: missing")
    refused(lambda d: d["cameras"][0]["sim"].update(fx=3),
            r"unknown key 'fx' in cameras\[0\]\.sim \(did you mean 'f_px'\?\)")
    refused(lambda d: d["cameras"][0].update(id="a/b"), r"cameras\[0\]\.id")
    refused(lambda d: d["cameras"][0]["sim"].update(fx_px=3), r"cameras\[0\]\.sim\.fx_px: give f_px, or fx_px and")
    refused(lambda d: d.pop("cameras"), r"cameras: missing")
    refused(lambda d: d["cameras"][2]["v4l2"].update(fourcc="MJPEG"),
            r"cameras\[2\]\.v4l2\.fourcc")
    refused(lambda d: d["cameras"][0]["sim"].update(dist=[0.1, "x"]),
            r"cameras\[0\]\.sim\.dist")


def test_error_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"rig": "r", "cameras": [{"id": "a", "driver": "x"}]}))
    with pytest.raises(InputError, match=r"bad\.yaml: cameras\[0\]\.driver"):
        load_rig(path)
    path.write_text("rig: [unclosed")
    with pytest.raises(InputError, match="not valid YAML"):
        load_rig(path)


NUMERIC_IDS = """\
rig: desk
stereo: {left: 0006, right: "0007", baseline_m: 0.12}
baselines:
  - {cameras: ["0007", 0010], baseline_m: 0.5}  # YAML 1.1: octal, the number 8
cameras:
  - id: 0006
  - id: "0007"
  - id: "0010"
"""


@pytest.mark.parametrize(
    ("fix", "message"),
    [
        ((), 'cameras[0].id: ids are strings, but YAML reads the unquoted 0006 as the number 6, losing how it was '
             'written; quote it: id: "0006"'),
        ((("- id: 0006", '- id: "0006"'),),
         'stereo.left: ids are strings, but YAML reads the unquoted 0006 as the number 6, losing how it was written; '
         'quote it: left: "0006"'),
        ((("- id: 0006", '- id: "0006"'), ("left: 0006", 'left: "0006"')),
         'baselines[0].cameras[1]: ids are strings, but YAML reads the unquoted 0010 as the number 8, losing how it '
         'was written; quote it: "0010"'),
        ((("- id: 0006", '- id: "0006"'), ("left: 0006", "left: on")),
         'stereo.left: ids are strings, but YAML reads the unquoted on as true, losing how it was written; '
         'quote it: left: "on"'),
        ((("- id: 0006", '- id: "0006"'), ("left: 0006", 'left: "0006"'), ("rig: desk", "rig: 2024")),
         'rig: ids are strings, but YAML reads the unquoted 2024 as the number 2024; quote it: rig: "2024"'),
    ],
    ids=["camera", "stereo", "baselines", "boolean", "rig"],
)
def test_an_unquoted_numeric_id_is_shown_as_written_and_quoted(tmp_path, fix, message):
    path = tmp_path / "rig.yaml"
    text = NUMERIC_IDS
    for old, new in fix:
        text = text.replace(old, new)
    path.write_text(text)
    with pytest.raises(InputError) as refusal:
        load_rig(path)
    assert str(refusal.value) == f"{path}: {message}"
    for old, new in (("- id: 0006", '- id: "0006"'), ("left: 0006", 'left: "0006"'), ("0010]", '"0010"]')):
        text = text.replace(old, new)
    path.write_text(text.replace("left: on", 'left: "0006"').replace("rig: 2024", "rig: desk"))
    rig = load_rig(path)  # quoted as the message says, every id is the one written
    assert [c.id for c in rig.cameras] == ["0006", "0007", "0010"] and rig.stereo.left == "0006"
    assert (rig.baselines[0].a, rig.baselines[0].b) == ("0007", "0010")


def test_a_numeric_id_without_its_yaml_text_says_the_spelling_is_lost():
    with pytest.raises(InputError, match=r'stereo\.left: ids are strings, but YAML read this one as the number 6, and '
                       r'how it was written is lost \(an unquoted 0006 is the number 6, its leading zeros dropped\); '
                       r'quote it as written, e\.g\. left: "0006"'):
        parse_rig({**base(), "stereo": {"left": 6, "right": "b", "baseline_m": 0.1}})


def test_camnet_match_names_a_numeric_id_in_one_line(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "rig.yaml"
    path.write_text(NUMERIC_IDS)
    result = subprocess.run([sys.executable, "-m", "camnet", "match", "0006.png", "0007.png", "0010.png", "--rig",
                             str(path), "-o", str(tmp_path / "obs.json")], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and not (tmp_path / "obs.json").exists()
    assert result.stderr == (f"camnet match: error: {path}: cameras[0].id: ids are strings, but YAML reads the "
                             'unquoted 0006 as the number 6, losing how it was written; quote it: id: "0006"\n')


def with_head(d: dict, **stereo) -> None:
    K = [[50.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]]
    for cam in d["cameras"][:2]:
        cam["intrinsics"] = {"K": K}
    d["stereo"].update(R=np.eye(3).tolist(), t=[-0.1, 0.0, 0.0])
    d["stereo"].update(stereo)


def test_a_known_stereo_pose_is_read_and_checked():
    data = copy.deepcopy(base())
    with_head(data)
    rig = parse_rig(data, source="rig.yaml")
    assert np.array_equal(rig.stereo.R, np.eye(3)) and np.allclose(rig.stereo.t, [-0.1, 0, 0])
    assert parse_rig(base(), source="rig.yaml").stereo.R is None
    refused(lambda d: with_head(d, t=[-0.2, 0.0, 0.0]), r"stereo\.t: its length 0\.2 m differs from stereo\.baseline_m")
    refused(lambda d: with_head(d, R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), r"stereo\.R: not a rotation matrix")
    refused(lambda d: with_head(d, R=[[1, 0], [0, 1]]), r"stereo\.R: expected a 3x3 array")
    refused(lambda d: (with_head(d), d["stereo"].pop("t")), r"stereo\.t: missing; a known stereo pose needs both")
    refused(lambda d: (with_head(d), d["cameras"][1].pop("intrinsics")),
            r"stereo\.R: a known stereo pose needs intrinsics\.K of camera 'b'")


def test_a_stereo_pair_is_a_parallel_head_only_when_the_rig_says_so():
    assert parse_rig(base()).stereo.parallel is False
    data = base()
    data["stereo"]["parallel"] = True
    assert parse_rig(data).stereo.parallel is True
    # The shipped rigs are parallel heads.
    for name in ("sim.yaml", "kitti.yaml", "aravis-example.yaml"):
        assert load_rig(CONFIG / name).stereo.parallel, name
    refused(lambda d: d["stereo"].update(parallel="yes"), r"stereo\.parallel: expected true or false")


@pytest.mark.parametrize(("change", "message"), [
    # A misspelt required key is named as the stray key, not as the missing one it was meant to be.
    (lambda d: d["stereo"].update(baseline=d["stereo"].pop("baseline_m")),
     "rig.yaml: unknown key 'baseline' in stereo (did you mean 'baseline_m'?)"),
    (lambda d: d.update(camera=d.pop("cameras")),
     "rig.yaml: unknown key 'camera' in the rig file (did you mean 'cameras'?)"),
    (lambda d: d["cameras"][2]["v4l2"].update(sorce="x.mp4"),
     "rig.yaml: unknown key 'sorce' in cameras[2].v4l2 (did you mean 'source'?)"),
    (lambda d: d["cameras"][0].update(drivr="sim"),
     "rig.yaml: unknown key 'drivr' in cameras[0] (did you mean 'driver'?)"),
    # The typo is named, not the section it leaves unknown.
    (lambda d: d["cameras"][1].update(sim=d["cameras"][1].pop("sim"), drivr=d["cameras"][1].pop("driver")),
     "rig.yaml: unknown key 'drivr' in cameras[1] (did you mean 'driver'?)"),
    (lambda d: d["cameras"][0].update(v4l2={}), "rig.yaml: unknown key 'v4l2' in cameras[0] (known: id, driver, "
                                                "model, intrinsics, sim)"),
])
def test_a_misspelt_key_is_named_with_the_key_it_resembles(change, message):
    data = copy.deepcopy(base())
    change(data)
    with pytest.raises(InputError) as caught:
        parse_rig(data, source="rig.yaml")
    assert str(caught.value) == message


def test_paths_are_relative_to_the_rig_file_and_absolute_ones_kept(tmp_path, monkeypatch):
    rig_dir = tmp_path / "rigs [1]"  # glob characters in the rig file's directory are not a pattern
    (rig_dir / "img").mkdir(parents=True)
    data = copy.deepcopy(base())
    data["cameras"][2]["v4l2"] = {"source": "img/*.png", "timestamps": "img/times.txt"}
    data["cameras"].append({"id": "d", "driver": "v4l2", "v4l2": {"source": "clips/d.mp4"}})
    data["cameras"].append({"id": "e", "driver": "v4l2", "v4l2": {"source": str(tmp_path / "e.mp4")}})
    data["cameras"].append({"id": "f", "driver": "v4l2", "v4l2": {"source": "2"}})
    (rig_dir / "rig.yaml").write_text(yaml.safe_dump(data))
    monkeypatch.chdir(tmp_path)
    rig = load_rig(Path("rigs [1]") / "rig.yaml")
    seq, clip, absolute, device = (rig.camera(c).config for c in "cdef")
    assert seq.source == str(Path("rigs [[]1]") / "img" / "*.png")
    assert seq.timestamps == str(Path("rigs [1]") / "img" / "times.txt")
    assert clip.source == str(Path("rigs [1]") / "clips" / "d.mp4")
    assert absolute.source == str(tmp_path / "e.mp4") and device.source == "2"
    assert rig.camera("c").config.source != parse_rig(data).camera("c").config.source == "img/*.png"


def test_an_image_sequence_beside_the_rig_file_is_found_from_anywhere(tmp_path, monkeypatch):
    import cv2
    from camnet.drivers.v4l2 import V4l2Camera

    (tmp_path / "rig" / "img").mkdir(parents=True)
    for i in range(2):
        cv2.imwrite(str(tmp_path / "rig" / "img" / f"{i}.png"), np.full((8, 10), 40 * i, np.uint8))
    data = {"rig": "r", "cameras": [{"id": "c", "driver": "v4l2", "v4l2": {"source": "img/*.png", "fps": 100}}]}
    (tmp_path / "rig" / "rig.yaml").write_text(yaml.safe_dump(data))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    entry = load_rig("../rig/rig.yaml").camera("c")
    with V4l2Camera("c", entry.config) as cam:
        assert cam.info.width == 10 and cam.read(timeout_s=1.0).image.shape[:2] == (8, 10)


def test_the_world_frame_is_the_left_cameras_unless_the_rig_asks_for_the_floors():
    assert parse_rig(base()).world == World.LEFT_CAMERA
    assert parse_rig({**base(), "world": "floor"}).world == World.FLOOR
    assert parse_rig({**base(), "world": "left_camera"}).world == World.LEFT_CAMERA
    refused(lambda d: d.update(world="ceiling"), r"rig\.yaml: world: .*ceiling.*left_camera, floor")


def test_the_sync_section_says_whether_the_cameras_run_free_and_the_matcher_follows_it(tmp_path):
    import argparse
    import subprocess
    import sys

    from camnet.commands.matcher import node_config_from_args

    rig = parse_rig({**base(), "sync": {"free_run": True, "tolerance_ms": 2}})
    assert (rig.sync.free_run, rig.sync.tolerance_ms, rig.sync.max_wait_s) == (True, 2.0, None)
    assert parse_rig({**base(), "sync": {"tolerance_ms": 2}}).sync.free_run is None  # the matcher's default
    config = node_config_from_args(argparse.Namespace(), rig)
    assert (config.sync_free_run, config.sync_tolerance_ms) == (True, 2.0)
    assert not node_config_from_args(argparse.Namespace(sync_free_run=False), rig).sync_free_run  # flags win
    assert not node_config_from_args(argparse.Namespace(), parse_rig(base())).sync_free_run

    refused(lambda d: d.update(sync={"free_run": "yes"}),
            r"^rig\.yaml: sync\.free_run: expected true or false, got 'yes'$")
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({**base(), "sync": {"free_run": 1}}))
    result = subprocess.run([sys.executable, "-m", "camnet", "matcher", "--rig", str(path)], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "sync.free_run: expected true or false, got 1" in result.stderr
