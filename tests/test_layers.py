"""camnet's layers hold: imports point downwards, and modules and functions stay short.

Every module under camnet/, drivers/ and services/ is parsed with `ast`; every
import statement counts, at any depth (a function-local import is still a
dependency). drivers/ and services/ install as camnet.drivers and
camnet.services, so they are named that way here.

The allow-lists name what is known to break a rule today and is being fixed
apart; an entry that no longer breaks its rule fails the test too, so that
the lists only shrink.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TREES = {"camnet": "camnet", "drivers": "camnet.drivers", "services": "camnet.services"}
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
LONG_BECAUSE = "Long because:"

NODES = ("camnet.services", "camnet.drivers", "camnet.commands")
VIZ = ("camnet.viz", "camnet.viz_sinks")

# (importing package, packages it must not import)
RULES = (
    ("camnet.geometry", ("camnet.io", "camnet.bus", *VIZ, *NODES, "camnet.datasets", "camnet.sim", "camnet.matching")),
    ("camnet.matching", ("camnet.io", "camnet.bus", *VIZ, *NODES)),
    ("camnet.sim", ("camnet.io", "camnet.bus", *VIZ, *NODES, "camnet.datasets")),
    ("camnet.bus", ("camnet.geometry", "camnet.matching", "camnet.sim", "camnet.io", *VIZ)),
    # Codecs open no session: session files hold the wire's messages (frame, keys), nothing of Zenoh.
    ("camnet.io", ("camnet.bus.session", "camnet.bus.node", "camnet.bus.launch", "camnet.bus.receiver", *VIZ, *NODES,
                   "camnet.datasets")),
    ("camnet.datasets", ("camnet.bus",)),  # a dataset reader opens no bus session
    ("camnet.drivers", ("camnet.services",)),
    ("camnet.services", ("camnet.drivers",)),
    # The live policy and the offline solve it judges know nothing of the live calibrator's state between solves.
    *((module, ("camnet.geometry.live",)) for module in (
        "camnet.geometry.live_policy", "camnet.geometry.judged_solve", "camnet.geometry.newest_first",
        "camnet.commands.calibrate")),
)

# Known violations, (importing file, imported module), each to be removed when its fix is merged.
ALLOWED_IMPORTS: set[tuple[str, str]] = set()

# Known long modules ("file") and functions ("file:function"), each being split apart.
ALLOWED_LONG: set[str] = set()


def modules(root: Path = ROOT):
    """(path relative to root, dotted module name, parsed tree) of every module of the trees."""
    for folder, package in TREES.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = path.relative_to(root / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join((package, *parts))
            yield path.relative_to(root).as_posix(), name, ast.parse(path.read_text(), filename=str(path))


def imported(name: str, tree: ast.Module, *, is_package: bool):
    """What each import of `tree` may name, most general first: ``import a.b`` gives [a.b];
    ``from a import b`` gives [a, a.b], since b may be a module or a name in a."""
    package = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from ([alias.name] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            yield from ([base, f"{base}.{alias.name}"] for alias in node.names)


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def import_violations(root: Path = ROOT) -> set[tuple[str, str]]:
    """(importing file, imported module) of every import a rule forbids."""
    found = set()
    for path, name, tree in modules(root):
        forbidden = [bad for importer, bads in RULES if within(name, importer) for bad in bads]
        for candidates in imported(name, tree, is_package=path.endswith("__init__.py")):
            module = next((c for c in candidates if any(within(c, bad) for bad in forbidden)), None)
            if module is not None:
                found.add((path, module))
    return found


def _long_because(tree: ast.Module) -> bool:
    docstring = ast.get_docstring(tree) or ""
    return any(line.strip().startswith(LONG_BECAUSE) for line in docstring.splitlines())


def size_violations(root: Path = ROOT) -> dict[str, int]:
    """Lines of every module over MAX_MODULE_LINES and every function over MAX_FUNCTION_LINES.

    Keys are the file, or ``file:function``; a module whose docstring has a line
    starting ``Long because:`` is exempt, functions included.
    """
    found = {}
    for path, _, tree in modules(root):
        if _long_because(tree):
            continue
        n_lines = len((root / path).read_text().splitlines())
        if n_lines > MAX_MODULE_LINES:
            found[path] = n_lines
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    found[f"{path}:{node.name}"] = length
    return found


def test_imports_point_downwards():
    found = import_violations()
    new = sorted(found - ALLOWED_IMPORTS)
    assert not new, "imports across layers (file, module): " + "; ".join(f"{f} imports {m}" for f, m in new)
    stale = sorted(ALLOWED_IMPORTS - found)
    assert not stale, f"fixed, remove from ALLOWED_IMPORTS: {stale}"


def test_modules_and_functions_are_short():
    found = size_violations()
    new = {key: n for key, n in found.items() if key not in ALLOWED_LONG}
    assert not new, (
        f"over {MAX_MODULE_LINES} lines a module or {MAX_FUNCTION_LINES} a function "
        f"(split it, or say why in a '{LONG_BECAUSE}' line of the module docstring): {new}"
    )
    stale = sorted(ALLOWED_LONG - set(found))
    assert not stale, f"short now, remove from ALLOWED_LONG: {stale}"


def _tree(root: Path, files: dict[str, str]) -> Path:
    for folder in TREES:
        (root / folder).mkdir(parents=True, exist_ok=True)
    for relative, text in files.items():
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).write_text(text)
    return root


def test_the_import_check_finds_a_violation(tmp_path):
    root = _tree(tmp_path, {
        "camnet/geometry/__init__.py": "",
        "camnet/geometry/bad.py": "import numpy\n\n\ndef f():\n    from camnet.io.formats import Calibration\n",
        "camnet/geometry/relative.py": "from .. import viz\nfrom . import projection\n",
        "camnet/geometry/fine.py": "from camnet.errors import InputError\nfrom camnet.geometry import projection\n",
        "camnet/matching/late.py": "def g():\n    import camnet.bus.session\n",
        "drivers/uses_node.py": "from camnet.services.calibrator import CalibratorNode\n",
        "services/fine.py": "from camnet.drivers_extra import x\n",
    })
    assert import_violations(root) == {
        ("camnet/geometry/bad.py", "camnet.io.formats"),
        ("camnet/geometry/relative.py", "camnet.viz"),
        ("camnet/matching/late.py", "camnet.bus.session"),
        ("drivers/uses_node.py", "camnet.services.calibrator"),
    }


def test_the_size_check_finds_long_modules_and_functions(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    root = _tree(tmp_path, {
        "camnet/long_function.py": f"def f():\n{body}",
        "camnet/short_function.py": f"def f():\n{body[: body.rindex('    x')]}",
        "camnet/long_module.py": "x = 1\n" * (MAX_MODULE_LINES + 1),
        "camnet/excused.py": f'"""Why.\n\n{LONG_BECAUSE} one table.\n"""\n' + "x = 1\n" * MAX_MODULE_LINES
        + f"def f():\n{body}",
    })
    assert size_violations(root) == {
        "camnet/long_function.py:f": MAX_FUNCTION_LINES + 1,
        "camnet/long_module.py": MAX_MODULE_LINES + 1,
    }


@pytest.mark.parametrize("relative", ["camnet/geometry/projection.py", "drivers/sim.py", "services/calibrator.py"])
def test_every_tree_is_read(relative):
    assert relative in {path for path, _, _ in modules()}
