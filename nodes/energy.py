"""Energy leaves for long missions: EnoughEnergy (go on or go home?) and ChangeBattery.

A Crazyflie flies about seven minutes on a battery; an inventory of a whole aisle takes
longer. Before each place the inventory asks ``EnoughEnergy``: will the charge left cover
flying to the place, the work there and the way back to the pad, with a reserve? The
consumption is measured on this battery in flight (charge per second, from the Vehicle's
sag-corrected state of charge), not assumed, and the time a place takes is measured from the
places done so far. If not, the drone flies home, lands, and ``ChangeBattery`` swaps the
battery (simulation; on a real drone the run stops and is resumed after a swap by hand) or
charges it on the pad; then the inventory resumes at the first place not answered.
"""

from __future__ import annotations

import statistics
from typing import Any

from bt_engine.node import FAILURE, RUNNING, SUCCESS, ConditionNode, NodeStatus, StatefulActionNode
from bt_engine.ports import DURATION, FLOAT, STRING, VEC3, input_port
from bt_engine.registry import register
from nodes.common import vehicle_of

CATEGORY_ENERGY = "energy"
#: charge (percent points) a reading must rise by to count as a new battery
NEW_BATTERY_JUMP = 20.0
#: airborne seconds on one battery before its measured consumption is trusted
MEASURE_AFTER_S = 20.0
#: ``ctx.resources`` key of the last measured consumption: (mission time, %/s)
RATE_KEY = "energy_rate"
#: ``ctx.resources`` key of the last steady charge reading: (mission time, %)
PERCENT_KEY = "energy_percent"
#: ``ctx.resources`` key of how many batteries ``ChangeBattery`` has put in so far
BATTERY_KEY = "energy_battery"
#: ``ctx.resources`` key of how many times the mission's energy checks (every EnoughEnergy,
#: EnoughEnergyForPass) have been evaluated: an interval between two of one check's own
#: evaluations that others interleave is not one task (the mission did other work between)
CHECKS_KEY = "energy_checks"
#: the latest task times (on one battery) EnoughEnergy takes the median of
TASKS_KEPT = 50
#: the charge is read as the median of the readings over this many seconds: the gauge dips
#: for a moment when the drone brakes or climbs (more thrust, more sag: 0.02 V, a few % at
#: a low charge) and a check on the dip would stop a pass the charge covers
STEADY_S = 3.0


def count_energy_check(ctx: Any) -> int:
    """Count one evaluation of an energy check (:data:`CHECKS_KEY`); return the count."""
    n = int(ctx.resources.get(CHECKS_KEY, 0)) + 1
    ctx.resources[CHECKS_KEY] = n
    return n


def travel_m(ctx: Any, a: Any, b: Any) -> float:
    """How far the drone flies from ``a`` to ``b``: around the racks of the world's map
    (the way ``FlyRoute`` goes), else in a straight line."""
    from nodes.sweep_plan import route_length

    return route_length(ctx, tuple(a), tuple(b))


def measured_rate(ctx: Any, now: float, max_age_s: float = 30.0) -> float | None:
    """The consumption (%/s) an ``EnoughEnergy`` measured on the current battery in the
    last ``max_age_s`` seconds, or None."""
    got = ctx.resources.get(RATE_KEY)
    if got is None or now - got[0] > max_age_s:
        return None
    return float(got[1])


def forget_battery(ctx: Any) -> None:
    """A new battery (``ChangeBattery`` done): the consumption and charge measured on the
    old one no longer hold."""
    ctx.resources.pop(RATE_KEY, None)
    ctx.resources.pop(PERCENT_KEY, None)
    ctx.resources[BATTERY_KEY] = ctx.resources.get(BATTERY_KEY, 0) + 1


def steady_reading(ctx: Any, now: float, max_age_s: float) -> tuple[float, float] | None:
    """(the charge an ``EnoughEnergy`` read last in flight: the median over
    :data:`STEADY_S`, %; how long ago, s), if within ``max_age_s``; else None."""
    got = ctx.resources.get(PERCENT_KEY)
    if got is None or now - got[0] > max_age_s:
        return None
    return float(got[1]), now - got[0]


def steady_percent(ctx: Any, now: float, fallback: float, max_age_s: float = 2.0) -> float:
    """:func:`steady_reading`'s charge if read within ``max_age_s``, else ``fallback`` (the
    gauge now)."""
    got = steady_reading(ctx, now, max_age_s)
    return fallback if got is None else got[0]


def needed_percent(
    rate_pct_per_s: float,
    to_target_m: float,
    target_to_home_m: float,
    speed_mps: float,
    task_s: float,
    landing_s: float,
    reserve_pct: float,
) -> tuple[float, float]:
    """(charge needed in %, seconds needed) to fly to the target, work there ``task_s``,
    fly home and land, plus the reserve."""
    seconds = (to_target_m + target_to_home_m) / max(speed_mps, 1e-3) + task_s + landing_s
    return rate_pct_per_s * seconds + reserve_pct, seconds


