"""Known distances in the wrong unit are refused with the range and the unit; a deliberate giant is kept."""

import json
import re
import sys
from pathlib import Path

import cv2
import pytest
import yaml

from camnet.errors import InputError
from camnet.io.formats import load_json, observations_to_doc, parse_observations
from camnet.io.rig import load_rig, parse_rig
from camnet.sim.render import Renderer
from camnet.sim.scene import Scene
from camnet.sim.simulate import make_rig, observe
from camnet.solve import calibrate
from camnet.solve.report.assemble import far_scene_warning
from tests.conftest import free_port, run_to_end
from tests.test_cli_calibrate import run_camnet
from tests.test_network import rig_file


@pytest.fixture(scope="module")
def doc() -> dict:
    return observations_to_doc(observe(make_rig(seed=2), noise_px=0.3, seed=2).observations)


def test_millimetres_for_metres_are_refused_with_the_unit(doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 125
    expected = (r"stereo.baseline_m: 125 m is not a distance between cameras \(expected 0.005 to 50 m\); "
                r"distances are given in metres \(125 mm = 0.125\)")
    with pytest.raises(InputError, match=expected):
        parse_observations(doc)
    assert parse_observations(doc, any_distance=True).stereo.baseline_m == 125


def test_kilometres_for_metres_and_further_distances_too(doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 0.000125
    with pytest.raises(InputError, match=r"0.000125 km = 0.125"):
        parse_observations(doc)
    doc["stereo"]["baseline_m"] = 0.125
    doc["baselines"] = [{"cameras": ["mono_a", "mono_b"], "baseline_m": 731}]
    with pytest.raises(InputError, match=r"baselines\[0\].baseline_m: 731 m"):
        parse_observations(doc)


def test_a_rig_file_in_millimetres_is_refused_unless_it_says_so():
    rig = {"rig": "units", "stereo": {"left": "a", "right": "b", "baseline_m": 537.2},
           "cameras": [{"id": "a"}, {"id": "b"}]}  # cameras known from their images only
    with pytest.raises(InputError, match=r"stereo.baseline_m: 537.2 m is not a distance.*accept_any_distance"):
        parse_rig(rig)
    assert parse_rig({**rig, "accept_any_distance": True}).stereo.baseline_m == 537.2


@pytest.mark.parametrize("distance_m", [1e-12, 1e200])
def test_a_distance_no_solve_can_take_is_refused_even_kept_on_purpose(doc, distance_m):
    """Kept on purpose, a distance still has to be one the solve's floats can take."""
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = distance_m
    expected = (f"stereo.baseline_m: {distance_m:g} m is no distance between cameras that camnet can solve with "
                "(1e-06 to 1e+06 m, even kept on purpose)")
    with pytest.raises(InputError, match=re.escape(expected)):
        parse_observations(doc, any_distance=True)
    rig = {"rig": "units", "stereo": {"left": "a", "right": "b", "baseline_m": distance_m},
           "cameras": [{"id": "a"}, {"id": "b"}], "accept_any_distance": True}
    with pytest.raises(InputError, match=r"stereo.baseline_m: .* even kept on purpose"):
        parse_rig(rig)


def test_calibrate_refuses_in_one_line_and_accepts_on_request(tmp_path, doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 125
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode != 0 and len(proc.stderr.strip().splitlines()) == 1 and not out.exists()
    assert "125 mm = 0.125" in proc.stderr
    proc = run_camnet("calibrate", str(src), "-o", str(out), "--accept-any-distance")
    assert proc.returncode == 0 and json.loads(out.read_text())["cameras"][1]["t"][0] == pytest.approx(-125, rel=1e-3)


def test_a_scene_a_thousand_baselines_away_is_warned_of():
    near = calibrate(observe(make_rig(seed=3), noise_px=0.3, seed=3).observations).calibration
    assert not any("baselines away" in w for w in near.warnings)  # 0.6 m for 0.125 m
    assert not far_scene_warning(21.0, 0.54)  # KITTI: the median point 40 baselines away
    (warning,) = far_scene_warning(608.0, 0.125)  # 125 mm taken for 125 m, the scene solved as before
    assert warning.startswith("the median point is 4864 baselines away (608 m for 0.125 m)")


# The two ways to keep a distance on purpose: the rig file's key, and calibrate's flag for an observations file.
RIG_FILE_KEY, FLAG = "`accept_any_distance: true`", "--accept-any-distance"


def kept_as_told(stderr: str, argv: list[str], rig: Path | None) -> list[str]:
    """`argv` (and the rig file) changed as the refusal in `stderr` says to keep the distance; it must name
    exactly one way, one the command takes."""
    assert "to keep it, " in stderr, stderr
    hint = stderr.split("to keep it, ", 1)[1]
    named = [way for way in (RIG_FILE_KEY, FLAG) if way in hint]
    assert len(named) == 1, stderr
    if named[0] == FLAG:
        assert FLAG in run_camnet(argv[0], "--help").stdout, f"camnet {argv[0]} names {FLAG} but takes no such flag"
        return [*argv, FLAG]
    assert rig is not None, f"camnet {argv[0]} reads no rig file, yet its refusal says to edit one: {stderr}"
    doc = yaml.safe_load(rig.read_text())
    rig.write_text(yaml.safe_dump({**doc, "accept_any_distance": True}, sort_keys=False))
    return argv


def millimetre_rig(tmp_path: Path) -> Path:
    """The simulated 4-camera rig with its baseline written in millimetres (125 for 0.125 m)."""
    rig = Path(rig_file(tmp_path, 4))
    doc = yaml.safe_load(rig.read_text())
    doc["stereo"]["baseline_m"] = 125
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))
    return rig


def test_calibrate_names_the_flag_it_takes(tmp_path, doc):
    doc = json.loads(json.dumps(doc))
    doc["stereo"]["baseline_m"] = 125
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(doc))
    argv = ["calibrate", str(src), "-o", str(out)]
    refused = run_camnet(*argv)
    assert refused.returncode == 2 and not out.exists()
    kept = run_camnet(*kept_as_told(refused.stderr, argv, None))
    assert kept.returncode == 0, kept.stderr
    assert json.loads(out.read_text())["cameras"][1]["t"][0] == pytest.approx(-125, rel=1e-3)


