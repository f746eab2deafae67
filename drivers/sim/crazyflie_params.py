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


def thrust_per_pwm_n(params: dict[str, float]) -> float:
    """Total thrust (N) per firmware PWM unit (all motors together)."""
    return params["max_thrust_per_motor_n"] * params["motor_count"] / params["pwm_max"]
