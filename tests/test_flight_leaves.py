"""Flight leaves on the simulator, tick by tick: thresholds, yaw modes, time-outs, halts."""

from __future__ import annotations

import math

import pytest
from helpers import sim_mission, wrap

TAKEOFF = '<TakeOff name="takeoff" height="1.0"/>'


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def fly_to_start(xml_body: str, **kw):
    m, run, pf = sim_mission(wrap(f"<Sequence>{TAKEOFF}{xml_body}</Sequence>"), **kw)
    run.run_until(lambda mm: mm.status_of("takeoff") == "SUCCESS" or mm.ticks > 400, 1000)
    return m, run, pf


def test_goto_stays_running_until_both_thresholds_hold():
    m, run, pf = fly_to_start(
        '<GoTo name="go" pose="1.5;0;1" yaw_mode="FIXED_YAW" yaw_angle_deg="90" '
        'pos_threshold="0.03" yaw_threshold_deg="15"/>'
    )
    v = pf.vehicle
    seen_running_outside = False
    for _ in range(2000):
        run.step()
        st = m.status_of("go") if m.status.value == "RUNNING" else "DONE"
        dist = math.dist(v.position, (1.5, 0.0, 1.0))
        yaw_err = abs(_wrap_deg(90.0 - math.degrees(v.yaw_rad)))
        if st == "RUNNING":
            if dist > 0.03 or yaw_err > 15.0:
                seen_running_outside = True
        else:
            # the tick GoTo returned SUCCESS, both errors were inside their thresholds
            assert dist <= 0.035 and yaw_err <= 15.0, (dist, yaw_err)
            break
    else:
        pytest.fail("GoTo never finished")
    assert seen_running_outside
    assert m.status.value == "SUCCESS"


def test_yaw_from_plus_170_to_minus_170_turns_20_degrees_not_340():
    m, run, pf = fly_to_start(
        '<GoTo name="a" pose="0;0;1" yaw_mode="FIXED_YAW" yaw_angle_deg="170"/>'
        '<GoTo name="b" pose="0;0;1" yaw_mode="FIXED_YAW" yaw_angle_deg="-170"/>'
    )
    run.run_until(lambda mm: mm.status_of("b") == "RUNNING", 3000)
    v = pf.vehicle
    assert abs(_wrap_deg(math.degrees(v.yaw_rad) - 170.0)) < 15.0
    yaws = []
    run.run_until(
        lambda mm: yaws.append(math.degrees(v.yaw_rad)) or mm.status.value != "RUNNING", 3000
    )
    assert m.status.value == "SUCCESS"
    # every yaw on the way stayed within the short 20-degree arc through 180
    assert all(abs(y) >= 160.0 for y in yaws), min(abs(y) for y in yaws)


def test_path_facing_faces_the_direction_of_travel():
    m, run, pf = fly_to_start(
        '<GoTo name="go" pose="1;1;1" yaw_mode="PATH_FACING" max_speed="0.5"/>'
    )
    v = pf.vehicle
    run.run_until(
        lambda mm: math.dist(v.position[:2], (0, 0)) > 0.7 or mm.status.value != "RUNNING", 3000
    )
    assert abs(_wrap_deg(math.degrees(v.yaw_rad) - 45.0)) < 15.0
    vel = v.velocity
    travel = math.degrees(math.atan2(vel.vy_mps, vel.vx_mps))
    assert abs(_wrap_deg(travel - 45.0)) < 10.0
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "SUCCESS"


def test_aerostack2_integer_yaw_mode_is_path_facing():
    m, run, pf = fly_to_start(
        '<Action ID="GoTo" name="go" pose="0;1;1" yaw_mode="1" max_speed="0.5"/>'
    )
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "SUCCESS"
    assert abs(_wrap_deg(math.degrees(pf.vehicle.yaw_rad) - 90.0)) < 15.0


def test_timeout_fails_the_node_and_the_drone_holds():
    m, run, pf = fly_to_start('<GoTo name="go" pose="5;0;1" max_speed="0.5" timeout="2"/>')
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "FAILURE"
    assert m.last_failure.startswith("GoTo 'go' failed")
    v = pf.vehicle
    assert v.is_flying
    # it holds: after 3 more seconds it has not moved on towards the goal
    held = v.position
    for _ in range(150):
        run.step()  # the root restarts the Sequence; TakeOff now fails at once (already flying)
        if m.status.value == "RUNNING":
            break
    assert math.dist(v.position, held) < 0.3
    assert any(
        "time-out after 2 s" in r.get("messages", [""])[0] for r in run.trace if r.get("messages")
    )


