"""The onboard state estimate of the simulated Crazyflie (what the firmware controls on).

Not a Kalman filter: a model of its errors. Position follows the truth while external poses
arrive (mocap forwarded over the link) and random-walks away when they stop; the yaw estimate
differs from the truth by a slowly wandering bias of a few degrees ([study], docs/references.md),
which rotates the thrust direction the controller asks for and so bends straight moves.
"""

from __future__ import annotations

import math
import random

from drivers.sim.dynamics import Quadrotor


class OnboardEstimator:
    """Estimated position, velocity and yaw, updated at the firmware rate."""

    def __init__(
        self,
        rng: random.Random,
        yaw_bias_deg: float = 3.0,
        yaw_bias_wander_deg: float = 1.0,
        yaw_bias_tau_s: float = 10.0,
        velocity_noise_mps: float = 0.005,
        drift_mps_per_sqrt_s: float = 0.05,
        extpos_timeout_s: float = 0.2,
    ) -> None:
        self.rng = rng
        sign = 1.0 if rng.random() < 0.5 else -1.0
        self.yaw_bias_rad = sign * math.radians(yaw_bias_deg) * (0.5 + 0.5 * rng.random())
        self._bias_mean = self.yaw_bias_rad
        self._bias_sigma = math.radians(yaw_bias_wander_deg)
        self._bias_tau = yaw_bias_tau_s
        self.velocity_noise_mps = velocity_noise_mps
        self.drift = drift_mps_per_sqrt_s
        self.extpos_timeout_s = extpos_timeout_s
        self.last_extpos_s = -math.inf
        self.ex = self.ey = self.ez = 0.0  # position error of the estimate (m)
        self.dvx = self.dvy = 0.0  # drift velocity while dead-reckoning
        self.x = self.y = self.z = 0.0
        self.vx = self.vy = self.vz = 0.0
        self.yaw = 0.0

    def external_pose(self, t_s: float) -> None:
        """An external pose arrived (the correction itself is modelled in :meth:`update`)."""
        self.last_extpos_s = t_s

    def update(self, t_s: float, dt_s: float, body: Quadrotor) -> None:
        """Refresh the estimate from the true state ``body``."""
        rng = self.rng
        if t_s - self.last_extpos_s <= self.extpos_timeout_s:
            k = math.exp(-dt_s / 0.05)  # the filter pulls the estimate back onto mocap
            self.ex *= k
            self.ey *= k
            self.ez *= k
            self.dvx = self.dvy = 0.0
        elif not body.on_ground:
            s = self.drift * math.sqrt(dt_s)
            self.dvx += rng.gauss(0.0, s)
            self.dvy += rng.gauss(0.0, s)
            self.ex += self.dvx * dt_s
            self.ey += self.dvy * dt_s
        if self._bias_sigma > 0.0:
            a = dt_s / self._bias_tau
            self.yaw_bias_rad += (self._bias_mean - self.yaw_bias_rad) * a + rng.gauss(
                0.0, self._bias_sigma * math.sqrt(2.0 * a)
            )
        n = self.velocity_noise_mps
        self.x, self.y, self.z = body.x + self.ex, body.y + self.ey, body.z + self.ez
        self.vx = body.vx - self.dvx + (rng.gauss(0.0, n) if n else 0.0)
        self.vy = body.vy - self.dvy + (rng.gauss(0.0, n) if n else 0.0)
        self.vz = body.vz + (rng.gauss(0.0, n) if n else 0.0)
        yaw = body.yaw + self.yaw_bias_rad
        self.yaw = (yaw + math.pi) % (2.0 * math.pi) - math.pi
