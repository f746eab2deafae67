"""Safety supervisor: pure fault logic on a fake clock, then each policy tick by tick on the
simulator (lock-step, no sleeping)."""

from __future__ import annotations

import math

import pytest
from helpers import sim_mission, wrap

from bt_engine.node import StatefulActionNode
from bt_engine.registry import REGISTRY
from bt_engine.runner import Abort
from drivers.safety.monitor import FaultMonitor, Observation
from drivers.safety.policies import FAULTS, Policy, SafetyConfig
from drivers.safety.supervisor import SafetySupervisor
from nodes.safety_hook import SafetyHook

# ---------------------------------------------------------------------- pure logic


def obs(t: float, **kw) -> Observation:
    kw.setdefault("airborne", True)
    return Observation(t_s=t, **kw)


def test_monitor_grace_then_act() -> None:
    m = FaultMonitor(SafetyConfig())
    assert m.update(obs(0.0, mocap_ok=True)) is None
    assert m.update(obs(1.0, mocap_ok=False)) is None  # grace 1.0 s starts
    assert m.active() == ["mocap_lost"] and m.is_active("any")
    assert m.update(obs(1.5, mocap_ok=False)) is None
    assert m.update(obs(2.0, mocap_ok=False)) == "mocap_lost"


def test_monitor_transient_fault_clears_and_is_recorded() -> None:
    m = FaultMonitor(SafetyConfig())
    m.update(obs(1.0, mocap_ok=False))
    assert m.update(obs(1.4, mocap_ok=True)) is None
    assert m.active() == []
    assert [r.as_dict() for r in m.history] == [
        {"fault": "mocap_lost", "t_s": 1.0, "cleared_s": 1.4}
    ]
    assert m.update(obs(3.0, mocap_ok=True)) is None


def test_monitor_tree_stopped_means_act_now() -> None:
    m = FaultMonitor(SafetyConfig())
    assert m.update(obs(1.0, battery_v=3.25)) is None  # battery_low: grace 2 s
    assert m.update(obs(1.02, battery_v=3.25, tree_running=False)) == "battery_low"


def test_monitor_waits_while_the_tree_lands_and_latches_battery() -> None:
    m = FaultMonitor(SafetyConfig())
    m.update(obs(0.0, battery_v=3.25))
    assert m.update(obs(5.0, battery_v=3.25, landing=True)) is None
    assert m.update(obs(6.0, battery_v=3.6)) == "battery_low"  # latched: load dropped, still low


def test_monitor_severity_and_motors_off() -> None:
    m = FaultMonitor(SafetyConfig())
    assert m.update(obs(0.0, link_ok=False, battery_v=3.0)) == "battery_critical"
    assert m.active()[:2] == ["battery_critical", "link_lost"]
    m2 = FaultMonitor(SafetyConfig())
    assert m2.update(obs(0.0, airborne=False, crashed=True)) == "crash"


def test_monitor_report_only_and_ground() -> None:
    m = FaultMonitor(SafetyConfig())
    assert m.update(obs(0.0, camera_ok=False)) is None
    assert m.update(obs(9.0, camera_ok=False, tree_running=False)) is None
    assert m.active() == ["camera_stalled"] and m.actionable() == []
    g = FaultMonitor(SafetyConfig())
    assert g.update(obs(0.0, airborne=False, link_ok=False, position=(99, 0, 0))) is None


def test_geofence_box_and_nearest_inside() -> None:
    c = SafetyConfig(geofence_min_m=(0, 0, 0), geofence_max_m=(4, 2, 2), geofence_margin_m=0.5)
    assert c.inside((1, 1, 1)) and not c.inside((4.1, 1, 1))
    assert c.nearest_inside((5, 1, 3)) == (3.5, 1, 1.5)
    m = FaultMonitor(c)
    assert m.update(obs(0.0, position=(4.2, 1, 1))) == "geofence"


def test_config_from_rig_data() -> None:
    from drivers.rig.loader import load_rig

    rig = load_rig(None, {"safety.policies.link_lost.hold_s": "0.4", "safety.battery_low_v": "3.5"})
    c = SafetyConfig.from_dict(rig.data["safety"])
    assert c.policies["link_lost"] == Policy("hold_then_land", 0.0, 0.4)
    assert c.battery_low_v == 3.5 and c.geofence_max_m[0] == pytest.approx(9.2)
    assert set(c.policies) == set(FAULTS)


# ---------------------------------------------------------------------- on the simulator

HOP = wrap(
    """    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <GoTo pose="3;0;1" max_speed="0.3"/>
      <Land speed="0.3"/>
    </Sequence>"""
)


