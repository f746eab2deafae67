"""Fly the simulated drone through the Vehicle API, tick by tick, on a simulated clock."""

import math

import pytest

from drivers.rig.harness import SimHarness
from drivers.vehicle.types import FlightState, YawMode

D = math.radians


def airborne(seed=1, mode="velocity", height=0.5):
    h = SimHarness.create(seed, {"control.setpoint_mode": mode})
    p = h.vehicle.takeoff(height, 0.5)
    assert h.run_until(lambda: p.settled, 10.0), p
    return h


def test_takeoff_reaches_height_and_reports_flying():
    h = SimHarness.create(seed=1)
    v = h.vehicle
    assert v.is_landed and not v.is_armed
    p = v.takeoff(0.5, 0.5)
    assert v.flight_state == FlightState.TAKING_OFF and v.is_armed  # auto-armed
    assert h.run_until(lambda: p.settled, 10.0)
    assert v.flight_state == FlightState.FLYING and v.is_flying
    assert v.position[2] == pytest.approx(0.5, abs=0.05)
    assert v.health.link.healthy and v.health.mocap.healthy
    assert v.health.mocap.rate_hz == pytest.approx(100, abs=5)
    assert 3.8 < v.battery.voltage_v < 4.1 and 0 < v.battery.percent < 100  # sag under load


@pytest.mark.parametrize("mode", ["velocity", "position"])
def test_go_to_path_facing_faces_the_direction_of_travel(mode):
    h = airborne(mode=mode)
    g = h.vehicle.go_to(1.0, 1.0, 0.5, YawMode.PATH_FACING, 0.0, 0.5)
    assert g.goal_yaw_rad == pytest.approx(D(45), abs=D(2))
    assert h.run_until(lambda: g.settled, 15.0), g
    assert h.vehicle.position[:2] == pytest.approx((1.0, 1.0), abs=0.05)
    assert abs(g.yaw_error_rad) < D(15)
    assert h.vehicle.yaw_rad == pytest.approx(D(45), abs=D(8))  # onboard yaw bias ~ 3 deg


def test_go_to_keep_yaw_keeps_the_yaw_and_fixed_yaw_turns():
    h = airborne()
    v = h.vehicle
    yaw0 = v.reference.yaw_rad
    g = v.go_to(1.0, -0.5, 0.6, YawMode.KEEP_YAW, 0.0, 0.5)
    assert h.run_until(lambda: g.settled, 15.0)
    assert g.goal_yaw_rad == yaw0 and v.yaw_rad == pytest.approx(yaw0, abs=D(8))
    g = v.go_to(1.0, -0.5, 0.6, YawMode.FIXED_YAW, D(-90), 0.5)
    assert h.run_until(lambda: g.settled, 15.0)
    assert v.yaw_rad == pytest.approx(D(-90), abs=D(8))


def test_path_facing_keeps_yaw_for_short_horizontal_moves():
    h = airborne()
    yaw0 = h.vehicle.reference.yaw_rad
    g = h.vehicle.go_to(0.05, 0.05, 1.0, YawMode.PATH_FACING, 0.0, 0.5)
    assert g.goal_yaw_rad == yaw0


def test_yaw_turns_the_shortest_way():
    h = airborne()
    v = h.vehicle
    g = v.go_to(0.0, 0.0, 0.5, YawMode.FIXED_YAW, D(170), 0.5)
    assert h.run_until(lambda: g.settled, 15.0)
    g = v.go_to(0.0, 0.0, 0.5, YawMode.FIXED_YAW, D(-170), 0.5)
    yaws = []
    assert h.run_until(lambda: g.settled, 5.0, on_tick=lambda: yaws.append(v.yaw_rad))
    assert min(abs(y) for y in yaws) > D(150)  # went through 180, not through 0
    assert g.elapsed_s < 2.0  # 20 deg, not 340 deg


def test_progress_reports_distance_and_wrapped_yaw_error_each_tick():
    h = airborne()
    v = h.vehicle
    g = v.go_to(2.0, 0.0, 0.5, YawMode.FIXED_YAW, D(179), 0.5)
    distances = []
    h.run_for(2.0, on_tick=lambda: distances.append(g.distance_m))
    assert distances[0] == pytest.approx(2.0, abs=0.1)
    assert distances[-1] < distances[0] - 0.5
    assert -math.pi <= g.yaw_error_rad <= math.pi and not g.reached
    assert h.run_until(lambda: g.settled, 15.0)
    assert g.reference_done and g.distance_m < 0.05 and not g.failed


def test_new_request_cancels_the_previous_one():
    h = airborne()
    g1 = h.vehicle.go_to(2.0, 0.0, 0.5)
    h.run_for(0.5)
    g2 = h.vehicle.go_to(0.0, 0.0, 0.5)
    assert g1.cancelled and not g1.active and "go_to" in g1.reason
    assert h.run_until(lambda: g2.settled, 10.0)


def test_go_to_before_takeoff_fails():
    h = SimHarness.create(seed=1)
    g = h.vehicle.go_to(1.0, 0.0, 0.5)
    assert g.failed and "not flying" in g.reason


def test_follow_path_visits_the_waypoints():
    h = airborne()
    v = h.vehicle
    seen = []
    p = v.follow_path([(1, 0, 0.5), (1, 1, 0.5), (0, 1, 0.5)], 0.5, YawMode.PATH_FACING)
    assert h.run_until(lambda: p.settled, 25.0, on_tick=lambda: seen.append(v.position)), p
    assert min(math.dist(q, (1, 1, 0.5)) for q in seen) < 0.1
    assert v.yaw_rad == pytest.approx(math.pi, abs=D(8)) or abs(v.yaw_rad) > D(172)


def test_hover_stops_and_holds():
    h = airborne()
    v = h.vehicle
    v.go_to(3.0, 0.0, 0.5)
    h.run_for(1.5)
    p = v.hover()
    assert h.run_until(lambda: p.settled, 5.0)
    x = v.position[0]
    h.run_for(2.0)
    assert v.position[0] == pytest.approx(x, abs=0.03)


def test_land_stops_the_motors_and_allows_disarm():
    h = airborne()
    v = h.vehicle
    p = v.land(0.4)
    assert v.flight_state == FlightState.LANDING
    assert h.run_until(lambda: p.reached, 10.0)
    assert v.is_landed and not h.platform.drone.firmware.motors_running
    assert v.disarm() and not v.is_armed
    s = h.platform.summary()
    assert s["landed"] and not s["crashed"] and s["final_pose"]["z_m"] == 0.0


def test_emergency_stop_cuts_the_motors():
    h = airborne(height=0.3)
    v = h.vehicle
    g = v.go_to(1.0, 0.0, 0.3)
    v.emergency_stop()
    assert g.failed and v.flight_state == FlightState.EMERGENCY
    h.run_for(1.0)
    assert h.platform.drone.body.on_ground
