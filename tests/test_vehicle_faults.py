"""Faults injected from a test change what the Vehicle reports."""

import pytest

from drivers.rig.harness import SimHarness
from drivers.vehicle.types import FlightState


def airborne(overrides=None, seed=2):
    h = SimHarness.create(seed, overrides)
    p = h.vehicle.takeoff(0.5, 0.5)
    assert h.run_until(lambda: p.settled, 10.0)
    return h


def test_link_drop_makes_the_link_unhealthy_and_the_watchdog_cuts_motors_after_2_s():
    h = airborne()
    v, fw = h.vehicle, h.platform.drone.firmware
    g = v.go_to(1.0, 0.0, 0.5)
    t_drop = h.now_s
    h.platform.faults.inject("link_drop")
    h.run_for(0.6)
    assert not v.health.link.healthy and v.health.link.age_s >= 0.5
    assert g.failed and g.reason == "link lost"
    assert fw.motors_running  # levelled by the watchdog, still spinning
    assert h.run_until(lambda: not fw.motors_running, 3.0)
    assert h.now_s - t_drop == pytest.approx(2.0, abs=0.05)
    h.run_for(1.0)
    assert h.platform.drone.body.on_ground
    s = h.platform.summary()
    assert s["crashed"]  # a 0.5 m fall is a hard landing
    assert s["faults"][0]["name"] == "link_drop"


def test_mocap_freeze_goes_stale_and_the_pose_falls_back_to_onboard():
    h = airborne()
    v = h.vehicle
    h.platform.faults.inject("mocap_freeze")
    h.run_for(0.3)
    m = v.health.mocap
    assert not m.healthy and m.age_s >= 0.25 and m.rate_hz > 50  # frames keep coming, frozen
    assert v.pose.source == "onboard"
    h.platform.faults.clear("mocap_freeze")
    h.run_for(0.1)
    assert v.health.mocap.healthy and v.pose.source == "mocap"


def test_mocap_drop_counts_drops():
    h = airborne()
    h.platform.faults.inject("mocap_drop", probability=0.5)
    h.run_for(1.0)
    assert h.vehicle.health.mocap.drops > 20


def test_battery_sag_lowers_the_voltage():
    h = airborne()
    v = h.vehicle
    h.run_for(1.0)
    before = v.battery.voltage_v
    h.platform.faults.inject("battery_sag", drop_v=0.8)
    h.run_for(6.0)
    assert v.battery.voltage_v == pytest.approx(before - 0.8, abs=0.05)
    assert v.battery.low


def test_faults_scheduled_from_the_rig_fire_at_their_time():
    h = airborne({"faults.battery_sag.at_s": "3.0", "faults.battery_sag.duration_s": "1.0"})
    h.run_until(lambda: h.now_s >= 5.0, 10.0)
    fired = h.platform.summary()["faults"]
    assert fired == [
        {
            "name": "battery_sag",
            "t_s": 3.0,
            "params": {"duration_s": 1.0, "drop_v": 0.5},
            "cleared_s": 4.0,
        }
    ]


def test_schedule_from_python_and_camera_stall():
    h = SimHarness.create(seed=3)
    h.platform.faults.schedule("camera_stall", at_s=0.5, duration_s=0.5)
    seen: list[tuple[float, float]] = []  # (now, newest frame time) every tick

    def look() -> None:
        f = h.vehicle.camera_frame()
        seen.append((h.clock.now(), f.t_s if f is not None else -1.0))

    h.run_for(1.5, on_tick=look)
    assert [f["name"] for f in h.platform.faults.summary()] == ["camera_stall"]
    assert h.platform.faults.active() == []
    stalled = [frame_t for now, frame_t in seen if 0.6 <= now < 1.0]
    assert stalled and max(stalled) <= 0.5 + 1e-9  # no new frame while stalled
    assert seen[-1][1] > 1.0  # frames again once the fault cleared


def test_gust_pushes_the_drone():
    h = airborne()
    h.platform.faults.inject("gust", speed_mps=[3.0, 0.0, 0.0], duration_s=1.0)
    xs = []
    h.run_for(1.5, on_tick=lambda: xs.append(h.platform.drone.body.x))
    assert max(xs) > 0.02


def test_unknown_fault_names_are_refused_with_a_suggestion():
    h = SimHarness.create(seed=3)
    with pytest.raises(ValueError, match="did you mean 'link_drop'"):
        h.platform.faults.inject("link_dorp")
    with pytest.raises(ValueError, match="no parameter"):
        h.platform.faults.inject("battery_sag", volts=1)


def test_crash_is_reported_by_the_vehicle():
    h = airborne()
    h.platform.faults.inject("link_drop")
    h.run_for(3.0)  # motors cut after 2 s, the drone falls
    h.platform.faults.clear("link_drop")  # link back: the telemetry tells the truth
    h.run_for(2.0)
    assert h.vehicle.flight_state == FlightState.CRASHED and h.vehicle.is_crashed