def flown(xml: str = HOP, overrides: dict | None = None, **kw):
    mission, runner, platform = sim_mission(xml, overrides=overrides, **kw)
    rig_overrides = dict(overrides or {})
    from drivers.rig.loader import load_rig

    config = SafetyConfig.from_dict(load_rig(None, rig_overrides).data["safety"])
    hook = SafetyHook(
        lambda **kw: SafetySupervisor(config, platform.vehicle, platform, **kw), mission
    )
    runner.hooks.insert(0, hook)
    return mission, runner, platform, hook.supervisor


def assert_down(sup: SafetySupervisor, fault: str | None) -> dict:
    s = sup.summary()
    assert s["fault"] == fault, s
    assert s["final_state"] == "landed" and s["disarmed"], s
    return s


def test_blackboard_state_every_tick_then_takeover() -> None:
    m, runner, platform, sup = flown(overrides={"faults.mocap_drop.at_s": "4.0"})
    assert m.blackboard["safety_state"] == "ok" and m.blackboard["safety_fault"] == ""
    runner.run_until(lambda mm: mm.blackboard["safety_fault"] == "mocap_lost", 400)
    t_detect = m.clock.now()
    assert 4.0 < t_detect < 4.3
    assert m.blackboard["safety_state"] == "fault"
    assert m.blackboard["safety_faults"] == ["mocap_lost"]
    assert m.status_of("GoTo") == "RUNNING"  # grace: the tree keeps flying on the onboard pose
    with pytest.raises(Abort, match="mocap_lost"):
        for _ in range(100):
            runner.step()
    assert m.clock.now() == pytest.approx(t_detect + 1.0, abs=0.03)
    assert m.blackboard["safety_state"] == "recovering"
    assert runner.last_record["bb"]["safety_state"] == "recovering"  # the last tick is logged


def test_link_loss_holds_then_lands() -> None:
    m, runner, platform, sup = flown(
        overrides={"faults.link_drop.at_s": "5.0", "faults.link_drop.duration_s": "0.6"}
    )
    res = runner.run(60)
    assert res.status == "ABORTED" and "link_lost" in res.reason
    s = assert_down(sup, "link_lost")
    assert s["actions"][0]["action"].startswith("hold")
    assert s["actions"][1]["action"] == "land"
    assert s["actions"][1]["t_s"] < 5.0 + 1.0 + 0.05  # link back after 0.6 s: land at once
    assert m.statuses()["Main/Sequence/GoTo"] == "IDLE"  # the tree was halted


def test_battery_low_returns_home_and_lands() -> None:
    m, runner, platform, sup = flown(
        overrides={"faults.battery_sag.at_s": "6.0", "faults.battery_sag.drop_v": "0.65"}
    )
    res = runner.run(80)
    assert "battery_low" in res.reason
    s = assert_down(sup, "battery_low")
    assert s["acted_s"] == pytest.approx(s["t_s"] + 2.0, abs=0.03)  # grace 2 s
    assert s["actions"][0]["action"].startswith("return to")
    b = platform.drone.body
    assert math.hypot(b.x, b.y) < 0.1


def test_battery_critical_lands_where_it_is() -> None:
    m, runner, platform, sup = flown(
        overrides={"faults.battery_sag.at_s": "6.0", "faults.battery_sag.drop_v": "1.0"}
    )
    res = runner.run(80)
    assert "battery_critical" in res.reason
    assert_down(sup, "battery_critical")
    assert platform.drone.body.x > 0.5  # not flown home


def test_geofence_breach_lands_inside() -> None:
    over = {"safety.geofence.max_m": "[2.0, 3, 2.5]"}
    m, runner, platform, sup = flown(overrides=over)
    res = runner.run(60)
    assert "geofence" in res.reason
    assert_down(sup, "geofence")
    assert platform.drone.body.x <= 2.0 - 0.2


def test_crash_cuts_motors() -> None:
    xml = wrap(
        """    <Sequence>
      <TakeOff height="0.25" speed="0.5"/>
      <GoTo pose="10;-0.05;0.25" max_speed="0.5"/>
    </Sequence>"""
    )
    m, runner, platform, sup = flown(xml, overrides={"safety.geofence.enabled": "false"})
    res = runner.run(60)
    assert "crash" in res.reason
    s = sup.summary()
    assert s["fault"] == "crash" and s["final_state"] == "crashed"
    assert s["actions"][0]["action"] == "motors off"


def test_camera_stall_is_reported_only() -> None:
    m, runner, platform, sup = flown(overrides={"faults.camera_stall.at_s": "3.0"})
    platform.camera.set_renderer(lambda pose, t_s, previous=None: b"frame")
    runner.run_until(lambda mm: mm.blackboard["safety_fault"] == "camera_stalled", 300)
    assert m.blackboard["safety_state"] == "fault"
    res = runner.run(60)
    assert res.status == "SUCCESS"
    s = assert_down(sup, None)
    assert s["faults_seen"][0]["fault"] == "camera_stalled"


