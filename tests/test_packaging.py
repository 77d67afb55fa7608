"""The distribution installs one top-level package, camnet, with every sub-package in it."""

import tomllib
from pathlib import Path

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
    assert listed == _packages_on_disk(), "pyproject.toml [tool.setuptools] packages and the folders disagree"
    assert all(name == "camnet" or name.startswith("camnet.") for name in listed)
    assert config["package-dir"] == {"camnet": "camnet", "camnet.drivers": "drivers", "camnet.services": "services"}


def test_drivers_and_services_import_from_their_folders():
    import camnet.drivers.base
    import camnet.services.calibrator

    assert Path(camnet.drivers.base.__file__).resolve() == ROOT / "drivers" / "base.py"
    assert Path(camnet.services.calibrator.__file__).resolve() == ROOT / "services" / "calibrator.py"