#: the battery's reserve and assumed endurance, as every energy leaf declares them
RESERVE_PORT = input_port(
    "reserve", FLOAT, 15.0, "charge to keep at touchdown, %", low=0.0, high=90.0
)
ENDURANCE_PORT = input_port(
    "endurance",
    DURATION,
    360.0,
    "flight time of a full battery until measured, s",
    low=10.0,
    high=36000.0,
)


@register
class EnoughEnergy(ConditionNode):
    """SUCCESS if the battery covers the next task and the way home: flying to ``target``,
    ``task_time`` there (once two tasks were timed on this battery: their median; a task is
    the time from one evaluation of this check to its next, unless another energy check was
    evaluated between: then the mission did other work, such as a sweep's pass), flying
    to ``home`` at ``speed`` and landing, with ``reserve`` percent left. The consumption is
    measured on the current battery after 20 s airborne (before that: a full battery lasts
    ``endurance``). FAILURE says how much is left and how much is needed."""

    bt_id = "EnoughEnergy"
    category = CATEGORY_ENERGY
    ports = (
        input_port("target", VEC3, description="where the next task is, x;y;z in m"),
        input_port("home", VEC3, description="where to land afterwards (the pad), x;y;z"),
        input_port("speed", FLOAT, 0.5, "transit speed, m/s", low=0.05, high=3.0),
        input_port("task_time", DURATION, 45.0, "time a task takes before any was timed, s"),
        input_port("landing_time", DURATION, 8.0, "time to land, s"),
        RESERVE_PORT,
        ENDURANCE_PORT,
        input_port(
            "period",
            DURATION,
            0.0,
            "re-evaluate at most this often (between two: the last answer); for a check "
            "ticked every tick beside a long action, such as a sweep pass, s",
        ),
    )

    def check(self) -> bool:
        v = vehicle_of(self)
        now = self.now()
        last = getattr(self, "_last", None)
        period = self.get_input("period")
        if (
            last is not None
            and period > 0
            and now - last[0] < period - 1e-9
            and v.is_flying == last[2]
        ):
            return last[1]
        ok = self._evaluate(v, now)
        self._last = (now, ok, v.is_flying)
        return ok

    def _evaluate(self, v: Any, now: float) -> bool:
        pct = v.battery.percent
        hist = getattr(self, "_hist", None)
        # a new battery: ChangeBattery said so (a check evaluated only just after each
        # change reads about the same charge each time, and its readings had spanned the
        # changes: the time between changes taken as the time per task), or the charge rose
        battery = self.ctx.resources.get(BATTERY_KEY, 0)
        renewed = hist is not None and (
            pct > hist[-1][1] + NEW_BATTERY_JUMP or battery != getattr(self, "_battery", 0)
        )
        self._battery = battery
        seq = count_energy_check(self.ctx)
        if hist is None or renewed or not v.is_flying:
            hist = self._hist = []  # a new battery (or on the ground): measure afresh
            self._tasks: list[float] = []  # the times of this check's tasks on it, s
            if renewed or not v.is_flying:
                self.ctx.resources.pop(RATE_KEY, None)
        if v.is_flying:
            if hist and getattr(self, "_seq", None) == seq - 1:  # nothing else checked since
                self._tasks.append(now - hist[-1][0])
                del self._tasks[:-TASKS_KEPT]
            hist.append((now, pct))
            recent = [p for t, p in hist if now - t <= STEADY_S]
            pct = statistics.median(recent)
            self.ctx.resources[PERCENT_KEY] = (now, pct)
        else:
            self.ctx.resources.pop(PERCENT_KEY, None)
        self._seq = seq
        (t0, p0) = hist[0] if hist else (now, pct)
        if hist and now - t0 >= MEASURE_AFTER_S and p0 > pct:
            rate = (p0 - pct) / (now - t0)
            how = "measured"
        else:
            rate = 100.0 / max(self.get_input("endurance"), 1.0)
            how = "assumed"
        if how == "measured":
            self.ctx.resources[RATE_KEY] = (now, rate)
        tasks = self._tasks
        task = statistics.median(tasks) if len(tasks) >= 2 else self.get_input("task_time")
        target, home = self.get_input("target"), self.get_input("home")
        need, seconds = needed_percent(
            rate,
            travel_m(self.ctx, v.position, target),
            travel_m(self.ctx, target, home),
            self.get_input("speed"),
            task,
            self.get_input("landing_time"),
            self.get_input("reserve"),
        )
        self.failure_reason = (
            f"{pct:.1f} % left, {need:.1f} % needed: {seconds:.0f} s to the next task, "
            f"through it and home at {rate * 60:.2f} %/min ({how}), plus the "
            f"{self.get_input('reserve'):g} % reserve"
        )
        return pct >= need


