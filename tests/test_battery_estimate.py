"""BatteryAbove reads a state of charge that does not sag under load, and says what it read."""

from __future__ import annotations

from helpers import sim_mission, wrap

from drivers.rig.harness import SimHarness
from nodes.energy import PERCENT_KEY, steady_percent


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


def _check_through_a_sag(drop_v: float, duration_s: float) -> str:
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5" takeoff_point="{home}"/>
      <ReactiveSequence>
        <EnoughEnergy target="{home}" home="{home}" speed="1.0" task_time="0" period="1"
                      reserve="15"/>
        <Sleep msec="20000"/>
      </ReactiveSequence>
      <Land/>
    </Sequence>"""
    )
    faults = {"faults.battery_sag.at_s": 12.5, "faults.battery_sag.duration_s": duration_s,
              "faults.battery_sag.drop_v": drop_v}  # fmt: skip
    _, runner, _ = sim_mission(xml, overrides=faults)
    result = runner.run(max_time_s=60)
    return result.status


def test_a_lasting_sag_still_stops_the_work_and_a_stale_reading_is_not_used() -> None:
    """EnoughEnergy reads the charge as the median over 3 s (the gauge dips for a moment
    when the drone brakes or climbs: validation seed 102 of the site stopped a pass on such
    a dip); a drop that lasts is real and still stops the work. EnoughEnergyForPass reads
    that steady value only while it is fresh."""
    assert _check_through_a_sag(0.4, 10.0) == "FAILURE"

    class Ctx:
        resources = {PERCENT_KEY: (100.0, 40.0)}

    assert steady_percent(Ctx(), 101.0, 35.0) == 40.0  # read 1 s ago: the steady value
    assert steady_percent(Ctx(), 105.0, 35.0) == 35.0  # stale: the gauge now


def test_a_check_evaluated_once_per_battery_does_not_time_the_changes_as_tasks() -> None:
    """EnoughEnergy checked only right after each take-off on a fresh battery read about
    the same charge each time, so it never saw a new battery: from the third change its
    readings spanned the changes, and the time between them was taken as the time a task
    takes (validation probe, site seed 304: FAILURE on a 98 % battery, 60 places not
    scanned). ChangeBattery now tells it."""
    xml = wrap(
        """    <Repeat num_cycles="4">
      <Sequence>
        <ChangeBattery mode="swap" duration="1"/>
        <TakeOff height="1.0" speed="0.5" takeoff_point="{home}"/>
        <EnoughEnergy name="after_change" target="{home}" home="{home}" speed="1.0"
                      task_time="0" endurance="60" reserve="15"/>
        <Land/>
        <Sleep msec="50000"/>
      </Sequence>
    </Repeat>"""
    )
    _, runner, _ = sim_mission(xml)
    result = runner.run(max_time_s=400)
    assert result.status == "SUCCESS", result.reason


def test_a_check_another_energy_check_interleaves_does_not_time_the_other_work() -> None:
    """The sweep's EnoughEnergy before a rescan is evaluated after passes that left places,
    and its readings spanned the passes between (other energy checks ran there): the
    time of whole passes was taken as the time one rescan takes, and a battery the rescans
    had fitted in was changed (about 80 s lost in a probe's run). Only the intervals no other
    energy check interleaves are tasks."""
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5" takeoff_point="{home}"/>
      <Repeat num_cycles="3">
        <Sequence>
          <EnoughEnergy name="before_rescan" target="{home}" home="{home}" speed="1.0"
                        task_time="5" landing_time="1" reserve="10"/>
          <Sleep msec="2000"/>
          <EnoughEnergy name="beside_pass" target="{home}" home="{home}" speed="1.0"
                        task_time="0" landing_time="1" reserve="10"/>
          <Sleep msec="40000"/>
        </Sequence>
      </Repeat>
      <Repeat num_cycles="3">
        <Sequence>
          <EnoughEnergy name="one_after_another" target="{home}" home="{home}" speed="1.0"
                        task_time="30" landing_time="1" reserve="10"/>
          <Sleep msec="3000"/>
        </Sequence>
      </Repeat>
      <Land/>
    </Sequence>"""
    )
    m, runner, _ = sim_mission(xml)
    result = runner.run(max_time_s=400)
    assert result.status == "SUCCESS", result.reason
    rescan = m.node("before_rescan")
    # the 42 s between its evaluations held another check and a pass: not a task (the
    # assumed 5 s stays); before, two such intervals made every rescan a 42 s task
    assert " 6 s to the next task" in rescan.failure_reason, rescan.failure_reason
    after = m.node("one_after_another")  # nothing between: 3 s tasks, measured
    assert " 4 s to the next task" in after.failure_reason, after.failure_reason
