"""One BLAS thread for a block of work, shared by the solver and the matcher.

Their products are small (a Schur block, a pair's few thousand descriptor
rows): BLAS threads save no wall time on them and, on a loaded machine,
double their CPU. The libraries loaded are found once, since a search costs
milliseconds.
"""

from __future__ import annotations

import functools


@functools.cache
def _controller():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_thread():
    """A context manager in which numpy's and scipy's BLAS run on one thread."""
    return _controller().limit(limits=1, user_api="blas")
