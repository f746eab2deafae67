"""Where the sweep changes its battery (nodes.sweep_energy.change_plan): between passes, at
the boundary that leaves the least time to the changes still to come, never with a charge
that still covers the rest, never later than the charge reaches."""

from __future__ import annotations

import pytest

from nodes.sweep_energy import change_plan, close_pass_timing, pass_overhead, pass_step

RATE = 100.0 / 300.0  # a full battery lasts 300 s
RESERVE = 15.0


def _passes(n, length_s=50.0, near_s=2.0, far_s=20.0, swap_s=60.0):
    """n passes of ``length_s`` each, ending alternately far from the pad and near it (a
    serpentine over an aisle whose pad is at its near end), as change_plan takes them from
    a drone at the start of the first (near the pad)."""
    steps, change = [], [swap_s + 2 * near_s]
    for k in range(n):
        home = far_s if k % 2 == 0 else near_s
        steps.append(((k + 1) * length_s, home))
        change.append(swap_s + 2 * home)
    return steps, change


def test_a_charge_that_covers_every_pass_goes_on_without_a_change():
    steps, change = _passes(4)  # 200 s + 2 s home: inside 255 s of a full battery
    assert change_plan(100.0, steps, change, RATE, RESERVE) == (False, 0.0)


def test_a_full_battery_at_the_start_is_never_changed():
    steps, change = _passes(6)  # 300 s: one change somewhere
    now, cost = change_plan(100.0, steps, change, RATE, RESERVE)
    assert not now
    assert cost == pytest.approx(60.0 + 2 * 2.0)  # the change will be at a near end


def test_the_change_is_made_at_the_near_end_when_the_far_end_is_the_last_reachable():
    # 3 passes to fly; the charge reaches the end of the first (far from the pad) but not
    # of the second: change here, near the pad, rather than at the far end
    steps, change = _passes(3)
    pct = RESERVE + RATE * (50.0 + 20.0) + 1.0
    now, cost = change_plan(pct, steps, change, RATE, RESERVE)
    assert now
    assert cost == pytest.approx(change[0])


def test_going_on_to_a_cheaper_boundary_the_charge_reaches():
    steps, change = _passes(3)
    pct = RESERVE + RATE * (100.0 + 2.0) + 1.0  # reaches the second pass's near end
    assert change_plan(pct, steps, change, RATE, RESERVE) == (False, pytest.approx(change[2]))


def test_a_charge_too_low_for_the_next_pass_changes_now_wherever_the_drone_is():
    steps, change = _passes(3)
    change[0] = 60.0 + 2 * 20.0  # far from the pad
    now, _ = change_plan(RESERVE + 1.0, steps, change, RATE, RESERVE)
    assert now


def test_fewer_changes_win_over_cheaper_ones():
    # 12 passes (600 s) need two changes at least; each change's flight is cheap next to
    # the swap, so the plan takes two, not three
    steps, change = _passes(12)
    now, cost = change_plan(100.0, steps, change, RATE, RESERVE)
    assert not now
    assert cost == pytest.approx(2 * (60.0 + 2 * 2.0))


def test_the_look_ahead_times_passes_on_this_flight_and_skips_a_battery_change():
    timing = {"last": None, "samples": []}
    # two passes timed: their line and transit took 20 s and 22 s, they took 22.5 and 25
    for start, core, end in ((10.0, 20.0, 32.5), (32.5, 22.0, 57.5)):
        timing["last"] = (start, core)
        close_pass_timing(timing, end, change_s=60.0)
    assert timing["samples"] == [2.5, 3.0] and timing["last"] is None
    assert pass_overhead(timing, 9.0) == (2.75, 2)
    # a pass with a battery change in it (90 s beyond its line) is not a sample
    timing["last"] = (57.5, 20.0)
    close_pass_timing(timing, 167.5, change_s=60.0)
    assert timing["samples"] == [2.5, 3.0]
    # nothing timed yet: the default
    assert pass_overhead({"last": None, "samples": [4.0]}, 3.0) == (3.0, 0)


def test_a_pass_towards_the_pad_needs_the_charge_to_get_home_from_its_start():
    # a 22 s pass from an aisle's far end (26 s from the pad) to its near end (4 s)
    t_end, home = pass_step(2.0, 24.0, 26.0, 4.0)
    assert (t_end, home) == (24.0, 4.0)  # from the end: 28 s in all, as from the start
    t_end, home = pass_step(2.0, 24.0, 40.0, 4.0)
    assert (t_end, home) == (24.0, 18.0)  # the start binds: 2 + 40 = 24 + 18
    # 30 % left at 0.5 %/s, 15 % reserve: 30 s of flight. From the end (24 + 4 s) the
    # pass fits; from its start (2 + 40 s) it does not: change before it
    steps = [pass_step(2.0, 24.0, 40.0, 4.0)]
    assert change_plan(30.0, steps, [64.0, 68.0], 0.5, 15.0)[0] is True
    assert change_plan(30.0, [(24.0, 4.0)], [64.0, 68.0], 0.5, 15.0)[0] is False
