"""EnoughEnergyForPass: change the battery between two passes, where it costs least.

A battery does not cover a whole site: the sweep changes it once or more. ``EnoughEnergy``
beside a pass stops the pass wherever the charge runs short, which may be at the far end of
an aisle: the drone then flies the aisle's length home and back again. Before each pass,
``EnoughEnergyForPass`` looks ahead over the passes still to fly (their lines, the routes
between them and home, the consumption measured on this battery) and chooses where to
change: now, or at the end of a later pass the charge still reaches, whichever leaves the
least time to the changes still to come (each change costs the flight home and back, the
landing and the swap). So a change happens at an aisle end near the pad rather than in the
middle of the racks, and before a pass rather than during it. The ``EnoughEnergy`` beside
the pass stays the safety net.
"""

from __future__ import annotations

import functools
import math

from bt_engine.node import ConditionNode
from bt_engine.ports import ANY, BOOL, DURATION, FLOAT, STRING, VEC3, input_port, output_port
from bt_engine.registry import register
from nodes.common import vehicle_of
from nodes.energy import (
    CATEGORY_ENERGY,
    ENDURANCE_PORT,
    RESERVE_PORT,
    count_energy_check,
    measured_rate,
    steady_percent,
    travel_m,
)
from nodes.inventory_log import InventoryLog
from nodes.sweep_plan import pass_line, sweep_plan_of

#: charge of a fresh battery, %
FULL_PERCENT = 100.0
#: ``ctx.resources`` key of the passes' measured overheads: {"last": (mission time at the
#: check, the pass's line and transit time) or None, "samples": [s, ...]}
OVERHEAD_KEY = "sweep_pass_overhead"
#: passes timed on this flight before their measured overhead replaces ``turn_time``
MIN_TIMED_PASSES = 2


def change_plan(
    percent: float,
    steps: list[tuple[float, float]],
    change_s: list[float],
    rate: float,
    reserve: float,
) -> tuple[bool, float]:
    """Change now or go on? ``steps[k]`` is (seconds of flight to the end of the k-th pass
    still to fly, from where the drone is; seconds from that end home and landed);
    ``change_s[k]`` is what a change costs there (``change_s[0]``: now, then after each
    pass). The charge lasts while ``percent - rate * seconds`` stays at or above ``reserve``
    at touchdown. Returns (change now, the least time the changes still cost). Ties go on.
    """
    n = len(steps)
    ends = [0.0] + [s for s, _ in steps]  # flight time to boundary b (0: now)
    home = [None] + [h for _, h in steps]

    def reach(start: int, pct: float) -> int:
        """The last boundary the charge reaches from ``start`` and still gets home from."""
        last = start
        for b in range(start + 1, n + 1):
            if pct - rate * (ends[b] - ends[start] + home[b]) >= reserve:  # type: ignore[operator]
                last = b
            else:
                break
        return last

    @functools.cache
    def cost_full(start: int) -> float:
        """The least change time to finish from boundary ``start`` on a fresh battery."""
        last = reach(start, FULL_PERCENT)
        if last == n:
            return 0.0
        if last == start:
            return math.inf  # not even one pass on a fresh battery
        return min(change_s[b] + cost_full(b) for b in range(start + 1, last + 1))

    last = reach(0, percent)
    go_on = (
        0.0
        if last == n
        else min((change_s[b] + cost_full(b) for b in range(1, last + 1)), default=math.inf)
    )
    now = change_s[0] + cost_full(0)
    if go_on <= now:
        return False, go_on
    return True, now


def pass_step(
    t_start: float, t_end: float, home_from_start: float, home_from_end: float
) -> tuple[float, float]:
    """One pass as :func:`change_plan` takes it: (seconds to its end, seconds home).

    The charge must get the drone home from anywhere along the pass (``EnoughEnergy``
    beside it checks the next place and the way home from there), not only from its end:
    a pass that starts at an aisle's far end and flies towards the pad needs the most
    charge at its start. The seconds home are raised so that the check at the end also
    holds at the start: ``max(home_from_end, home_from_start - (t_end - t_start))``."""
    return t_end, max(home_from_end, home_from_start - (t_end - t_start))


def close_pass_timing(timing: dict, now: float, change_s: float) -> None:
    """End the timing of the pass started at ``timing["last"]`` (mission time at its check,
    seconds of its line and transit): what it took beyond them is a sample, unless it was
    ``change_s`` or more (a battery change came in between)."""
    last, timing["last"] = timing["last"], None
    if last is not None:
        extra = now - last[0] - last[1]
        if 0.0 <= extra < change_s:
            timing["samples"].append(extra)


def pass_overhead(timing: dict, default: float) -> tuple[float, int]:
    """(seconds a pass takes beyond its line and transit: turning, speeding up, second
    looks, the mean over the passes timed on this flight, else ``default``; passes timed)."""
    samples = timing["samples"]
    if len(samples) < MIN_TIMED_PASSES:
        return default, 0
    return sum(samples) / len(samples), len(samples)