def test_match_names_the_rig_file_key(tmp_path):
    rig = millimetre_rig(tmp_path)
    parsed = parse_rig(yaml.safe_load(rig.read_text()) | {"accept_any_distance": True})
    scene = Scene(parsed.scene)
    images = []
    for entry in parsed.cameras:
        images.append(str(tmp_path / f"{entry.id}.png"))
        cv2.imwrite(images[-1], Renderer(entry.config.camera(entry.id)).render(scene.quads(0.0)))
    out = tmp_path / "obs.json"
    argv = ["match", *images, "--rig", str(rig), "-o", str(out)]
    refused = run_camnet(*argv)
    assert refused.returncode == 2 and not out.exists(), refused.stderr
    kept = run_camnet(*kept_as_told(refused.stderr, argv, rig))
    assert kept.returncode == 0, kept.stderr
    assert parse_observations(load_json(out), any_distance=True).stereo.baseline_m == 125


def test_up_names_the_rig_file_key(tmp_path):
    rig = millimetre_rig(tmp_path)
    run_dir = tmp_path / "run"
    argv = ["up", str(rig), "--until-frame-sets", "2", "--duration-s", "300", "--run-dir", str(run_dir),
            "--listen", f"tcp/127.0.0.1:{free_port()}"]
    refused = run_camnet(*argv)
    assert refused.returncode == 2 and not run_dir.exists(), refused.stderr
    argv = kept_as_told(refused.stderr, argv, rig)
    assert load_rig(rig).stereo.baseline_m == 125
    kept = run_to_end([sys.executable, "-m", "camnet", *argv], timeout_s=600)
    logs = "\n".join(p.read_text()[-1500:] for p in run_dir.rglob("*.log"))
    assert kept.returncode == 0, kept.stdout + kept.stderr + logs
    cal = load_json(run_dir / "calibration.json")
    left, right = (next(c for c in cal["cameras"] if c["id"] == i) for i in ("left", "right"))
    assert abs(left["t"][0] - right["t"][0]) == pytest.approx(125, rel=0.01)  # the distance as given: kept
