"""Physical and firmware parameters of the simulated Crazyflie 2.x (plain dict, rotorpy-style).

Gains and limits follow the Crazyflie firmware's PID position controller as summarised in
[firmware] in docs/references.md; values marked (approx.) are estimates, tune them from a rig file with
``sim.params.<name>``.
"""

from __future__ import annotations

crazyflie_params: dict[str, float] = {
    # Inertial and aerodynamic properties
    "mass_kg": 0.034,  # Crazyflie 2.1 with battery, AI-deck and markers (approx.)
    "gravity_mps2": 9.81,
    "drag_xy_kgps": 0.01,  # linear drag (rotor drag dominated), N per m/s (approx.)
    "drag_z_kgps": 0.01,
    "radius_m": 0.06,  # collision sphere (92 mm motor-to-motor diagonal + props)
    # Actuation
    "max_thrust_per_motor_n": 0.12,
    "motor_count": 4,
    "motor_time_constant_s": 0.03,  # thrust first-order lag (approx.)
    "attitude_time_constant_s": 0.05,  # closed attitude loop as a first-order lag (approx.)
    "yaw_rate_time_constant_s": 0.05,  # closed yaw-rate loop (approx.)
    "max_tilt_deg": 20.0,  # rpLimit of the velocity loop
    "max_yaw_rate_dps": 200.0,  # yaw-rate limit of the attitude controller (approx.)
    # Firmware position/velocity PID (100 Hz), units as in the firmware
    "pos_xy_kp": 2.0,
    "pos_xy_ki": 0.0,
    "pos_z_kp": 2.0,
    "pos_z_ki": 0.5,
    "vel_max_xy_mps": 1.1,  # output limit of the position loop (approx.)
    "vel_max_z_mps": 1.1,
    "vel_xy_kp_deg_per_mps": 25.0,  # velocity PID x,y -> pitch/roll in degrees
    "vel_xy_ki_deg_per_m": 1.0,
    "vel_z_kp": 25.0,  # velocity PID z -> thrust, scaled by thrust_scale_pwm
    "vel_z_ki": 15.0,
    "thrust_scale_pwm": 1000.0,
    "pwm_max": 65535.0,
    # Firmware attitude PID (500 Hz): only yaw is modelled explicitly
    "yaw_kp": 6.0,  # deg/s per deg
    # Commander watchdog (firmware): level after 0.5 s, motors off after 2 s without set-points
    "setpoint_stabilize_timeout_s": 0.5,
    "setpoint_shutdown_timeout_s": 2.0,
    # Ground contact and crashes
    "hard_landing_speed_mps": 1.0,  # touching the floor faster than this is a crash (approx.)
    "tumble_tilt_deg": 60.0,
    # Battery (250 mAh 1S LiPo, ~7 min hover)
    "battery_capacity_mah": 250.0,
    "battery_internal_resistance_ohm": 0.15,
    "battery_idle_current_a": 0.1,  # electronics, decks, radio
    "battery_current_coeff": 11.0,  # motor current = coeff * thrust_N ** 1.5 (approx.)
    "battery_initial_soc": 1.0,
}

