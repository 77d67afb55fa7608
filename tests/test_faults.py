"""A short fault run on a live 30 fps sim rig: a mono camera goes silent, calibrations go on.

The benchmark (`benchmarks/bench_faults.py`) does every fault at full length;
this is its harness with one short fault, so that CI stays fast.
"""

import importlib.util
import sys
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_faults.py"


def bench_faults():
    spec = importlib.util.spec_from_file_location("bench_faults", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_faults", module)  # its dataclasses look their module up by name
    spec.loader.exec_module(sys.modules["bench_faults"])
    module = sys.modules["bench_faults"]
    return module


def test_calibrations_go_on_while_a_mono_camera_is_silent(tmp_path):
    faults = bench_faults()
    with faults.Network(tmp_path, faults.rig_document("monoout", fps=30.0, side_px=320)) as net:
        # Progress-based: the first calibration comes when the machine lets it; the margin is generous.
        assert net.wait_calibration(net.started_s, 240.0) is not None, "no first calibration"
        result = faults.measure(net, "silent", faults.silent_camera("mono_b", 6.0, check_status=True),
                                recover_s=120.0)
        assert result.alive, [c.log_tail() for c in net.launch.exited()]
        assert "first calibration during it after none" not in result.note, result.note
        assert "shown MISSING by status" in result.note, result.note
        assert result.lost == 0 and result.next_s is not None, result
        status = faults.run_status(net)
        assert "MISSING" not in status, status  # it came back
        started_s = time.monotonic()
        assert net.wait_calibration(started_s, 120.0) is not None
