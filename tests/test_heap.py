"""camnet.bus.heap: freed blocks between live ones go back to the operating system only when trimmed."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from camnet.bus.heap import HeapTrim, _malloc_trim, process_trim

# Run in a fresh interpreter: its heap holds nothing freed before, whatever ran in this process.
# Arrays of 96 KB are below glibc's threshold for mapping a block alone (128 KB, and it only rises),
# so they come from the heap, like the matcher's descriptors and match matrices; a small buffer kept
# after each one keeps the freed arrays from being the top of the heap, which free() returns by itself.
PATTERN = textwrap.dedent("""
    import sys
    import numpy as np
    from camnet.bus.heap import release_free_heap

    def rss_mb():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096 / 2**20

    arrays, kept = [], []
    for _ in range(1000):
        arrays.append(np.ones(96 * 1024 // 8))
        kept.append(bytearray(4096))
    full = rss_mb()
    del arrays
    freed = rss_mb()
    if sys.argv[1] == "trim":
        release_free_heap()
    print(full, freed, rss_mb())
""")
ARRAYS_MB = 1000 * 96 / 1024


def _rss_after(action: str) -> tuple[float, float, float]:
    out = subprocess.run([sys.executable, "-c", PATTERN, action], capture_output=True, text=True, timeout=120,
                         check=True).stdout
    full, freed, after = (float(x) for x in out.split())
    return full, freed, after


@pytest.mark.skipif(_malloc_trim() is None or not sys.platform.startswith("linux"),
                    reason="no malloc_trim (not glibc)")
def test_trim_returns_freed_arrays_that_free_alone_keeps() -> None:
    full, freed, untrimmed = _rss_after("none")
    # Without a trim, glibc keeps what the arrays held: the process stays about as large as at its peak.
    assert full - untrimmed < 0.25 * ARRAYS_MB, (full, freed, untrimmed)
    full, freed, trimmed = _rss_after("trim")
    assert full - trimmed > 0.75 * ARRAYS_MB, (full, freed, trimmed)


def test_trims_at_most_once_a_period_across_callers() -> None:
    trim = HeapTrim(period_s=10.0)
    start_s = trim._next_s - 10.0
    for now_s in (start_s, start_s + 5.0, start_s + 10.0, start_s + 12.0, start_s + 19.0, start_s + 20.5):
        trim.if_due(now_s)
    assert trim.trims == 2  # at +10 and at +20.5
    assert process_trim(7.0) is process_trim(7.0)
