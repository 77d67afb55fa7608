"""Giving the heap's freed memory back to the operating system, every few seconds.

glibc's malloc keeps what a process frees for its next allocations: it
returns memory by itself only from the top of a heap, and only when the
free block there is large. A node that allocates and frees large buffers
at every frame set or solve (the matcher's descriptors and match matrices,
the calibrator's Jacobians: numpy and OpenCV arrays of tens to hundreds of
KB, below glibc's threshold for mapping them alone) leaves free blocks
between the ones still in use, and its resident memory steps by tens of MB
and stays there, though Python's objects and the bytes in use stay flat.
`malloc_trim(0)` hands the free pages of every arena back (madvise), and
costs milliseconds on such heaps, so a node calls it at most every few
seconds from its loop (`camnet.bus.node.Presence`, `trim_heap_period_s`).
Elsewhere than glibc (musl, macOS) there is no `malloc_trim` and nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import threading
import time

# Trimming a matcher's heap this often costs under 1% of a core (docs/benchmarks.md, "Sixteen cameras across hosts").
TRIM_PERIOD_S = 5.0


@functools.cache
def _malloc_trim():
    """libc's malloc_trim, or None where there is none."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Give every arena's free pages back to the operating system; True if any memory was released."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False


class HeapTrim:
    """`release_free_heap` at most once every `period_s`, whichever thread asks (nodes on threads of one
    process, such as a camera host's, share one heap)."""

    def __init__(self, period_s: float = TRIM_PERIOD_S) -> None:
        self.period_s = period_s
        self._lock = threading.Lock()
        self._next_s = time.monotonic() + period_s
        self.trims = 0
        self.seconds = 0.0  # spent trimming, in all

    def if_due(self, now_s: float) -> None:
        with self._lock:
            if now_s < self._next_s:
                return
            self._next_s = now_s + self.period_s
        t0_s = time.perf_counter()
        release_free_heap()
        with self._lock:
            self.trims += 1
            self.seconds += time.perf_counter() - t0_s


_process_trims: dict[float, HeapTrim] = {}
_process_lock = threading.Lock()


def process_trim(period_s: float = TRIM_PERIOD_S) -> HeapTrim:
    """The process's one `HeapTrim` of `period_s`: nodes sharing a process share its heap and its trims."""
    with _process_lock:
        return _process_trims.setdefault(period_s, HeapTrim(period_s))
