"""BatteryAbove reads a state of charge that does not sag under load, and says what it read."""

from __future__ import annotations

from helpers import sim_mission, wrap

from drivers.rig.harness import SimHarness


def test_state_of_charge_in_flight_follows_the_truth_not_the_loaded_voltage() -> None:
    h = SimHarness.create(seed=0)
    v, battery = h.vehicle, h.platform.drone.battery
    p = v.takeoff(1.0)
    assert h.run_until(lambda: p.settled, timeout_s=10)
    h.run_for(60.0)
    b = v.battery
    truth = 100.0 * battery.soc
    assert b.sag_v > 0.15  # the loaded voltage reads far lower than the charge left ...
    assert abs(b.percent - truth) < 6.0, (b, truth)  # ... the estimate does not


def test_battery_above_succeeds_in_flight_and_a_failure_names_the_value() -> None:
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <Sleep msec="8000"/>
      <BatteryAbove percent="30"/>
      <BatteryAbove percent="99.9" name="too_high"/>
      <Land/>
    </Sequence>"""
    )
    m, runner, _ = sim_mission(xml)
    result = runner.run(max_time_s=60)
    assert result.status == "FAILURE"
    assert "too_high" in result.reason and "not above 99.9 %" in result.reason, result.reason
    assert "state of charge" in result.reason