@register
class ChangeBattery(StatefulActionNode):
    """On the ground (after Land): ``mode=swap`` puts in a fresh battery and waits
    ``duration`` (the handling time); ``mode=charge`` charges on the pad for at least
    ``duration`` and until the charge reaches ``target_percent``: every ``check_period`` it
    stops charging for ``settle`` and reads the rested charge (the voltage reads high while a
    charging current flows). After a swap it waits ``settle`` for the reading to settle.
    SUCCESS when done; FAILURE in flight, when the vehicle cannot (a real battery is swapped
    by hand: the run stops there, resume it afterwards), or after ``timeout``."""

    bt_id = "ChangeBattery"
    category = CATEGORY_ENERGY
    ports = (
        input_port("mode", STRING, "swap", "swap (a fresh battery) or charge (on the pad)"),
        input_port("duration", DURATION, 60.0, "handling time of a swap / least charging time, s"),
        input_port(
            "target_percent", FLOAT, 95.0, "charge: stop at this charge, %", low=1.0, high=100.0
        ),
        input_port("check_period", DURATION, 60.0, "charge: read the rested charge this often, s"),
        input_port("settle", DURATION, 3.0, "rest before reading the charge, s"),
        input_port("timeout", DURATION, 3600.0, "FAILURE if not done within this time, s"),
    )

    def preflight(self) -> list[Any]:
        """A charge to stop at that no battery reaches, or a mode that is neither swap nor
        charge (``battery_mode=nuclear`` flew and failed at the first change), before
        anything flies."""
        out: list[Any] = []
        try:
            mode = self.get_input("mode")
        except Exception:  # noqa: BLE001 - written in flight: checked then
            return out
        if isinstance(mode, str) and mode.strip().lower() not in ("swap", "charge"):
            out.append(("mode", f"mode {mode!r}: expected swap or charge"))
        return out

    def _fail(self, reason: str) -> NodeStatus:
        self.ctx.log(f"{self.describe()} failed: {reason}")
        self.failure_reason = reason
        return FAILURE

    def on_start(self) -> NodeStatus:
        self.vehicle = vehicle_of(self)
        mode = self.get_input("mode").strip().lower()
        if mode not in ("swap", "charge"):
            return self._fail(f"mode must be swap or charge, got {mode!r}")
        self.mode, self.started_s = mode, self.now()
        # just landed, the gauge still reads the loaded voltage without the flight's sag
        # correction (a few %): the charge is the last steady reading in flight, if recent
        got = steady_reading(self.ctx, self.now(), 60.0)
        self.before = self.vehicle.battery.percent if got is None else got[0]
        self.before_note = "" if got is None else f" (read in flight {got[1]:.0f} s before)"
        self.resting_since: float | None = None  # resting (not charging) since
        self.charging_since = self.now()
        why = self.vehicle.battery_service(mode)
        if why:
            return self._fail(why)
        if mode == "swap":
            self.ctx.log(
                f"{self.describe()}: battery swapped at {self.before:.0f} %{self.before_note}"
            )
        return RUNNING

    def on_running(self) -> NodeStatus:
        now = self.now()
        if now - self.started_s >= self.get_input("timeout") - 1e-9:
            if self.mode == "charge":
                self.vehicle.battery_service("stop_charging")
            return self._fail(
                f"time-out after {self.get_input('timeout'):g} s at "
                f"{self.vehicle.battery.percent:.0f} %"
            )
        if now - self.started_s < self.get_input("duration") - 1e-9:
            return RUNNING
        settle = self.get_input("settle")
        if self.mode == "swap":
            if now - self.started_s < self.get_input("duration") + settle - 1e-9:
                return RUNNING
            return self._done(now)
        if self.resting_since is None:  # charging: time to rest and read?
            if now - self.charging_since < self.get_input("check_period") - 1e-9 and (
                now - self.started_s > self.get_input("duration") + 1e-9
            ):
                return RUNNING
            why = self.vehicle.battery_service("stop_charging")
            if why:
                return self._fail(why)
            self.resting_since = now
            return RUNNING
        if now - self.resting_since < settle - 1e-9:
            return RUNNING
        if self.vehicle.battery.percent >= self.get_input("target_percent"):
            return self._done(now)
        why = self.vehicle.battery_service("charge")  # not there yet: charge on
        if why:
            return self._fail(why)
        self.resting_since, self.charging_since = None, now
        return RUNNING

    def _done(self, now: float) -> NodeStatus:
        forget_battery(self.ctx)
        self.ctx.log(
            f"{self.describe()}: battery {self.mode} done, {self.before:.0f} % -> "
            f"{self.vehicle.battery.percent:.0f} % after {now - self.started_s:.0f} s"
        )
        return SUCCESS

    def on_halted(self) -> None:
        if getattr(self, "mode", "") == "charge" and getattr(self, "vehicle", None) is not None:
            self.vehicle.battery_service("stop_charging")
