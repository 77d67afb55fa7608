"""camnet's rooms hold: imports point downwards, no module imports itself through others, every module
imports on its own, and nothing shipped leans on the test helpers.

Every module under camnet/, drivers/ and services/ is parsed with `ast`; every
import statement counts, at any depth (a function-local import, or one under
``if TYPE_CHECKING:``, is still a dependency). drivers/ and services/ install
as camnet.drivers and camnet.services, so they are named that way here.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TREES = {"camnet": "camnet", "drivers": "camnet.drivers", "services": "camnet.services"}

NODES = ("camnet.services", "camnet.drivers", "camnet.commands")
VIZ = ("camnet.viz", "camnet.viz_sinks")
OUTSIDE = ("camnet.io", "camnet.bus", *VIZ, *NODES, "camnet.datasets", "camnet.sim")  # what the engine never sees

# (importing package, packages it must not import). The engine's rooms, from the bottom: model, solve, live.
RULES = (
    ("camnet.model", (*OUTSIDE, "camnet.solve", "camnet.live", "camnet.matching")),
    ("camnet.solve", (*OUTSIDE, "camnet.live", "camnet.matching")),
    ("camnet.live", (*OUTSIDE, "camnet.matching")),
    # The start and the report are parts of a solve: they never call the solve they are part of.
    ("camnet.solve.start", ("camnet.solve.pipeline",)),
    ("camnet.solve.report", ("camnet.solve.pipeline", "camnet.solve.start")),
    # The live policy and the offline solve it judges know nothing of the live calibrator's state between solves.
    *((module, ("camnet.live.tracker",)) for module in (
        "camnet.live.policy", "camnet.live.judged_solve", "camnet.live.newest_first", "camnet.commands.calibrate")),
    ("camnet.matching", ("camnet.io", "camnet.bus", *VIZ, *NODES, "camnet.solve", "camnet.live")),
    ("camnet.sim", ("camnet.io", "camnet.bus", *VIZ, *NODES, "camnet.datasets", "camnet.live")),
    ("camnet.bus", ("camnet.model", "camnet.solve", "camnet.live", "camnet.matching", "camnet.sim", "camnet.io", *VIZ)),
    # Codecs open no session: session files hold the wire's messages (frame, keys), nothing of Zenoh.
    ("camnet.io", ("camnet.bus.session", "camnet.bus.node", "camnet.bus.launch", "camnet.bus.receiver", *VIZ, *NODES,
                   "camnet.datasets", "camnet.live")),
    ("camnet.datasets", ("camnet.bus",)),  # a dataset reader opens no bus session
    ("camnet.drivers", ("camnet.services",)),
    ("camnet.services", ("camnet.drivers",)),
)
TESTING = "camnet.testing"  # helpers for tests and benchmarks: no other module imports them


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
        if not within(name, TESTING):
            forbidden.append(TESTING)
        for candidates in imported(name, tree, is_package=path.endswith("__init__.py")):
            module = next((c for c in candidates if any(within(c, bad) for bad in forbidden)), None)
            if module is not None:
                found.add((path, module))
    return found


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules of the trees it imports by name (``from a import b`` counts as a.b where a.b is
    a module, else as a). A package's own front door (its __init__ importing its modules) is not an edge of
    the modules that import through the package."""
    found = list(modules(root))
    names = {name for _, name, _ in found}
    graph = {}
    for path, name, tree in found:
        edges = set()
        for candidates in imported(name, tree, is_package=path.endswith("__init__.py")):
            module = next((c for c in reversed(candidates) if c in names), None)
            if module is not None and module != name:
                edges.add(module)
        graph[name] = edges
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of `graph`: its strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_imports_point_downwards():
    found = sorted(import_violations())
    assert not found, "imports across rooms (file, module): " + "; ".join(f"{f} imports {m}" for f, m in found)


def test_no_import_circles():
    found = circles(import_graph())
    assert not found, "import circles: " + "; ".join(" <-> ".join(c) for c in found)


