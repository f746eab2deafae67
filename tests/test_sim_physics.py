"""The simulated Crazyflie: firmware loops, watchdog, ground contact, battery, collisions."""

import math
import random

import pytest

from drivers.rig.harness import SimHarness
from drivers.sim.battery import SimBattery
from drivers.sim.crazyflie_params import crazyflie_params
from drivers.sim.drone import SimCrazyflie
from drivers.sim.estimator import OnboardEstimator
from drivers.sim.firmware import POSITION
from drivers.sim.wind import WindModel
from drivers.vehicle.types import FlightState, YawMode


def bare_drone(start=(0.0, 0.0, 0.0)):
    rng = random.Random(0)
    est = OnboardEstimator(rng, yaw_bias_deg=0.0, yaw_bias_wander_deg=0.0, velocity_noise_mps=0)
    return SimCrazyflie(dict(crazyflie_params), None, est, WindModel(rng), start)


def test_firmware_position_loop_climbs_to_a_setpoint_and_respects_limits():
    d = bare_drone()
    d.firmware.arm(True)
    max_tilt = max_vz = 0.0
    for k in range(1, 400):  # 4 s at 100 Hz set-points
        t = k * 0.01
        d.estimator.external_pose(t)
        d.firmware.setpoint(t, POSITION, (0.0, 0.0, 1.0, 0.0))
        d.step_to(t)
        max_tilt = max(max_tilt, abs(d.body.pitch), abs(d.body.roll))
        max_vz = max(max_vz, d.body.vz)
    assert d.body.z == pytest.approx(1.0, abs=0.1)
    assert max_vz <= 1.3  # position loop output limit (~1.1 m/s) plus a little overshoot
    assert max_tilt <= math.radians(20.0) + 1e-9


def test_watchdog_stops_the_motors_2_s_after_the_last_setpoint():
    d = bare_drone()
    d.firmware.arm(True)
    for k in range(1, 200):
        d.estimator.external_pose(k * 0.01)
        d.firmware.setpoint(k * 0.01, POSITION, (0.0, 0.0, 0.5, 0.0))
        d.step_to(k * 0.01)
    last = 1.99
    d.step_to(last + 1.9)
    assert d.firmware.motors_running and d.firmware.watchdog_level
    d.step_to(last + 2.05)
    assert not d.firmware.motors_running
    d.step_to(last + 3.0)
    assert d.body.on_ground and d.crashed and d.collisions[0]["with"] == "floor"


def test_gentle_touchdown_is_not_a_crash_but_a_drop_is():
    d = bare_drone(start=(0.0, 0.0, 0.05))
    d.step_to(1.0)  # 5 cm fall: about 1 m/s would be needed to break it
    assert d.body.on_ground and not d.crashed
    d = bare_drone(start=(0.0, 0.0, 1.0))
    d.step_to(1.0)
    assert d.crashed and d.collisions[0]["speed_mps"] > 4.0


def test_battery_lasts_about_seven_minutes_of_hover():
    params = dict(crazyflie_params)
    b = SimBattery(params)
    hover_n = params["mass_kg"] * params["gravity_mps2"]
    t = 0.0
    while b.voltage_v > 3.2 and t < 900:
        b.update(0.1, hover_n)
        t += 0.1
    assert 5.5 * 60 < t < 8.0 * 60
    assert 3.0 < b.voltage_v <= 3.2


def test_hover_holds_position_within_a_few_centimetres():
    h = SimHarness.create(seed=4)
    p = h.vehicle.takeoff(0.255, 0.3)
    assert h.run_until(lambda: p.settled, 10.0)
    h.run_for(3.0)
    errors = []
    h.run_for(
        5.0,
        on_tick=lambda: errors.append(
            math.dist(
                (h.platform.drone.body.x, h.platform.drone.body.y, h.platform.drone.body.z),
                (0.0, 0.0, 0.255),
            )
        ),
    )
    assert max(errors) < 0.03


def test_flying_into_a_pallet_crashes():
    h = SimHarness.create(seed=5)
    v = h.vehicle
    p = v.takeoff(0.1, 0.3)
    assert h.run_until(lambda: p.settled, 10.0)
    world = h.platform.world
    row = [pl for pl in world.pallets if pl.identity != world.scan_pallet][0]
    g = v.go_to(row.x_m, row.y_m, 0.1, YawMode.KEEP_YAW, 0.0, 1.0)
    assert h.run_until(lambda: v.is_crashed, 40.0)
    assert g.failed and g.reason == "crashed"
    s = h.platform.summary()
    assert s["crashed"] and s["collisions"][0]["with"] == f"pallet {row.pallet_id}"
    assert v.flight_state == FlightState.CRASHED


def test_scan_height_flight_passes_over_the_floor_pallets():
    h = SimHarness.create(seed=6)
    v = h.vehicle
    p = v.takeoff(0.255, 0.5)
    assert h.run_until(lambda: p.settled, 10.0)
    g = v.go_to(9.3, 1.55, 0.255, YawMode.KEEP_YAW, 0.0, 1.0)  # over pallet top (0.144 m)
    assert h.run_until(lambda: g.settled, 30.0) and not v.is_crashed
