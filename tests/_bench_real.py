"""benchmarks/bench_real.py loaded as a module, for the tests that use its scenes and its judgement."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_real.py"


def load_bench():
    """benchmarks/ is no package: the script loaded as a module."""
    spec = importlib.util.spec_from_file_location("bench_real", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up while it is being executed
    spec.loader.exec_module(module)
    return module