def test_halted_goto_holds_position():
    m, run, pf = fly_to_start(
        '<Timeout msec="1500"><GoTo name="go" pose="5;0;1" max_speed="0.5"/></Timeout>'
    )
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "FAILURE" and m.status_of("go") == "IDLE"
    v = pf.vehicle
    x_at_halt = v.position[0]
    for _ in range(100):
        pf.before_tick(m.clock.now() + 0.02)  # keep the simulator running without ticking
        m.clock.advance(0.02)
    assert abs(v.position[0] - x_at_halt) < 0.3
    assert v.is_flying


def test_relative_goto_and_feedback_outputs():
    m, run, pf = fly_to_start(
        '<GoTo name="go" pose="0.5;0;0" relative="true" distance_to_go="{dist}" yaw_error="{yerr}"/>'
    )
    run.step()
    run.step()
    first = m.blackboard["dist"]
    assert 0.3 < first < 0.6
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "SUCCESS"
    assert pf.vehicle.position[0] == pytest.approx(0.5, abs=0.04)
    assert m.blackboard["dist"] < 0.03


def test_conditions_read_the_vehicle():
    m, run, pf = sim_mission(
        wrap(
            "<Sequence>"
            "<Inverter><IsFlying/></Inverter>"
            f"{TAKEOFF}"
            '<IsFlying/><IsAtPosition pose="0;0;1" threshold="0.06"/>'
            '<IsYawWithin angle_deg="0" threshold_deg="15"/>'
            '<BatteryAbove percent="20"/><BatteryAbove volts="3.3"/>'
            "<IsHealthy/>"
            '<Land name="land"/></Sequence>'
        )
    )
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "SUCCESS", m.last_failure
    assert pf.vehicle.is_landed


def test_battery_above_needs_exactly_one_threshold():
    m, run, _ = sim_mission(wrap("<BatteryAbove/>"))
    result = run.run(max_time_s=1)
    assert (
        result.status == "ABORTED" and "give exactly one of 'percent' or 'volts'" in result.reason
    )


def test_leaves_without_a_vehicle_give_a_located_error():
    from helpers import xml_mission

    import nodes  # noqa: F401
    from bt_engine import Runner

    m = xml_mission(wrap('<TakeOff height="1"/>'), path="m.xml")
    result = Runner(m).run(max_time_s=1)
    assert result.status == "ABORTED"
    assert result.reason.startswith("m.xml:3:1: TakeOff 'TakeOff': needs a vehicle")


def test_yaw_mode_names_and_integers_validate():
    from helpers import problems_of_xml

    assert problems_of_xml(wrap('<GoTo pose="1;2;3" yaw_mode="fixed_yaw"/>')) == []
    assert problems_of_xml(wrap('<GoTo pose="1;2;3" yaw_mode="2"/>')) == []
    (p,) = problems_of_xml(wrap('<GoTo pose="1;2;3" yaw_mode="5"/>'))
    assert "expected one of KEEP_YAW (0), PATH_FACING (1), FIXED_YAW (2), got '5'" in p
    (p,) = problems_of_xml(wrap('<GoTo pose="1;2"/>'))
    assert 'expected three numbers "x;y;z", got 2 value(s)' in p


def test_halted_goto_does_not_cancel_the_motion_that_replaced_it():
    """A reactive fallback starts Land, then halts the running GoTo: the drone must land."""
    m, run, pf = fly_to_start(
        "<ReactiveFallback>"
        '<ReactiveSequence><ScriptCondition code="land_now"/><Land name="land"/></ReactiveSequence>'
        '<GoTo name="go" pose="5;0;1" max_speed="0.5"/>'
        "</ReactiveFallback>",
        blackboard={"land_now": False},
    )
    run.run_until(lambda mm: mm.status_of("go") == "RUNNING", 500)
    for _ in range(50):
        run.step()
    m.blackboard["land_now"] = True
    run.run_until(lambda mm: mm.status.value != "RUNNING", 3000)
    assert m.status.value == "SUCCESS"
    assert pf.vehicle.is_landed
