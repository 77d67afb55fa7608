"""The distribution installs one top-level package, camnet, with every sub-package in it,
and the built-in rig of `camnet up` as data: an installed wheel runs `camnet up` with no
rig file, away from the source tree."""

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from tests.conftest import free_port, run_to_end

ROOT = Path(__file__).resolve().parents[1]


def _packages_on_disk() -> set[str]:
    """Dotted names of every folder with an __init__.py, as installed (drivers/ -> camnet.drivers)."""
    found = set()
    for top, installed in (("camnet", "camnet"), ("drivers", "camnet.drivers"), ("services", "camnet.services")):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / top).parts
            found.add(".".join((installed, *rel)))
    return found


def test_every_package_is_installed_inside_camnet():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    # camnet.rigs is config/'s built-in rig, data without code.
    assert listed == _packages_on_disk() | {"camnet.rigs"}, \
        "pyproject.toml [tool.setuptools] packages and the folders disagree"
    assert all(name == "camnet" or name.startswith("camnet.") for name in listed)
    assert config["package-dir"] == {"camnet": "camnet", "camnet.drivers": "drivers", "camnet.services": "services",
                                     "camnet.rigs": "config"}
    assert config["package-data"] == {"camnet.rigs": ["sim.yaml"]}


def test_drivers_and_services_import_from_their_folders():
    import camnet.drivers.base
    import camnet.services.calibrator

    assert Path(camnet.drivers.base.__file__).resolve() == ROOT / "drivers" / "base.py"
    assert Path(camnet.services.calibrator.__file__).resolve() == ROOT / "services" / "calibrator.py"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """camnet's wheel, built from a copy of what the image's build copies (docker/Dockerfile)
    with this environment's setuptools, so that nothing is written into the tree."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    for name in ("camnet", "drivers", "services"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    (src / "config").mkdir()
    for name in ("pyproject.toml", "README.md", "config/sim.yaml"):
        shutil.copy(ROOT / name, src / name)
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                           "--disable-pip-version-check", "-q", "-w", str(tmp / "dist"), str(src)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    [built] = (tmp / "dist").glob("camnet-*.whl")
    return built


def test_the_wheel_holds_the_built_in_rig_and_no_other_config(wheel):
    with zipfile.ZipFile(wheel) as whl:
        names = whl.namelist()
        assert whl.read("camnet/rigs/sim.yaml") == (ROOT / "config" / "sim.yaml").read_bytes()
    assert [n for n in names if n.startswith("camnet/rigs/")] == ["camnet/rigs/sim.yaml"]
    assert "camnet/drivers/base.py" in names and "camnet/services/calibrator.py" in names
    assert not [n for n in names if n.split("/")[0] in ("config", "drivers", "services")]


def test_an_installed_wheel_runs_camnet_up_with_its_built_in_rig(wheel, tmp_path):
    site = tmp_path / "site"
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--disable-pip-version-check", "-q",
                           "--target", str(site), str(wheel)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    # The installed camnet, first on the path, run from a directory away from the source tree.
    env = {**os.environ, "PYTHONPATH": str(site)}
    where = subprocess.run([sys.executable, "-c", "import camnet.commands.up as up; print(up.default_rig())"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()) == site / "camnet" / "rigs" / "sim.yaml"
    # On a loopback port of its own: on the default rendezvous it could hear another rig named sim.
    up = run_to_end([sys.executable, "-m", "camnet.cli", "up", "--duration-s", "1",
                     "--out", str(tmp_path / "run"), "--listen", f"tcp/127.0.0.1:{free_port()}"],
                    cwd=tmp_path, env=env, timeout_s=120)
    # It loads the rig and starts its nodes; in a second they calibrate nothing (exit 2).
    assert "camnet up: rig 'sim', 4 cameras" in up.stdout, up.stdout + up.stderr
    assert "cannot read rig file" not in up.stdout + up.stderr
    assert up.returncode == 2 and "no calibration in 1 s" in up.stderr, up.stdout + up.stderr
