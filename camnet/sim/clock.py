"""A simulated camera's clock: when it exposes frame slot k, and what time it stamps on that frame.

Two clocks, both in integer nanoseconds:

- The rig clock: the true time (the sim takes the host's Unix clock for it).
  Scenes move on it, and a triggered camera exposes slot k at ``k / fps`` of it.
- The camera clock: what the camera stamps. It reads the rig time minus
  `offset_ms`, and runs fast by `drift_ppm` (slow when negative) from the
  instant `epoch_ns` of the rig clock (when the camera's clock was set, the
  driver's start): ``camera(t) = t - offset + drift_ppm * 1e-6 * (t - epoch)``.

A free-running camera exposes slot k when its own clock reads
``(k + phase) / fps`` (`phase`: a fraction of a frame period), so its
exposures keep its own phase, its own offset, and a period shorter by
`drift_ppm` (longer when negative) on the rig clock; a triggered one (not
`free_run`) exposes at ``k / fps`` of the rig clock whatever its clock
reads. Either way the frame's stamp is the camera clock's reading `latency_ms`
after the exposure, and the frame is delivered then.

The formats contract's per-camera time, "the capture instant on the rig's
clock is the frame stamp plus `offset_ms`", is then at exposure instant t:
``offset_ms - latency_ms - drift_ppm * 1e-6 * (t + latency - epoch)`` in ms
(`true_offset_ms`): the sim's `offset_ms` is the contract's when there is no
latency and no drift, and drift moves the contract's offset by
``-drift_ppm`` microseconds per second.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from fractions import Fraction

NS_PER_S = 1_000_000_000
MAX_DRIFT_PPM = 1000.0  # crystal oscillators are within 100 ppm; beyond a thousand a value is a typo


@dataclass(frozen=True)
class SimClock:
    """A simulated camera's clock (see the module docstring for the model and its signs).

    `offset_ms`: the camera clock reads rig time minus this (ms). `drift_ppm`:
    the camera clock runs fast by this many parts per million. `latency_ms`
    (>= 0): from the exposure to its stamp and delivery. `free_run`: the camera
    exposes on its own clock, at `phase` (a fraction of a frame period in
    [0, 1)) past each of its ticks; else it is triggered on the rig clock's.
    """

    offset_ms: float = 0.0
    drift_ppm: float = 0.0
    latency_ms: float = 0.0
    free_run: bool = False
    phase: float = 0.0

    def __post_init__(self) -> None:
        if not self.latency_ms >= 0:
            raise ValueError(f"latency_ms must be >= 0, got {self.latency_ms}")
        if not abs(self.drift_ppm) <= MAX_DRIFT_PPM:
            raise ValueError(f"|drift_ppm| must be at most {MAX_DRIFT_PPM:g}, got {self.drift_ppm}")
        if not 0 <= self.phase < 1:
            raise ValueError(f"phase must be in [0, 1), got {self.phase}")

    @property
    def _offset_ns(self) -> int:
        return round(self.offset_ms * 1e6)

    @property
    def latency_ns(self) -> int:
        """From an exposure to its stamp and delivery (ns)."""
        return round(self.latency_ms * 1e6)

    def camera_time_ns(self, rig_ns: int, epoch_ns: int) -> int:
        """What the camera clock reads at rig time `rig_ns` (both ns), its clock set at rig time `epoch_ns`."""
        return rig_ns - self._offset_ns + round(self.drift_ppm * 1e-6 * (rig_ns - epoch_ns))

    def rig_time_ns(self, camera_ns: int, epoch_ns: int) -> int:
        """The rig time (ns) at which the camera clock reads `camera_ns`: `camera_time_ns`'s inverse, to 1 ns."""
        return epoch_ns + round((camera_ns + self._offset_ns - epoch_ns) / (1.0 + self.drift_ppm * 1e-6))

    def exposure_ns(self, slot: int, fps: Fraction, epoch_ns: int) -> int:
        """Rig time (ns) of frame slot `slot`'s exposure at `fps` frames per second.

        Triggered: ``slot * 1e9 / fps`` rounded down. Free-running: when the
        camera clock reads ``(slot + phase) / fps``.
        """
        tick_ns = slot * NS_PER_S * fps.denominator // fps.numerator
        if not self.free_run:
            return tick_ns
        return self.rig_time_ns(tick_ns + round(self.phase * NS_PER_S / fps), epoch_ns)

    def stamp_ns(self, exposure_ns: int, epoch_ns: int) -> int:
        """The frame's stamp (ns, camera clock) of an exposure at rig time `exposure_ns`."""
        return self.camera_time_ns(exposure_ns + self.latency_ns, epoch_ns)

    def slot_at(self, rig_ns: int, fps: Fraction, epoch_ns: int) -> int:
        """The last slot exposed at or before rig time `rig_ns`."""
        reading_ns = rig_ns if not self.free_run else self.camera_time_ns(rig_ns, epoch_ns)
        slot = reading_ns * fps.numerator // (NS_PER_S * fps.denominator)
        # The camera clock's rounding and the phase put the answer within a slot of this guess.
        while self.exposure_ns(slot, fps, epoch_ns) > rig_ns:
            slot -= 1
        while self.exposure_ns(slot + 1, fps, epoch_ns) <= rig_ns:
            slot += 1
        return slot

    def true_offset_ms(self, exposure_ns: int, epoch_ns: int) -> float:
        """The formats contract's `offset_ms` of this camera for an exposure at rig time `exposure_ns`:
        exposure (rig clock) minus stamp (camera clock), in ms, before the stamp's rounding to 1 ns."""
        since_epoch_ns = exposure_ns + self.latency_ms * 1e6 - epoch_ns
        return self.offset_ms - self.latency_ms - self.drift_ppm * 1e-6 * since_epoch_ns / 1e6


def free_run_phase(camera_id: str) -> float:
    """A free-running camera's phase (a fraction of a frame period in [0, 1)) from its id: each camera its
    own, the same in every run."""
    return zlib.crc32(camera_id.encode()) / 2**32
