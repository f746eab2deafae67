"""Translational dynamics of a small quadrotor, with attitude as a fast first-order lag.

Plain Python floats throughout: numpy on 3-element arrays costs more than the arithmetic,
and this function runs 500 times per simulated second.

Frames: world z up. ``pitch_rad > 0`` tilts the thrust forward (+x of the body yaw frame),
``roll_rad > 0`` tilts it to the left (+y). The closed attitude loop of the firmware is
modelled as first-order lags on roll, pitch and yaw rate; motor thrust has its own lag.
"""

from __future__ import annotations

import math


class Quadrotor:
    """Rigid-body state plus the commands the onboard controller last set.

    Commands (set by :class:`~drivers.sim.firmware.Firmware`): ``cmd_thrust_n``,
    ``cmd_roll_rad``, ``cmd_pitch_rad``, ``cmd_yaw_rate_radps``.
    """

    def __init__(
        self,
        params: dict,
        x_m: float = 0.0,
        y_m: float = 0.0,
        z_m: float = 0.0,
        yaw_rad: float = 0.0,
        floor_z_m: float = 0.0,
    ) -> None:
        self.p = params
        self.x, self.y, self.z = x_m, y_m, z_m
        self.vx = self.vy = self.vz = 0.0
        self.roll = self.pitch = 0.0
        self.yaw, self.yaw_rate = yaw_rad, 0.0
        self.thrust_n = 0.0
        self.cmd_thrust_n = 0.0
        self.cmd_roll_rad = self.cmd_pitch_rad = self.cmd_yaw_rate_radps = 0.0
        self.floor_z = floor_z_m
        self.on_ground = z_m <= floor_z_m + 1e-9
        self.last_impact_mps = 0.0
        m = params["mass_kg"]
        self._inv_m = 1.0 / m
        self._g = params["gravity_mps2"]
        self._kxy = params["drag_xy_kgps"] / m
        self._kz = params["drag_z_kgps"] / m
        self._tau_att = params["attitude_time_constant_s"]
        self._tau_yaw = params["yaw_rate_time_constant_s"]
        self._tau_mot = params["motor_time_constant_s"]
        self._max_thrust = params["max_thrust_per_motor_n"] * params["motor_count"]

    def step(
        self, dt_s: float, wind_x: float = 0.0, wind_y: float = 0.0, wind_z: float = 0.0
    ) -> float:
        """Advance by ``dt_s``. Returns the impact speed (m/s) if the floor was hit, else 0."""
        # First-order lags (exact discretisation would be overkill at 500 Hz). Locals for
        # speed; every expression is evaluated as written, so results are bit for bit those
        # of the attribute-by-attribute form.
        a_att = dt_s / self._tau_att
        roll, pitch, yaw_rate, thrust = self.roll, self.pitch, self.yaw_rate, self.thrust_n
        roll += (self.cmd_roll_rad - roll) * a_att
        pitch += (self.cmd_pitch_rad - pitch) * a_att
        yaw_rate += (self.cmd_yaw_rate_radps - yaw_rate) * (dt_s / self._tau_yaw)
        cmd = min(max(self.cmd_thrust_n, 0.0), self._max_thrust)
        thrust += (cmd - thrust) * (dt_s / self._tau_mot)
        self.roll, self.pitch, self.yaw_rate, self.thrust_n = roll, pitch, yaw_rate, thrust

        sin, cos = math.sin, math.cos
        sr, cr = sin(roll), cos(roll)
        sp, cp = sin(pitch), cos(pitch)
        yaw = self.yaw
        sy, cy = sin(yaw), cos(yaw)
        f = thrust * self._inv_m
        fwd, left, up = f * sp * cr, f * sr, f * cp * cr
        vx, vy, vz = self.vx, self.vy, self.vz
        kxy = self._kxy
        ax = fwd * cy - left * sy + kxy * (wind_x - vx)
        ay = fwd * sy + left * cy + kxy * (wind_y - vy)
        az = up - self._g + self._kz * (wind_z - vz)

        if self.on_ground:
            if az <= 0.0:  # resting: the floor carries the weight, friction holds it
                self.vx = self.vy = self.vz = 0.0
                self.yaw_rate = 0.0
                return 0.0
            self.on_ground = False

        vx += ax * dt_s
        vy += ay * dt_s
        vz += az * dt_s
        self.vx, self.vy, self.vz = vx, vy, vz
        self.x += vx * dt_s
        self.y += vy * dt_s
        z = self.z + vz * dt_s
        self.z = z
        yaw += yaw_rate * dt_s
        if yaw > math.pi:
            yaw -= 2.0 * math.pi
        elif yaw < -math.pi:
            yaw += 2.0 * math.pi
        self.yaw = yaw

        if z <= self.floor_z:
            impact = -vz
            self.z = self.floor_z
            self.vx = self.vy = self.vz = 0.0
            self.on_ground = True
            self.last_impact_mps = impact
            return impact
        return 0.0

    def speed_mps(self) -> float:
        """Magnitude of the velocity."""
        return math.sqrt(self.vx * self.vx + self.vy * self.vy + self.vz * self.vz)
