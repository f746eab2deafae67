"""Keeping drones apart: the corridor gate, the separation guard, pausing a motion.

Two simulated drones on one lock-step clock, driven through the Vehicle API as a fleet's
missions would drive them."""

from __future__ import annotations

import math
import os

import pytest
from helpers import REPO

from bt_engine.clock import SimClock
from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from drivers.safety.airspace import Airspace, SeparationGuard, segment_distance

RIG = os.path.join(REPO, "rigs", "aisle.yaml")


def test_segment_distance():
    assert segment_distance((0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)) == pytest.approx(1.0)
    assert segment_distance((0, 0, 0), (2, 0, 0), (1, -1, 0), (1, 1, 0)) == pytest.approx(0.0)
    assert segment_distance((0, 0, 0), (0, 0, 0), (3, 4, 0), (3, 4, 0)) == pytest.approx(5.0)
    assert segment_distance((0, 0, 0), (1, 0, 0), (2, 1, 0), (3, 1, 0)) == pytest.approx(
        math.sqrt(2)
    )


def _drones(starts: dict[str, tuple[float, float]]):
    clock = SimClock()
    platforms = {}
    for i, (name, (x, y)) in enumerate(starts.items()):
        rig = load_rig(RIG, {"sim.start_m": [x, y, 0.0]})
        p = make_platform(rig, clock, seed=i)
        p.vehicle.name = name
        platforms[name] = p
    return clock, platforms


def _step(clock, platforms, hooks, seconds: float, until=None) -> None:
    for _ in range(int(seconds / 0.02)):
        clock.advance(0.02)
        for p in platforms.values():
            p.before_tick(clock.now())
        for h in hooks:
            h.after_step(clock.now())
        if until is not None and until():
            return


def _hovering(starts: dict[str, tuple[float, float]], inside=None, height: float = 1.0):
    """Two drones in one airspace, under one guard, hovering at ``height`` above their
    starts."""
    clock, pf = _drones(starts)
    a, b = pf["a"].vehicle, pf["b"].vehicle
    air = Airspace(0.5)
    air.add(a, inside)
    air.add(b, inside)
    guard = SeparationGuard({"a": a, "b": b}, 0.5, 0.2)
    hooks = [air, guard]
    _step(clock, pf, hooks, 0.1)  # the first telemetry: where each drone stands
    ta, tb = a.takeoff(height, 0.5), b.takeoff(height, 0.5)
    _step(clock, pf, hooks, 8.0, until=lambda: ta.reached and tb.reached)
    assert ta.reached and tb.reached
    return clock, pf, hooks, air, guard


def test_a_motion_through_a_taken_corridor_waits_until_it_is_free():
    clock, pf = _drones({"a": (0.0, -1.5), "b": (1.5, 0.0)})
    a, b = pf["a"].vehicle, pf["b"].vehicle
    air = Airspace(0.5)
    air.add(a)
    air.add(b)
    guard = SeparationGuard({"a": a, "b": b}, 0.5, 0.2)
    hooks = [air, guard]
    _step(clock, pf, hooks, 0.1)  # the first telemetry: where each drone stands
    ta, tb = a.takeoff(1.0, 0.5), b.takeoff(1.0, 0.5)
    _step(clock, pf, hooks, 6.0, until=lambda: ta.reached and tb.reached)
    assert ta.reached and tb.reached
    ga = a.go_to(0.0, 1.5, 1.0, speed_mps=0.5)  # a crosses the origin first ...
    gb = b.go_to(-1.5, 0.0, 1.0, speed_mps=0.5)  # ... b's crossing line must wait
    assert ga.waiting == "" and gb.waiting.startswith("airspace: a's corridor")
    closest, b_waited_while_a_crossed = math.inf, False
    for _ in range(1500):
        _step(clock, pf, hooks, 0.02)
        closest = min(closest, math.dist(a.position, b.position))
        if gb.waiting and abs(a.position[1]) < 0.3:
            b_waited_while_a_crossed = True
        if ga.reached and gb.reached:
            break
    assert ga.reached and gb.reached
    assert b_waited_while_a_crossed
    assert closest >= 0.5 and guard.violations == 0
    assert b.waits == 1 and air.waits >= 1
    assert math.dist(b.position, (-1.5, 0.0, 1.0)) < 0.05


