"""`camnet calibrate` through its real entry point: good input, and every kind of bad input."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from camnet.io.formats import observations_to_doc, parse_calibration
from camnet.sim.simulate import make_rig, observe


def run_camnet(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camnet", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture()
def good_doc() -> dict:
    rig = make_rig(seed=3)
    return observations_to_doc(observe(rig, noise_px=0.3, seed=3).observations)


def test_calibrate_writes_the_contract(tmp_path, good_doc):
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(good_doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    assert doc["format"] == "camnet.calibration/1" and doc["units"] == "m" and doc["world_frame"] == "left"
    cal = parse_calibration(doc)
    left = next(c for c in cal.cameras if c.id == "left")
    np.testing.assert_allclose(left.R, np.eye(3))
    np.testing.assert_allclose(left.t, 0.0)
    right = next(c for c in cal.cameras if c.id == "right")
    assert abs(np.linalg.norm(right.centre) - 0.125) < 1e-12  # the baseline is held exactly
    assert 0 < cal.rms_reprojection_px < 1.0
    assert doc["uncertainty"]["scale_rel"] > 0
    assert set(doc["diagnostics"]["cameras"]) == {"left", "right", "mono_a", "mono_b"}


def test_paper_and_unconstrained_methods_run(tmp_path, good_doc):
    src = tmp_path / "obs.json"
    src.write_text(json.dumps(good_doc))
    for method in ("paper", "unconstrained"):
        out = tmp_path / f"{method}.json"
        proc = run_camnet("calibrate", str(src), "-o", str(out), "--method", method)
        assert proc.returncode == 0, proc.stderr
        assert json.loads(out.read_text())["method"] == method


def _mutations(doc: dict):
    """(name, mutated document or raw text, text the one-line error must contain)."""
    import copy

    def mutate(fn):
        d = copy.deepcopy(doc)
        fn(d)
        return d

    yield "malformed JSON", "{not json", "not valid JSON"
    yield "wrong format", mutate(lambda d: d.update(format="camnet.observations/9")), "format"
    yield "missing cameras", mutate(lambda d: d.pop("cameras")), "cameras: missing"
    yield (
        "unknown camera in a track",
        mutate(lambda d: d["tracks"][5]["observations"].update(ghost=[1.0, 2.0])),
        "tracks[5].observations.ghost",
    )
    yield "unknown stereo camera", mutate(lambda d: d["stereo"].update(left="ghost")), "stereo.left"
    yield (
        "non-numeric coordinate",
        mutate(lambda d: d["tracks"][2]["observations"].update(left=["a", 1.0])),
        "tracks[2].observations.left",
    )
    yield "not a pixel pair", mutate(lambda d: d["tracks"][2]["observations"].update(left=[1.0])), "expected [u, v]"
    yield "zero baseline", mutate(lambda d: d["stereo"].update(baseline_m=0)), "stereo.baseline_m"
    yield "negative baseline", mutate(lambda d: d["stereo"].update(baseline_m=-0.1)), "stereo.baseline_m"
    yield "missing baseline", mutate(lambda d: d["stereo"].pop("baseline_m")), "stereo.baseline_m"
    yield (
        "two cameras",
        mutate(
            lambda d: (
                d.update(cameras=d["cameras"][:2]),
                [t["observations"].pop(k, None) for t in d["tracks"] for k in ("mono_a", "mono_b")],
            )
        ),
        "at least 3",
    )
    yield (
        "three shared tracks",
        mutate(lambda d: [t["observations"].pop(k, None) for t in d["tracks"][3:] for k in ("mono_a", "mono_b")]),
        "need at least 6",
    )
    yield ("numeric camera id", mutate(lambda d: d["cameras"][0].update(id=6)),
           'cameras[0].id: ids are strings, got the number 6; quote it: "id": "6"')
    yield ("numeric stereo id", mutate(lambda d: d["stereo"].update(right=7)),
           'stereo.right: ids are strings, got the number 7; quote it: "right": "7"')
    yield "duplicate camera", mutate(lambda d: d["cameras"].append(dict(d["cameras"][0]))), "duplicate camera id"
    yield "nested 100k deep", "[" * 100_000 + "]" * 100_000, "nested too deeply"
    yield "not UTF-8", json.dumps(doc).encode()[:40] + b"\xff\xfe" + json.dumps(doc).encode()[40:], "not UTF-8"
    yield "float track id", mutate(lambda d: d["tracks"][0].update(id=1e30)), "tracks[0].id"
    yield "huge track id", mutate(lambda d: d["tracks"][0].update(id=10**30)), "tracks[0].id: integer out of range"
    assert '"id": 0,' in json.dumps(doc)
    yield "5000-digit integer", json.dumps(doc).replace('"id": 0,', '"id": ' + "9" * 5000 + ",", 1), "not usable JSON"


MUTATIONS = 20


def test_every_mutation_is_run(good_doc):
    assert len(list(_mutations(good_doc))) == MUTATIONS


@pytest.mark.parametrize("index", range(MUTATIONS))
def test_bad_input_gets_one_clear_line_and_no_output(tmp_path, good_doc, index):
    name, doc, expected = list(_mutations(good_doc))[index]
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    if isinstance(doc, bytes):
        src.write_bytes(doc)
    else:
        src.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode != 0, name
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], (name, proc.stderr)
    assert not out.exists()


def test_non_finite_coordinate_is_refused(tmp_path, good_doc):
    text = re.sub(r'"left": \[[^,]+,', '"left": [NaN,', json.dumps(good_doc), count=1)
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(text)
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode != 0 and "finite" in proc.stderr and not out.exists()


def test_a_solve_that_cannot_succeed_is_refused(tmp_path, good_doc):
    rng = np.random.default_rng(0)
    for track in good_doc["tracks"]:  # pure noise: no camera is consistent with the others
        for cam in track["observations"]:
            track["observations"][cam] = rng.uniform([0, 0], [1279, 1023]).tolist()
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(good_doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode != 0 and len(proc.stderr.strip().splitlines()) == 1 and not out.exists()


def test_calibrate_tells_a_person_on_stderr_and_json_only_when_asked(tmp_path, good_doc):
    src, out = tmp_path / "obs.json", tmp_path / "cal.json"
    src.write_text(json.dumps(good_doc))
    proc = run_camnet("calibrate", str(src), "-o", str(out))
    assert proc.returncode == 0 and proc.stdout == "", proc.stderr
    lines = proc.stderr.splitlines()
    assert lines[0] == f"camnet calibrate: wrote {out}"
    table = {line.split()[0]: line for line in lines if line.split()[:1] in (["left"], ["mono_a"])}
    assert "given" in table["left"] and re.search(r"\d+\.\d ± \d+\.\d", table["mono_a"]), lines
    verdict = json.loads(out.read_text())["verdict"]["level"]
    assert f"verdict: {verdict}" in proc.stderr
    proc = run_camnet("calibrate", str(src), "-o", str(out), "--json")
    summary = json.loads(proc.stdout)
    assert summary["verdict"] == verdict and summary["output"] == str(out)


HEAVY_MODULES = ("scipy.optimize", "scipy.sparse", "cv2", "zenoh", "rerun", "pycolmap", "camnet.solve")


@pytest.mark.parametrize("command", ["", "calibrate"])
def test_help_imports_nothing_the_solve_needs(command):
    """`camnet --help` and `camnet calibrate --help` build their parser without the solver, the
    codecs, Zenoh or Rerun (a fresh interpreter: these tests' own imports would hide it)."""
    code = (
        "import sys, camnet.cli\n"
        f"camnet.cli.build_parser(only={command!r})\n"
        f"loaded = [m for m in {HEAVY_MODULES!r} if m in sys.modules]\n"
        "assert not loaded, loaded\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_calibrate_help_runs():
    proc = run_camnet("calibrate", "--help")
    assert proc.returncode == 0 and "--free" in proc.stdout
