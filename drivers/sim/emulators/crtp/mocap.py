"""The emulator's simulated motion capture, as a thread-safe :class:`drivers.vehicle.interfaces.PoseSource`.

Frames of the true pose are captured on the emulator thread at ``rate_hz`` (noise, latency,
drops and freezes from :class:`drivers.sim.sensors.SimMocap`) and handed over through a lock;
``poll`` returns every frame delivered since the last call. Frame times are emulator time.
"""

from __future__ import annotations

import threading

from drivers.sim.dynamics import Quadrotor
from drivers.sim.sensors import SimMocap
from drivers.vehicle.interfaces import PoseSample


class EmulatorMocap:
    """Implements :class:`drivers.vehicle.interfaces.PoseSource` for SITL (the Vicon stand-in)."""

    def __init__(self, sim: SimMocap) -> None:
        self.sim = sim
        self._lock = threading.Lock()
        self._out: list[PoseSample] = []
        self._k = 0
        self.next_s = 0.0

    def tick(self, t_s: float, body: Quadrotor) -> None:
        """Emulator thread: capture the frames due up to ``t_s`` and deliver the ripe ones."""
        period = self.sim.period_s
        while self.next_s <= t_s + 1e-9:
            self.sim.capture(self.next_s, body)
            self._k += 1
            self.next_s = self._k * period
            if self.next_s < t_s - 5 * period:  # stalled: skip instead of bursting
                self._k = int(t_s / period) + 1
                self.next_s = self._k * period
        ripe = self.sim.poll(t_s)
        if ripe:
            with self._lock:
                self._out.extend(ripe)

    def poll(self, now_s: float) -> list[PoseSample]:
        """Frames delivered since the last poll (``now_s`` is mission time, unused)."""
        with self._lock:
            out, self._out = self._out, []
        return out

    def expected_rate_hz(self) -> float:
        """Nominal frame rate."""
        return self.sim.rate_hz

    def freeze(self, frozen: bool = True) -> None:
        """Fault: repeat the last frame."""
        self.sim.freeze(frozen)

    def set_drop_probability(self, probability: float | None) -> None:
        """Fault: lose frames."""
        self.sim.set_drop_probability(probability)
