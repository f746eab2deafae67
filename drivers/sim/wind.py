"""Wind: a mean, random gusts (Ornstein-Uhlenbeck per axis) and injected gusts."""

from __future__ import annotations

import math
import random


class WindModel:
    """World-frame wind velocity (m/s), updated at a fixed rate."""

    def __init__(
        self,
        rng: random.Random,
        mean_mps: tuple[float, float, float] = (0, 0, 0),
        gust_std_mps: float = 0.0,
        gust_time_constant_s: float = 2.0,
    ) -> None:
        self.rng = rng
        self.mean = tuple(float(v) for v in mean_mps)
        self.std, self.tau = gust_std_mps, gust_time_constant_s
        self.turb = [0.0, 0.0, 0.0]
        self.injected = (0.0, 0.0, 0.0)  # fault "gust"
        self.x, self.y, self.z = self.mean

    def update(self, dt_s: float) -> None:
        """Advance the gust process by ``dt_s``."""
        if self.std > 0.0:
            a = dt_s / self.tau
            s = self.std * math.sqrt(2.0 * a)
            for i in range(3):
                self.turb[i] += -self.turb[i] * a + self.rng.gauss(0.0, s)
        ix, iy, iz = self.injected
        self.x = self.mean[0] + self.turb[0] + ix
        self.y = self.mean[1] + self.turb[1] + iy
        self.z = self.mean[2] + self.turb[2] * 0.3 + iz