def test_the_guard_pauses_the_drone_closing_in_and_resumes_it():
    clock, pf = _drones({"a": (0.0, 0.0), "b": (2.0, 0.0)})
    a, b = pf["a"].vehicle, pf["b"].vehicle  # no airspace: only the guard keeps them apart
    guard = SeparationGuard({"a": a, "b": b}, 0.5, 0.2)
    _step(clock, pf, [guard], 0.1)
    ta, tb = a.takeoff(1.0, 0.5), b.takeoff(1.0, 0.5)
    _step(clock, pf, [guard], 6.0, until=lambda: ta.reached and tb.reached)
    g = a.go_to(2.0, 0.0, 1.0, speed_mps=0.4)  # straight at b, which hovers there
    _step(clock, pf, [guard], 12.0)
    assert guard.holds == 1 and a.paused and g.active and not g.reached
    assert g.waiting.startswith("paused: b is")
    assert guard.min_distance_m >= 0.5 and guard.violations == 0
    b.go_to(2.0, 3.0, 1.0, speed_mps=0.5)  # b leaves: a is sent on and arrives
    _step(clock, pf, [guard], 20.0, until=lambda: g.reached)
    assert g.reached and not a.paused
    assert math.dist(a.position, (2.0, 0.0, 1.0)) < 0.05
    assert any("resumed" in e for e in guard.events)


def _one_hovering(start: tuple[float, float]):
    """One drone hovering 1 m above ``start``, no airspace."""
    clock, pf = _drones({"a": start})
    a = pf["a"].vehicle
    _step(clock, pf, [], 0.1)
    t = a.takeoff(1.0, 0.5)
    _step(clock, pf, [], 6.0, until=lambda: t.reached)
    assert t.reached
    return clock, pf, a


def test_pause_holds_the_motion_and_resume_finishes_it():
    clock, pf, a = _one_hovering((0.0, 0.0))
    g = a.go_to(0.0, -3.0, 1.0, speed_mps=0.5)  # along the aisle
    _step(clock, pf, [], 2.0)
    assert a.pause("test") and not a.pause("again")
    y_paused = a.position[1]
    _step(clock, pf, [], 4.0)
    assert abs(a.position[1] - y_paused) < 0.25 and not g.reached and g.active
    held = a.position[1]
    _step(clock, pf, [], 2.0)
    assert abs(a.position[1] - held) < 0.03  # holding still
    assert a.resume() and not a.resume()
    _step(clock, pf, [], 15.0, until=lambda: g.reached)
    assert g.reached and g.waiting == ""


def _head_on(inside=None, height=1.0):
    """a and b hover 2 m apart and each is sent to the other's far side: each holds where
    the other must pass (a mutual wait)."""
    clock, pf, hooks, air, guard = _hovering({"a": (-1.0, 0.0), "b": (1.0, 0.0)}, inside, height)
    a, b = pf["a"].vehicle, pf["b"].vehicle
    ga = a.go_to(1.5, 0.0, height, speed_mps=0.5)
    gb = b.go_to(-1.5, 0.0, height, speed_mps=0.5)
    assert ga.waiting.startswith("airspace: b's") and gb.waiting.startswith("airspace: a's")
    return clock, pf, hooks, air, guard, ga, gb


def _fly_until_both_reach(clock, pf, hooks, ga, gb, seconds=40.0):
    a, b = pf["a"].vehicle, pf["b"].vehicle
    closest, z_range = math.inf, {"a": [9.0, 0.0], "b": [9.0, 0.0]}
    for _ in range(int(seconds / 0.02)):
        _step(clock, pf, hooks, 0.02)
        closest = min(closest, math.dist(a.position, b.position))
        for name, v in (("a", a), ("b", b)):
            z_range[name] = [
                min(z_range[name][0], v.position[2]),
                max(z_range[name][1], v.position[2]),
            ]
        if ga.reached and gb.reached:
            break
    return closest, z_range


def test_two_drones_waiting_for_each_other_one_steps_aside_and_both_arrive():
    clock, pf, hooks, air, guard, ga, gb = _head_on()
    assert air.wait_cycle("a") == ["a", "b"]
    closest, z = _fly_until_both_reach(clock, pf, hooks, ga, gb)
    assert ga.reached and gb.reached and not ga.failed and not gb.failed
    assert air.asides == 1 and pf["a"].vehicle.asides == 1 and pf["b"].vehicle.asides == 0
    assert air.events[0]["aside"] == "a" and air.events[0]["ring"] == ["a", "b"]
    assert z["a"][1] > 1.7 and z["b"][1] < 1.1  # a went up out of b's way; b flew level
    assert closest >= 0.5 and guard.violations == 0
    assert math.dist(pf["a"].vehicle.position, (1.5, 0.0, 1.0)) < 0.05
    assert math.dist(pf["b"].vehicle.position, (-1.5, 0.0, 1.0)) < 0.05


def test_a_drone_with_no_room_above_steps_down():
    clock, pf, hooks, air, guard, ga, gb = _head_on(inside=lambda p: p[2] <= 1.5, height=1.2)
    closest, z = _fly_until_both_reach(clock, pf, hooks, ga, gb)
    assert ga.reached and gb.reached and air.asides == 1
    assert z["a"][0] < 0.5 and z["a"][1] < 1.3  # down to 1.2 - 0.75 m, never up
    assert closest >= 0.5 and guard.violations == 0


