"""Simulated motion capture: a 100 Hz pose stream with noise, latency, dropouts and freezes."""

from __future__ import annotations

import math
import random
from collections import deque

from drivers.sim.dynamics import Quadrotor
from drivers.vehicle.angles import quaternion_from_euler
from drivers.vehicle.interfaces import PoseSample


class SimMocap:
    """Captures the true pose every ``1/rate_hz`` and delivers it ``latency_s`` later.

    Faults: :meth:`freeze` makes the server repeat its last frame (same sequence number, so
    the Vehicle sees it as stale); :meth:`set_drop_probability` loses frames (gaps in the
    sequence numbers count as drops).
    """

    def __init__(
        self,
        rng: random.Random,
        rate_hz: float = 100.0,
        position_noise_std_m: float = 3e-5,
        orientation_noise_std_deg: float = 0.05,
        latency_s: float = 0.005,
        dropout_probability: float = 0.0,
    ) -> None:
        self.rng = rng
        self.rate_hz = rate_hz
        self.period_s = 1.0 / rate_hz
        self.pos_std = position_noise_std_m
        self.ori_std = math.radians(orientation_noise_std_deg)
        self.latency_s = latency_s
        self.base_drop_p = dropout_probability
        self.drop_p = dropout_probability
        self.frozen = False
        self.seq = 0
        self._queue: deque[tuple[float, PoseSample]] = deque()
        self._last: PoseSample | None = None

    def expected_rate_hz(self) -> float:
        """Nominal frame rate."""
        return self.rate_hz

    def capture(self, t_s: float, body: Quadrotor) -> None:
        """Take one frame of the true pose at mission time ``t_s``."""
        if self.frozen:
            if self._last is not None:
                self._queue.append((t_s + self.latency_s, self._last))
            return
        self.seq += 1
        rng = self.rng
        if self.drop_p > 0.0 and rng.random() < self.drop_p:
            return
        g, ps, os_ = rng.gauss, self.pos_std, self.ori_std
        roll = body.roll + g(0.0, os_)
        pitch = body.pitch + g(0.0, os_)
        yaw = math.remainder(body.yaw + g(0.0, os_), 2.0 * math.pi)
        sample = PoseSample(
            t_s,
            body.x + g(0.0, ps),
            body.y + g(0.0, ps),
            body.z + g(0.0, ps),
            quaternion_from_euler(roll, pitch, yaw),
            yaw,
            self.seq,
        )
        self._last = sample
        self._queue.append((t_s + self.latency_s, sample))

    def poll(self, now_s: float) -> list[PoseSample]:
        """Frames whose delivery time has come."""
        out = []
        q = self._queue
        while q and q[0][0] <= now_s + 1e-9:
            out.append(q.popleft()[1])
        return out

    def freeze(self, frozen: bool = True) -> None:
        """Freeze (True) or unfreeze the stream."""
        self.frozen = frozen

    def set_drop_probability(self, probability: float | None) -> None:
        """Lose frames with ``probability`` (None restores the rig's dropout rate)."""
        self.drop_p = self.base_drop_p if probability is None else float(probability)