def test_operator_interrupt_lands() -> None:
    m, runner, platform, sup = flown()
    runner.run_until(lambda mm: mm.clock.now() >= 5.0, 1000)
    runner.interrupt()
    res = runner.run(60)
    assert res.reason == "operator interrupt (Ctrl-C)"
    assert_down(sup, "operator_interrupt")


def test_second_interrupt_cuts_motors() -> None:
    m, runner, platform, sup = flown()
    runner.run_until(lambda mm: mm.clock.now() >= 5.0, 1000)
    calls = {"n": 0}
    real = platform.before_tick

    def step(t: float) -> None:  # the second Ctrl-C arrives while the supervisor lands
        calls["n"] += 1
        if calls["n"] == 10:
            raise KeyboardInterrupt
        real(t)

    platform.before_tick = step
    sup.shutdown("operator interrupt (Ctrl-C)")
    s = sup.summary()
    assert [a["action"] for a in s["actions"]][-2:] == [
        "emergency stop (second interrupt)",
        "disarm",
    ]
    assert platform.vehicle.flight_state.value in ("emergency", "crashed")


class _Boom(StatefulActionNode):
    """Test-only: raises after ``2 s`` of running."""

    bt_id = "SafetyTestBoom"

    def on_start(self):
        self.t0 = self.now()
        from bt_engine.node import RUNNING

        return RUNNING

    def on_running(self):
        if self.now() - self.t0 > 2.0:
            raise ValueError("test bug")
        from bt_engine.node import RUNNING

        return RUNNING


def test_leaf_exception_lands_and_keeps_the_traceback() -> None:
    reg = REGISTRY.copy()
    reg.register(_Boom)
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <SafetyTestBoom/>
    </Sequence>"""
    )
    m, runner, platform, sup = flown(xml, registry=reg)
    res = runner.run(60)
    assert res.status == "ABORTED" and res.reason.startswith("internal error")
    assert "ValueError: test bug" in runner.error_traceback
    assert_down(sup, "leaf_exception")


def test_tree_reacts_first_within_grace() -> None:
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <Fallback>
        <ReactiveSequence>
          <NoFault fault="battery_low"/>
          <GoTo pose="3;0;1" max_speed="0.2"/>
        </ReactiveSequence>
        <Sequence>
          <FaultActive fault="battery_low"/>
          <Land name="own_landing" speed="0.5"/>
        </Sequence>
      </Fallback>
    </Sequence>"""
    )
    m, runner, platform, sup = flown(
        xml, overrides={"faults.battery_sag.at_s": "5.0", "faults.battery_sag.drop_v": "0.65"}
    )
    res = runner.run(60)
    assert res.status == "SUCCESS"  # the tree handled it: the supervisor never took over
    s = sup.summary()
    assert s["fault"] is None and s["final_state"] == "landed" and s["disarmed"]
    assert s["faults_seen"][0]["fault"] == "battery_low"
    assert m.status_of("own_landing") in ("SUCCESS", "IDLE")


def test_fault_names_are_checked_when_loading() -> None:
    from helpers import problems_of_xml

    probs = problems_of_xml(wrap('    <FaultActive fault="battery_lo"/>'))
    assert len(probs) == 1 and "battery_lo" in probs[0] and "inline" not in probs[0]
    assert problems_of_xml(wrap('    <NoFault fault="any"/>')) == []


def test_a_final_state_the_drone_did_not_report_is_not_claimed_as_confirmed() -> None:
    """A real drone whose link (or the guard holding it) died: the record said
    disarmed: true, what btrun last commanded; the drone stayed armed. Said unconfirmed
    when the link was down at the last look and no ground truth is known."""
    mission, runner, platform, sup = flown()
    runner.run(max_time_s=200)
    assert "confirmed" not in sup.summary()  # the link up at the end
    sup.last_link_ok = False
    assert "confirmed" not in sup.summary()  # down, but the simulator knows the truth
    truth = platform.summary
    platform.summary = lambda: {k: v for k, v in truth().items() if k != "collisions"}
    s = sup.summary()  # as a real drone's platform: no ground truth
    assert (
        s["confirmed"] is False
        and "not confirmed by the drone, which may still be armed" in s["note"]
    )


def test_a_second_interrupt_during_the_landing_is_in_the_reason() -> None:
    """The run's reason says the emergency stop (it was only in the supervisor's actions:
    the console line read as if the drone had landed)."""
    m, runner, platform, sup = flown()
    runner.run_until(lambda mm: mm.clock.now() >= 5.0, 1000)
    runner.interrupt()
    calls = {"n": 0}
    real = platform.before_tick

    def step(t: float) -> None:  # the second Ctrl-C, as the signal handler gives it
        calls["n"] += 1
        if calls["n"] == 10:
            runner.interrupt()
            raise KeyboardInterrupt
        real(t)

    platform.before_tick = step
    res = runner.run(60)
    assert res.reason == "operator interrupt (Ctrl-C); Ctrl-C again: emergency stop"
    assert sup.summary()["motors_cut"]