def test_no_room_to_step_aside_leaves_the_mutual_wait_to_the_time_outs():
    level = lambda p: abs(p[2] - 1.0) < 0.3  # noqa: E731 (a geofence one level high)
    clock, pf, hooks, air, guard, ga, gb = _head_on(inside=level)
    _step(clock, pf, hooks, 10.0)
    assert ga.waiting and gb.waiting and not ga.reached and not gb.reached
    assert air.asides == 0 and air.wait_cycle("b") == ["b", "a"]
    assert abs(pf["a"].vehicle.position[2] - 1.0) < 0.05  # held where it was


def test_step_aside_only_for_a_motion_waiting_at_the_gate():
    clock, pf, a = _one_hovering((0.0, 0.0))
    assert a.step_aside((0.0, 0.0, 1.75)) == "no motion waiting at the gate"
    a.motion_gate = lambda *args: "test: wait"
    g = a.go_to(0.0, -1.0, 1.0, speed_mps=0.5)
    assert g.waiting == "test: wait" and a.waiting_at_gate
    assert "above control.max_altitude_m" in a.step_aside((0.0, 0.0, 50.0))
    assert "above the ground" in a.step_aside((0.0, 0.0, 0.1))
    assert a.step_aside((0.0, 0.0, 1.6)) == "" and a.aside_goal == (0.0, 0.0, 1.6)
    _step(clock, pf, [], 5.0)
    assert abs(a.position[2] - 1.6) < 0.05 and g.waiting == "test: wait"  # there, waiting
    a.motion_gate = None
    _step(clock, pf, [], 10.0, until=lambda: g.reached)
    assert g.reached and a.aside_goal is None
    assert math.dist(a.position, (0.0, -1.0, 1.0)) < 0.05


def test_a_path_reserves_its_waypoints_not_the_straight_line_to_its_goal():
    clock, pf, hooks, air, guard = _hovering({"a": (0.0, -1.5), "b": (1.5, 0.0)})
    a, b = pf["a"].vehicle, pf["b"].vehicle
    # an L round b: the straight line to the goal passes 0.67 m from b, the path through it
    g = a.follow_path([(1.5, -1.5, 1.0), (1.5, 1.5, 1.0)], speed_mps=0.5)
    assert g.waiting.startswith("airspace: b's corridor passes 0.00 m")
    gb = b.go_to(-1.0, 0.0, 1.0, speed_mps=0.5)  # b leaves; a may go once b is clear
    assert gb.waiting == ""
    assert len(air.corridors["b"]) == 2 and air.corridors["b"][-1] == (-1.0, 0.0, 1.0)
    _step(clock, pf, hooks, 30.0, until=lambda: not g.waiting and a.position[0] > 0.3)
    # flying, a's reservation is the rest of its path: where it is, its corner, its goal
    assert air.corridors["a"][1:] == ((1.5, -1.5, 1.0), (1.5, 1.5, 1.0))
    _step(clock, pf, hooks, 30.0, until=lambda: g.reached and gb.reached)
    assert g.reached and gb.reached and guard.violations == 0
    assert air.corridors["a"] == (tuple(a.position),)  # arrived: its position alone


def test_the_guard_stops_a_fast_drone_in_time():
    clock, pf = _drones({"a": (0.0, -4.0), "b": (0.0, 1.0)})
    a, b = pf["a"].vehicle, pf["b"].vehicle  # no airspace: only the guard keeps them apart
    guard = SeparationGuard({"a": a, "b": b}, 0.5, 0.2)
    _step(clock, pf, [guard], 0.1)
    ta, tb = a.takeoff(1.0, 0.5), b.takeoff(1.0, 0.5)
    _step(clock, pf, [guard], 6.0, until=lambda: ta.reached and tb.reached)
    g = a.go_to(0.0, 1.0, 1.0, speed_mps=1.0)  # at 1 m/s straight at b: 0.5 m to stop
    _step(clock, pf, [guard], 12.0)
    assert guard.holds == 1 and a.paused and not g.reached
    assert guard.min_distance_m >= 0.5 and guard.violations == 0


def test_a_path_paused_twice_goes_on_through_the_waypoints_it_has_not_reached():
    clock, pf, a = _one_hovering((0.0, -1.5))
    g = a.follow_path([(1.5, -1.5, 1.0), (1.5, 0.0, 1.0), (0.0, 0.0, 1.0)], speed_mps=0.5)
    _step(clock, pf, [], 20.0, until=lambda: a.position[1] > -1.0)  # on the second leg
    assert a.pause("one") and a.resume()
    _step(clock, pf, [], 20.0, until=lambda: a.position[0] < 1.0)  # on the third leg
    assert a.pause("two") and a.resume()
    track = []
    _step(clock, pf, [], 20.0, until=lambda: track.append(a.position) or g.reached)
    assert g.reached and math.dist(a.position, (0.0, 0.0, 1.0)) < 0.05
    assert max(p[0] for p in track) < 1.1  # never back to a corner it had passed
