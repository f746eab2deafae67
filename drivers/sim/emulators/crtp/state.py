"""The simulated Crazyflie behind the CRTP ports: the simulator's drone plus what ports share.

:class:`EmulatedCrazyflie` wraps a :class:`drivers.sim.drone.SimCrazyflie` (the same body,
firmware, estimator and battery the lock-step simulator flies) and derives the IMU readings
(``gyro.*`` in deg/s, ``acc.*`` in g, body frame) from successive states. It is only touched
from the emulator thread (or under :attr:`CrtpEmulator.lock`).
"""

from __future__ import annotations

import math
from typing import Any

from drivers.sim.crazyflie_params import crazyflie_params
from drivers.sim.drone import SimCrazyflie, make_rng
from drivers.sim.estimator import OnboardEstimator
from drivers.sim.wind import WindModel
from drivers.sim.world import World
from drivers.vehicle.angles import quaternion_from_euler

PROTOCOL_VERSION = 12  # current firmware: supervisor port 9 arming, velocity-world set-points


def build_sim_drone(rig_data: dict[str, Any], seed: int, world: World | None) -> SimCrazyflie:
    """A :class:`SimCrazyflie` configured from rig data exactly as ``SimPlatform`` does."""
    s, ob, w = rig_data["sim"], rig_data["sensors"]["onboard"], rig_data["wind"]
    params: dict[str, float] = dict(crazyflie_params)
    params["battery_initial_soc"] = rig_data["battery"]["initial_soc"]
    params["battery_capacity_mah"] = rig_data["battery"]["capacity_mah"]
    params.update(s["params"])
    estimator = OnboardEstimator(
        make_rng(seed, "estimator"),
        ob["yaw_bias_deg"],
        ob["yaw_bias_wander_deg"],
        velocity_noise_mps=ob["velocity_noise_mps"],
        drift_mps_per_sqrt_s=ob["drift_mps_per_sqrt_s"],
    )
    wind = WindModel(
        make_rng(seed, "wind"), tuple(w["mean_mps"]), w["gust_std_mps"], w["gust_time_constant_s"]
    )
    return SimCrazyflie(
        params,
        world,
        estimator,
        wind,
        tuple(s["start_m"]),
        math.radians(s["start_yaw_deg"]),
        s["physics_rate_hz"],
    )


class EmulatedCrazyflie:
    """The drone plus shared firmware state seen through CRTP."""

    def __init__(self, drone: SimCrazyflie, protocol_version: int = PROTOCOL_VERSION) -> None:
        self.drone = drone
        self.protocol_version = protocol_version
        self.last_extpose: tuple[float, ...] | None = None  # x y z [qx qy qz qw]
        self.extpose_count = 0
        self.setpoint_count = 0
        self.last_setpoint: tuple[str, tuple[float, float, float, float]] | None = None
        self.notify_stop_count = 0
        self.gyro_dps = (0.0, 0.0, 0.0)
        self.acc_g = (0.0, 0.0, 1.0)
        b = drone.body
        self._prev = (drone.t_s, b.roll, b.pitch, b.yaw, b.vx, b.vy, b.vz)

    @property
    def t_s(self) -> float:
        """Firmware time (s since the emulator started)."""
        return self.drone.t_s

    def step_to(self, t_s: float) -> None:
        """Advance the drone to ``t_s`` and refresh the IMU readings."""
        d = self.drone
        d.step_to(t_s)
        b = d.body
        t0, r0, p0, y0, vx0, vy0, vz0 = self._prev
        dt = d.t_s - t0
        if dt < 1e-3:
            return
        rem = math.remainder
        self.gyro_dps = (
            math.degrees(rem(b.roll - r0, 2 * math.pi) / dt),
            math.degrees(rem(b.pitch - p0, 2 * math.pi) / dt),
            math.degrees(rem(b.yaw - y0, 2 * math.pi) / dt),
        )
        g = d.params["gravity_mps2"]
        ax, ay, az = (b.vx - vx0) / dt, (b.vy - vy0) / dt, (b.vz - vz0) / dt + g
        cy, sy = math.cos(b.yaw), math.sin(b.yaw)  # world -> body (yaw only; tilt is small)
        self.acc_g = ((cy * ax + sy * ay) / g, (-sy * ax + cy * ay) / g, az / g)
        self._prev = (d.t_s, b.roll, b.pitch, b.yaw, b.vx, b.vy, b.vz)

    # ------------------------------------------------------------------ views for the log
    def quaternion(self) -> tuple[float, float, float, float]:
        """Onboard attitude estimate (qx, qy, qz, qw): true roll/pitch, estimated yaw."""
        b, e = self.drone.body, self.drone.estimator
        return quaternion_from_euler(b.roll, b.pitch, e.yaw)

    def tumbled(self) -> bool:
        """Tilted beyond the firmware's tumble limit."""
        b = self.drone.body
        lim = math.radians(self.drone.params["tumble_tilt_deg"])
        return abs(b.roll) > lim or abs(b.pitch) > lim

    def supervisor_bits(self) -> int:
        """The supervisor state bitfield (cflib ``Supervisor.STATES`` order)."""
        fw = self.drone.firmware
        crashed = fw.crashed or self.drone.crashed
        bits = 0
        if not crashed:
            bits |= 1 << 0  # can be armed
        if fw.armed:
            bits |= 1 << 1
            if not crashed:
                bits |= 1 << 3  # can fly
        if fw.motors_running:
            bits |= 1 << 4  # is flying
        if self.tumbled():
            bits |= 1 << 5
        if crashed:
            bits |= 1 << 7
        return bits