@register
class EnoughEnergyForPass(ConditionNode):
    """SUCCESS to fly the pass ``pass`` on this battery; FAILURE to change the battery
    first (the Fallback's other child): when the charge does not cover the pass and the
    way home from its end, or when changing here, before the pass, costs less than any
    later place the charge reaches (see the module doc). The pass times come from its line
    at ``speed``, ``turn_time`` per pass and the routes between passes at
    ``transit_speed``; the consumption is ``EnoughEnergy``'s measurement on this battery
    (before any: a full battery lasts ``endurance``)."""

    bt_id = "EnoughEnergyForPass"
    category = CATEGORY_ENERGY
    ports = (
        input_port("pass", STRING, description="the next pass (PlanSweep's passes, e.g. A/2)"),
        input_port("home", VEC3, description="where a battery is changed (the pad), x;y;z"),
        input_port("speed", FLOAT, 0.8, "speed along a pass, m/s", low=0.02, high=2.0),
        input_port(
            "transit_speed", FLOAT, 1.0, "speed between passes and home, m/s", low=0.05, high=3.0
        ),
        input_port("standoff", FLOAT, 0.45, "the passes' distance from the faces, m"),
        input_port("lead", FLOAT, 0.5, "the passes' run-up, m"),
        input_port(
            "turn_time",
            DURATION,
            3.0,
            "time lost per pass to speeding up, turning and second looks, until two passes "
            "were timed on this flight (then their mean), s",
        ),
        input_port("landing_time", DURATION, 4.0, "time to land, s"),
        input_port("swap_time", DURATION, 60.0, "handling time of a change, s"),
        RESERVE_PORT,
        input_port(
            "margin",
            FLOAT,
            3.0,
            "charge the look-ahead keeps beyond the reserve (about one unplanned second look "
            "and the consumption's noise), so the EnoughEnergy beside a pass does not stop "
            "it where the plan said it fits, %",
            low=0.0,
            high=50.0,
        ),
        ENDURANCE_PORT,
        input_port(
            "enabled",
            BOOL,
            True,
            "false: never change between passes (the EnoughEnergy beside a pass stops it "
            "when the charge runs short)",
        ),
        output_port("start_point", ANY, "where the pass starts, x;y;z"),
    )

    def check(self) -> bool:
        v = vehicle_of(self)
        plan = sweep_plan_of(self.ctx)
        name = self.get_input("pass")
        count_energy_check(self.ctx)  # the rescans' EnoughEnergy: a pass came between
        if plan is None or name not in plan.passes or not v.is_flying:
            return True  # SweepPass says what is wrong with the pass
        if not self.get_input("enabled"):
            return True
        done = InventoryLog.of(self.ctx).finished() | plan.left_for_rescan()
        standoff, lead = self.get_input("standoff"), self.get_input("lead")
        speed = max(self.get_input("speed"), 1e-3)
        transit = max(self.get_input("transit_speed"), 1e-3)
        home = tuple(self.get_input("home"))
        landing = self.get_input("landing_time")
        timing = self.ctx.resources.setdefault(OVERHEAD_KEY, {"last": None, "samples": []})
        close_pass_timing(timing, self.now(), self.get_input("swap_time"))
        turn, timed = pass_overhead(timing, self.get_input("turn_time"))
        here = tuple(v.position)
        change_s = [
            self.get_input("swap_time") + landing + 2 * travel_m(self.ctx, here, home) / transit
        ]
        steps: list[tuple[float, float]] = []
        t = core = 0.0
        for p in plan.order[plan.order.index(name) :]:
            todo = [x for x in plan.passes[p].places if x not in done]
            if not todo:
                continue
            start, end = pass_line(plan.passes[p], standoff, lead, todo)
            to_start = travel_m(self.ctx, here, start) / transit
            flown = to_start + math.dist(start, end) / speed
            if not steps:
                self.set_output("start_point", start)
                core = flown
            t_start, t = t + to_start, t + flown + turn
            back = travel_m(self.ctx, end, home) / transit
            from_start = travel_m(self.ctx, start, home) / transit
            steps.append(pass_step(t_start, t, from_start + landing, back + landing))
            change_s.append(self.get_input("swap_time") + landing + 2 * back)
            here = end
        if not steps:
            return True
        # measured on this battery, however long ago (ChangeBattery forgets it): after a
        # few per-place rescans the last measurement is minutes old, and still far nearer
        # the drone's consumption than the assumed endurance
        rate = measured_rate(self.ctx, self.now(), max_age_s=math.inf)
        how = "measured"
        if rate is None:
            rate, how = 100.0 / max(self.get_input("endurance"), 1.0), "assumed"
        pct = steady_percent(self.ctx, self.now(), v.battery.percent)
        keep = self.get_input("reserve") + max(self.get_input("margin"), 0.0)
        change, cost = change_plan(pct, steps, change_s, rate, keep)
        # this pass is timed from here to the next check, unless a change comes first
        timing["last"] = None if change else (self.now(), core)
        if change:
            self.failure_reason = (
                f"change the battery before pass {name}: {pct:.1f} % left at "
                f"{rate * 60:.2f} %/min ({how}), {turn:.1f} s per pass beyond its line "
                f"({f'measured on {timed} passes' if timed else 'assumed'}); changing here costs least "
                f"({cost:.0f} s of changes to the end of the sweep)"
            )
            self.ctx.log(f"{self.describe()}: {self.failure_reason}")
        return not change
