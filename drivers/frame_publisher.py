"""Putting a driver's frame messages on the bus, through Zenoh shared memory when it can.

A frame message handed to `put` as bytes is copied twice on its way to a
subscriber on the same host: into a Zenoh buffer, then into the shared
memory Zenoh passes large messages through. Copied once into a
shared-memory buffer of our own instead, it goes out with no further copy
(a subscriber on another host gets it over the network as before; Zenoh
copies it out of shared memory for that link), which saves publisher CPU
(docs/benchmarks.md, "Bus, recording, Rerun"; benchmarks/bench_bus.py).

The shared-memory API (`zenoh.shm`) is marked unstable in Zenoh: where it
is missing, fails to set up, or has no room left (subscribers still hold
earlier frames), a message goes out as bytes, as before. `shared` and
`copied` count which way the frames went, `pools` the pools set up.

The driver node leaves it off by default (`DriverNode(shared_memory=...)`):
at high frame rates on a loaded host, frames through shared memory are lost
where the same node putting bytes loses few or none, and subscribers fall
behind (docs/benchmarks.md, "Bus, recording, Rerun"; docs/bus-benchmark.md).
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

# Smaller messages are not worth a shared-memory buffer (Zenoh's own threshold is 3 KB).
MIN_SHARED_BYTES = 64 * 1024
# The pool holds this many messages (subscribers release each as soon as they have copied it out)...
POOL_MESSAGES = 8
# ...but no more bytes than this, unless that is less than two messages.
MAX_POOL_BYTES = 64 * 1024 * 1024


class FramePublisher:
    """`put(message)` on a Zenoh publisher, through a shared-memory buffer when possible."""

    def __init__(self, publisher, *, shared_memory: bool = True) -> None:
        self._publisher = publisher
        self._provider = None
        self._retired = None  # the pool before it grew: frames in flight may still be in it
        self._policy = None
        self._shm_errors: tuple[type[Exception], ...] = ()
        self._pool_for = 0  # the largest message the pool was made for
        self._enabled = shared_memory
        self.shared = 0
        self.copied = 0
        self.pools = 0  # set up so far

    def put(self, message: bytes | bytearray) -> None:
        """Publish `message`; it may be overwritten as soon as this returns."""
        if not self._enabled:  # the default: a camera's every frame comes this way
            self._publisher.put(message)
            self.copied += 1
            return
        size = len(message)
        if size >= MIN_SHARED_BYTES and (size <= self._pool_for or self._make_pool(size)):
            try:
                chunk = self._provider.alloc(size, self._policy)
            except self._shm_errors:
                chunk = None  # no room: subscribers still hold earlier frames
            if chunk is not None:
                chunk[:] = message
                self._publisher.put(chunk)
                self.shared += 1
                return
        self._publisher.put(message)
        self.copied += 1

    def _make_pool(self, size: int) -> bool:
        """Set up a pool for messages of up to `size` bytes; False (and shared memory off) if it cannot be."""
        if self._pool_for:
            # A larger message than the pool was made for (compressed frames vary): grow by half at
            # least, so that a growing size sets up few pools.
            size = max(size, self._pool_for * 3 // 2)
        try:
            import zenoh
            from zenoh import shm

            pool_bytes = max(2 * size, min(POOL_MESSAGES * size, MAX_POOL_BYTES))
            self._retired, self._provider = self._provider, shm.ShmProvider.default_backend(pool_bytes)
            # When the pool is full, first reclaim the buffers subscribers have released.
            self._policy = shm.GarbageCollect()
            self._shm_errors = (zenoh.ZError,)
        except Exception as exc:  # noqa: BLE001 (an unstable API: whatever fails, bytes still work)
            log.info("frames go out without Zenoh shared memory (%s: %s)", type(exc).__name__, exc)
            self._enabled = False
            return False
        self._pool_for = size
        self.pools += 1
        return True