def test_every_module_imports_on_its_own():
    """Each module imported first, into an interpreter where no other module of camnet was imported before
    it: no module leans on another having been imported already. One interpreter, camnet's modules
    forgotten between imports (the third-party ones stay, for speed)."""
    names = [name for path, name, _ in modules() if not name.endswith("__main__")]
    code = (
        "import importlib, sys\n"
        "failed = []\n"
        f"for name in {names!r}:\n"
        "    for loaded in [m for m in sys.modules if m == 'camnet' or m.startswith('camnet.')]:\n"
        "        del sys.modules[loaded]\n"
        "    try:\n"
        "        importlib.import_module(name)\n"
        "    except Exception as exc:\n"
        "        failed.append(f'{name}: {type(exc).__name__}: {exc}')\n"
        "print('\\n'.join(failed))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "", "modules that do not import on their own:\n" + proc.stdout


def _tree(root: Path, files: dict[str, str]) -> Path:
    for folder in TREES:
        (root / folder).mkdir(parents=True, exist_ok=True)
    for relative, text in files.items():
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).write_text(text)
    return root


def test_the_import_check_finds_a_violation(tmp_path):
    root = _tree(tmp_path, {
        "camnet/model/__init__.py": "",
        "camnet/model/bad.py": "import numpy\n\n\ndef f():\n    from camnet.io.formats import Calibration\n",
        "camnet/model/relative.py": "from .. import viz\nfrom . import projection\n",
        "camnet/model/up.py": "from camnet.solve.bundle import State\n",
        "camnet/model/fine.py": "from camnet.errors import InputError\nfrom camnet.model import projection\n",
        "camnet/solve/report/late.py": "def g():\n    from camnet.solve.pipeline import calibrate\n",
        "camnet/matching/late.py": "def g():\n    import camnet.bus.session\n",
        "camnet/io/helper.py": "from camnet.testing.ports import free_port\n",
        "camnet/testing/fine.py": "from camnet.testing.ports import free_port\n",
        "drivers/uses_node.py": "from camnet.services.calibrator import CalibratorNode\n",
        "services/fine.py": "from camnet.drivers_extra import x\n",
    })
    assert import_violations(root) == {
        ("camnet/model/bad.py", "camnet.io.formats"),
        ("camnet/model/relative.py", "camnet.viz"),
        ("camnet/model/up.py", "camnet.solve.bundle"),
        ("camnet/solve/report/late.py", "camnet.solve.pipeline"),
        ("camnet/matching/late.py", "camnet.bus.session"),
        ("camnet/io/helper.py", "camnet.testing.ports"),
        ("drivers/uses_node.py", "camnet.services.calibrator"),
    }


def test_the_circle_check_finds_a_circle(tmp_path):
    """A circle through a type-only import counts; a package whose __init__ imports its modules does not
    make a circle with the modules that import through it."""
    root = _tree(tmp_path, {
        "camnet/solve/__init__.py": "from camnet.solve.pipeline import calibrate\n",
        "camnet/solve/pipeline.py": "from camnet.solve import fit\n\n\ndef calibrate():\n    pass\n",
        "camnet/solve/fit.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                               "    from camnet.solve.choice import Result\n",
        "camnet/solve/choice.py": "from camnet.solve.fit import x\n",
        "camnet/solve/bundle.py": "import numpy\n",
        "camnet/live/policy.py": "from camnet.solve import calibrate, bundle\n",
    })
    graph = import_graph(root)
    assert graph["camnet.live.policy"] == {"camnet.solve", "camnet.solve.bundle"}
    assert circles(graph) == [["camnet.solve.choice", "camnet.solve.fit"]]


@pytest.mark.parametrize("relative", ["camnet/model/projection.py", "drivers/sim.py", "services/calibrator.py"])
def test_every_tree_is_read(relative):
    assert relative in {path for path, _, _ in modules()}