#: What each parameter may be (a rig's ``sim.params`` is checked against it before anything
#: flies): ``(lowest, highest, meaning)``. Generous, a drone much larger or smaller than a
#: Crazyflie fits; nonsense does not: a zero mass or time constant divides by zero, a
#: negative mass or a drone too heavy for its motors never flies. The bounds that come from
#: the simulation itself: drag up to 1 N per m/s on a mass of at least 0.01 kg decays the
#: velocity in no less than one 100 Hz physics step (the slowest ``sim.physics_rate_hz``), as
#: the explicit integration needs. The rig loader also checks what no single parameter shows:
#: the motors lift more than the weight, each time constant is at least one physics step, the
#: tumble angle is beyond the tilt limit and the watchdog levels before it stops the motors.
crazyflie_param_limits: dict[str, tuple[float, float, str]] = {
    "mass_kg": (0.01, 10.0, "take-off mass (kg)"),
    "gravity_mps2": (1.0, 30.0, "gravity (m/s^2)"),
    "drag_xy_kgps": (0.0, 1.0, "horizontal linear drag (N per m/s)"),
    "drag_z_kgps": (0.0, 1.0, "vertical linear drag (N per m/s)"),
    "radius_m": (0.01, 2.0, "collision sphere radius (m)"),
    "max_thrust_per_motor_n": (0.01, 100.0, "thrust of one motor at full PWM (N)"),
    "motor_count": (1, 16, "number of motors (a whole number)"),
    "motor_time_constant_s": (0.001, 2.0, "motor thrust first-order lag (s)"),
    "attitude_time_constant_s": (0.001, 2.0, "closed attitude loop first-order lag (s)"),
    "yaw_rate_time_constant_s": (0.001, 2.0, "closed yaw-rate loop first-order lag (s)"),
    "max_tilt_deg": (1.0, 80.0, "roll/pitch limit of the velocity loop (deg)"),
    "max_yaw_rate_dps": (1.0, 2000.0, "yaw-rate limit of the attitude controller (deg/s)"),
    "pos_xy_kp": (0.01, 100.0, "position loop x, y: P gain (1/s)"),
    "pos_xy_ki": (0.0, 100.0, "position loop x, y: I gain"),
    "pos_z_kp": (0.01, 100.0, "position loop z: P gain (1/s)"),
    "pos_z_ki": (0.0, 100.0, "position loop z: I gain"),
    "vel_max_xy_mps": (0.01, 20.0, "output limit of the position loop, x, y (m/s)"),
    "vel_max_z_mps": (0.01, 20.0, "output limit of the position loop, z (m/s)"),
    "vel_xy_kp_deg_per_mps": (0.01, 1000.0, "velocity loop x, y -> pitch/roll: P (deg per m/s)"),
    "vel_xy_ki_deg_per_m": (0.0, 1000.0, "velocity loop x, y -> pitch/roll: I (deg per m)"),
    "vel_z_kp": (0.01, 1000.0, "velocity loop z -> thrust: P (times thrust_scale_pwm)"),
    "vel_z_ki": (0.0, 1000.0, "velocity loop z -> thrust: I (times thrust_scale_pwm)"),
    "thrust_scale_pwm": (1.0, 65535.0, "PWM units per unit of the z velocity loop's output"),
    "pwm_max": (1000.0, 65535.0, "full-thrust PWM (the firmware's 16-bit 65535)"),
    "yaw_kp": (0.01, 100.0, "yaw angle loop: P gain (deg/s per deg)"),
    "setpoint_stabilize_timeout_s": (0.01, 60.0, "watchdog: level after this without set-points"),
    "setpoint_shutdown_timeout_s": (0.01, 60.0, "watchdog: motors off after this silence"),
    "hard_landing_speed_mps": (0.01, 20.0, "touching the floor faster is a crash (m/s)"),
    "tumble_tilt_deg": (1.0, 180.0, "tilt beyond which the drone has tumbled (deg)"),
    "battery_capacity_mah": (50.0, 100000.0, "battery capacity (mAh; as battery.capacity_mah)"),
    "battery_internal_resistance_ohm": (0.0, 10.0, "battery internal resistance (ohm)"),
    "battery_idle_current_a": (0.0, 50.0, "electronics, decks, radio current (A)"),
    "battery_current_coeff": (0.0, 1000.0, "motor current = coeff * thrust_N ** 1.5 (A)"),
    "battery_initial_soc": (0.0, 1.0, "state of charge at start (as battery.initial_soc)"),
}
#: Parameters that count things: whole numbers.
crazyflie_integer_params = frozenset({"motor_count"})


def thrust_per_pwm_n(params: dict[str, float]) -> float:
    """Total thrust (N) per firmware PWM unit (all motors together)."""
    return params["max_thrust_per_motor_n"] * params["motor_count"] / params["pwm_max"]
