"""The simulated Crazyflie: body dynamics + firmware + onboard estimate + battery + wind.

:meth:`SimCrazyflie.step_to` advances physics at ``physics_rate_hz`` (500 Hz default) and the
firmware's position/velocity loop, estimator, battery and wind at 100 Hz. Contact with the
floor faster than ``hard_landing_speed_mps`` or with any world box ends the flight as crashed.
"""

from __future__ import annotations

import random

from drivers.sim.battery import SimBattery
from drivers.sim.dynamics import Quadrotor
from drivers.sim.estimator import OnboardEstimator
from drivers.sim.firmware import Firmware
from drivers.sim.wind import WindModel
from drivers.sim.world import World

FIRMWARE_RATE_HZ = 100.0


class SimCrazyflie:
    """One simulated drone in a world. Time advances only through :meth:`step_to`."""

    def __init__(
        self,
        params: dict,
        world: World | None,
        estimator: OnboardEstimator,
        wind: WindModel,
        start_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        start_yaw_rad: float = 0.0,
        physics_rate_hz: float = 500.0,
    ) -> None:
        self.params, self.world = params, world
        floor = world.floor_z_m if world is not None else 0.0
        self.body = Quadrotor(
            params, start_m[0], start_m[1], max(start_m[2], floor), start_yaw_rad, floor
        )
        self.estimator, self.wind = estimator, wind
        self.firmware = Firmware(params, self.body, estimator)
        self.battery = SimBattery(params)
        self.dt_s = 1.0 / physics_rate_hz
        self.sub = max(1, round(physics_rate_hz / FIRMWARE_RATE_HZ))
        self.n = 0  # physics steps taken; time = n * dt
        self.crashed = False
        self.collisions: list[dict] = []
        self.max_speed_mps = 0.0
        estimator.update(0.0, 0.0, self.body)

    @property
    def t_s(self) -> float:
        """Simulated time of the drone."""
        return self.n * self.dt_s

    def _crash(self, what: str, speed_mps: float) -> None:
        b = self.body
        self.collisions.append(
            {
                "t_s": round(self.t_s, 4),
                "with": what,
                "speed_mps": round(speed_mps, 3),
                "position_m": [round(b.x, 4), round(b.y, 4), round(b.z, 4)],
            }
        )
        self.crashed = True
        fw = self.firmware
        fw.crashed, fw.motors_running = True, False
        b.cmd_thrust_n = b.thrust_n = 0.0

    def step_to(self, t_s: float) -> None:
        """Advance the simulation to mission time ``t_s`` (no-op if already there)."""
        b, fw, dt, sub = self.body, self.firmware, self.dt_s, self.sub
        fw_dt = dt * sub
        world = self.world
        radius = self.params["radius_m"]
        hard = self.params["hard_landing_speed_mps"]
        wind = self.wind
        while (self.n + 1) * dt <= t_s + 1e-9:
            if self.n % sub == 0:
                t = self.n * dt
                wind.update(fw_dt)
                self.estimator.update(t, fw_dt, b)
                fw.control(t, fw_dt)
                self.battery.update(fw_dt, b.thrust_n)
            fw.attitude()
            impact = b.step(dt, wind.x, wind.y, wind.z)
            self.n += 1
            if self.crashed:
                continue
            if impact > hard:
                self._crash("floor", impact)
            elif world is not None and not b.on_ground:
                hit = world.collision(b.x, b.y, b.z, radius)
                if hit is not None:
                    self._crash(hit, b.speed_mps())
                    b.vx = b.vy = 0.0  # stuck against the obstacle; falls to the floor
            if b.on_ground is False:
                speed = b.speed_mps()
                if speed > self.max_speed_mps:
                    self.max_speed_mps = speed

    def true_state(self) -> dict:
        """Ground truth pose and velocity (for summaries and tests)."""
        b = self.body
        return {
            "x_m": b.x,
            "y_m": b.y,
            "z_m": b.z,
            "yaw_rad": b.yaw,
            "vx_mps": b.vx,
            "vy_mps": b.vy,
            "vz_mps": b.vz,
            "roll_rad": b.roll,
            "pitch_rad": b.pitch,
            "on_ground": b.on_ground,
        }


def make_rng(seed: int, component: str) -> random.Random:
    """A per-component random generator derived deterministically from one seed."""
    return random.Random(f"btrun/{seed}/{component}")
