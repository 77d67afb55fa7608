"""`camnet calibrate` writes the same calibration documents as before (golden files in tests/golden/).

The golden outputs were written by `camnet calibrate` itself before the solve's
outcome became a typed report; they hold the contract's keys and every further
key of docs/calibration-keys.md. Timings differ from run to run and are left
out; numbers are compared to a relative 1e-6 (BLAS builds round differently).
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

GOLDEN = Path(__file__).parent / "golden"

CASES = [
    ("sim-observations.json", "sim-refined.json", []),
    ("sim-observations.json", "sim-paper.json", ["--method", "paper"]),
    ("ring6-observations.json", "ring6-refined.json", []),
    ("ring6-observations.json", "ring6-warm.json", ["--initial", str(GOLDEN / "ring6-refined.json")]),
]


def same(a, b, path="") -> list[str]:
    """Where the documents `a` and `b` differ, as JSON paths (numbers to a relative 1e-6, the pair checks' to 1e-3)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}.{k}: only in one" for k in sorted(set(a) ^ set(b))]
        for k in sorted(set(a) & set(b)):
            out += same(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items vs {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in same(x, y, f"{path}[{i}]")]
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        # The pair check refines each pair to a thousandth of its cost (camnet.model.pair_pose_check).
        rel_tol, abs_tol = (1e-3, 1e-4) if path.startswith(".diagnostics.pair_checks") else (1e-6, 1e-9)
        return [] if math.isclose(a, b, rel_tol=rel_tol, abs_tol=abs_tol) else [f"{path}: {a!r} vs {b!r}"]
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


@pytest.mark.parametrize(("observations", "expected", "flags"), CASES, ids=[c[1] for c in CASES])
def test_calibrate_writes_the_golden_document(tmp_path, observations, expected, flags):
    out = tmp_path / "calibration.json"
    proc = subprocess.run(
        [sys.executable, "-m", "camnet", "calibrate", str(GOLDEN / observations), "-o", str(out), *flags],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    written, golden = json.loads(out.read_text()), json.loads((GOLDEN / expected).read_text())
    written.pop("timings_s"), golden.pop("timings_s")
    assert list(written) == list(golden), "the keys' order changed"
    differences = same(written, golden)
    assert not differences, differences[:10]


def test_the_comparison_can_fail():
    golden = json.loads((GOLDEN / "sim-refined.json").read_text())
    changed = json.loads(json.dumps(golden))
    changed["uncertainty"]["cameras"]["mono_a"]["f_px"] *= 1.001
    changed["diagnostics"]["warnings"].append("new")
    assert len(same(golden, changed)) == 2
