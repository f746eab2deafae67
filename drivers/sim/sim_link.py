"""The in-process link to the simulated Crazyflie (what cflib is to a real one).

Set-points, arming and external poses reach the simulated firmware at once; telemetry (the
onboard estimate, battery, flags) comes back at ``telemetry_rate_hz``. Faults: :meth:`drop`
cuts the link both ways (set-points stop reaching the drone, so its watchdog stops the
motors 2 s later); ``loss_probability`` loses single packets.
"""

from __future__ import annotations

import random

from drivers.sim.drone import SimCrazyflie
from drivers.sim.firmware import POSITION, STOP, VELOCITY
from drivers.vehicle.angles import quaternion_from_euler
from drivers.vehicle.interfaces import LinkTelemetry


class SimLink:
    """Implements :class:`drivers.vehicle.interfaces.Link` over a :class:`SimCrazyflie`."""

    def __init__(
        self,
        drone: SimCrazyflie,
        rng: random.Random,
        telemetry_rate_hz: float = 100.0,
        loss_probability: float = 0.0,
    ) -> None:
        self.drone, self.rng = drone, rng
        self.period_s = 1.0 / telemetry_rate_hz
        self.loss_probability = loss_probability
        self.up = True
        self.sent = 0
        self.lost = 0
        self._last_tel_s = -1e9

    @property
    def connected(self) -> bool:
        """True while the link is up."""
        return self.up

    def drop(self, down: bool = True) -> None:
        """Take the link down (True) or bring it back (False)."""
        self.up = not down

    def _through(self) -> bool:
        if not self.up:
            self.lost += 1
            return False
        if self.loss_probability > 0.0 and self.rng.random() < self.loss_probability:
            self.lost += 1
            return False
        self.sent += 1
        return True

    def arm(self, armed: bool) -> bool:
        if self._through():
            self.drone.firmware.arm(armed)
            return True
        return False

    def send_position_setpoint(self, x_m: float, y_m: float, z_m: float, yaw_rad: float) -> None:
        if self._through():
            self.drone.firmware.setpoint(self.drone.t_s, POSITION, (x_m, y_m, z_m, yaw_rad))

    def send_velocity_setpoint(
        self, vx_mps: float, vy_mps: float, vz_mps: float, yaw_rate_radps: float
    ) -> None:
        if self._through():
            self.drone.firmware.setpoint(
                self.drone.t_s, VELOCITY, (vx_mps, vy_mps, vz_mps, yaw_rate_radps)
            )

    def send_stop_setpoint(self) -> None:
        if self._through():
            self.drone.firmware.setpoint(self.drone.t_s, STOP, (0.0, 0.0, 0.0, 0.0))

    def send_external_pose(
        self, x_m: float, y_m: float, z_m: float, quaternion: tuple[float, float, float, float]
    ) -> None:
        if self._through():
            self.drone.estimator.external_pose(self.drone.t_s)

    def emergency_stop(self) -> None:
        if self._through():
            self.drone.firmware.emergency_stop()

    def poll(self, now_s: float) -> list[LinkTelemetry]:
        if now_s - self._last_tel_s < self.period_s - 1e-9:
            return []
        self._last_tel_s = now_s
        if not self._through():
            return []
        d = self.drone
        e, b, fw = d.estimator, d.body, d.firmware
        return [
            LinkTelemetry(
                now_s,
                e.x,
                e.y,
                e.z,
                e.vx,
                e.vy,
                e.vz,
                e.yaw,
                quaternion_from_euler(b.roll, b.pitch, e.yaw),
                d.battery.voltage_v,
                fw.armed,
                fw.motors_running,
                d.crashed,
            )
        ]

    def battery_service(self, kind: str) -> str:
        """``swap``: a fresh battery; ``charge`` / ``stop_charging``: the charging pad's
        current on or off. "" when done, else why not (link down, motors running)."""
        if not self.up:
            return "the link is down"
        fw, battery = self.drone.firmware, self.drone.battery
        if fw.motors_running or not self.drone.body.on_ground:
            return "the drone must be on the ground with its motors off"
        if kind == "swap":
            battery.swap(float(self.drone.params.get("battery_swap_soc", 1.0)))
        elif kind in ("charge", "stop_charging"):
            battery.charging = kind == "charge"
        else:
            return f"unknown battery service {kind!r} (swap, charge, stop_charging)"
        return ""

    def close(self) -> None:
        self.up = False
