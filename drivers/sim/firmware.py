"""The onboard software of the simulated Crazyflie: commander, watchdog and PID controller.

Mirrors the firmware's cascaded PID position controller ([firmware], docs/references.md):
position (100 Hz) -> velocity -> roll/pitch in degrees (clamped to +-20 deg) and thrust in
PWM units; yaw angle -> yaw rate. The attitude loop itself is the first-order lag in
:mod:`drivers.sim.dynamics`. The commander watchdog levels the drone 0.5 s after the last
set-point and stops the motors after 2 s, like the firmware.
"""

from __future__ import annotations

import math

from drivers.sim.crazyflie_params import thrust_per_pwm_n
from drivers.sim.dynamics import Quadrotor
from drivers.sim.estimator import OnboardEstimator

POSITION, VELOCITY, STOP = "position", "velocity", "stop"


def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


class Firmware:
    """Commander + controller. Call :meth:`control` at 100 Hz and :meth:`attitude` at 500 Hz."""

    def __init__(self, params: dict, body: Quadrotor, estimator: OnboardEstimator) -> None:
        self.p, self.body, self.est = params, body, estimator
        self.armed = False
        self.motors_running = False
        self.crashed = False
        self.mode = STOP
        self.sp = [0.0, 0.0, 0.0, 0.0]  # x y z yaw_rad | vx vy vz yaw_rate
        self.last_setpoint_s = -math.inf
        self.watchdog_level = False
        self._ix = self._iy = self._iz_pos = self._ivz = 0.0
        self._per_pwm = thrust_per_pwm_n(params)
        self._thrust_base = params["mass_kg"] * params["gravity_mps2"] / self._per_pwm
        self._tilt = math.radians(params["max_tilt_deg"])
        self._yaw_rate_max = math.radians(params["max_yaw_rate_dps"])
        self._yaw_sp = 0.0
        self._last_pwm = 0.0

    # ------------------------------------------------------------ commander (link side)
    def setpoint(self, t_s: float, mode: str, values: tuple[float, float, float, float]) -> None:
        """A set-point packet arrived."""
        if self.crashed:
            return
        self.last_setpoint_s = t_s
        if mode == STOP:
            self.mode, self.motors_running = STOP, False
            self._reset_integrators()
            return
        if not self.armed:
            return
        if not self.motors_running:
            self._reset_integrators()
            self._yaw_sp = self.est.yaw
        self.mode, self.motors_running = mode, True
        self.sp[:] = values

    def arm(self, armed: bool) -> None:
        """Supervisor arming request."""
        if self.crashed:
            return
        self.armed = armed
        if not armed:
            self.motors_running = False

    def emergency_stop(self) -> None:
        """Cut the motors."""
        self.motors_running = False
        self.mode = STOP

    def _reset_integrators(self) -> None:
        self._ix = self._iy = self._iz_pos = self._ivz = 0.0

    # ------------------------------------------------------------ control (100 Hz)
    def control(self, t_s: float, dt_s: float) -> None:
        """Position and velocity loops; writes thrust and attitude commands to the body."""
        b, p, e = self.body, self.p, self.est
        if not self.motors_running or self.crashed:
            b.cmd_thrust_n = 0.0
            b.cmd_roll_rad = b.cmd_pitch_rad = b.cmd_yaw_rate_radps = 0.0
            return
        silent = t_s - self.last_setpoint_s
        if silent > p["setpoint_shutdown_timeout_s"]:
            self.motors_running = False
            self.mode = STOP
            b.cmd_thrust_n = 0.0
            return
        if silent > p["setpoint_stabilize_timeout_s"]:
            # Firmware: level attitude, zero yaw rate, keep the last thrust.
            self.watchdog_level = True
            b.cmd_roll_rad = b.cmd_pitch_rad = b.cmd_yaw_rate_radps = 0.0
            b.cmd_thrust_n = self._last_pwm * self._per_pwm
            return
        self.watchdog_level = False
        sp = self.sp
        if self.mode == POSITION:
            vmax_xy, vmax_z = p["vel_max_xy_mps"], p["vel_max_z_mps"]
            ex, ey, ez = sp[0] - e.x, sp[1] - e.y, sp[2] - e.z
            self._iz_pos = _clamp(self._iz_pos + ez * dt_s, -2.0, 2.0)
            vx_sp = _clamp(p["pos_xy_kp"] * ex, -vmax_xy, vmax_xy)
            vy_sp = _clamp(p["pos_xy_kp"] * ey, -vmax_xy, vmax_xy)
            vz_sp = _clamp(p["pos_z_kp"] * ez + p["pos_z_ki"] * self._iz_pos, -vmax_z, vmax_z)
            self._yaw_sp = sp[3]
        else:
            vx_sp, vy_sp, vz_sp = sp[0], sp[1], sp[2]
            self._yaw_sp = math.remainder(self._yaw_sp + sp[3] * dt_s, 2.0 * math.pi)
        # Velocity loop in the world frame, outputs rotated into the *estimated* yaw frame.
        evx, evy, evz = vx_sp - e.vx, vy_sp - e.vy, vz_sp - e.vz
        self._ix = _clamp(self._ix + evx * dt_s, -5.0, 5.0)
        self._iy = _clamp(self._iy + evy * dt_s, -5.0, 5.0)
        kp, ki = p["vel_xy_kp_deg_per_mps"], p["vel_xy_ki_deg_per_m"]
        ax_deg = kp * evx + ki * self._ix
        ay_deg = kp * evy + ki * self._iy
        cy, sy = math.cos(e.yaw), math.sin(e.yaw)
        tilt = self._tilt
        b.cmd_pitch_rad = _clamp(math.radians(ax_deg * cy + ay_deg * sy), -tilt, tilt)
        b.cmd_roll_rad = _clamp(math.radians(-ax_deg * sy + ay_deg * cy), -tilt, tilt)
        self._ivz = _clamp(self._ivz + evz * dt_s, -2.0, 2.0)
        pwm = (
            self._thrust_base
            + (p["vel_z_kp"] * evz + p["vel_z_ki"] * self._ivz) * p["thrust_scale_pwm"]
        )
        pwm = _clamp(pwm, 0.0, p["pwm_max"])
        self._last_pwm = pwm
        b.cmd_thrust_n = pwm * self._per_pwm

    def attitude(self) -> None:
        """Yaw angle loop (runs with the attitude loop, 500 Hz)."""
        b = self.body
        if not self.motors_running or self.watchdog_level:
            return
        err = math.remainder(self._yaw_sp - b.yaw - self.est.yaw_bias_rad, 2.0 * math.pi)
        rate = self.p["yaw_kp"] * err
        b.cmd_yaw_rate_radps = _clamp(rate, -self._yaw_rate_max, self._yaw_rate_max)
