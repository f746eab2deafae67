"""The safety supervisor: fault policies checked every tick, outside the mission tree.

Two layers:

* :class:`FaultMonitor` is pure logic. Fed one :class:`Observation` per tick (a fake clock is
  enough), it tracks which faults are active, since when, and decides when the supervisor
  must take over (a fault whose grace period ran out, or any actionable fault once the tree
  has stopped running while the drone is airborne).
* :class:`SafetySupervisor` is a runner hook (``before_tick``/``after_tick``/``shutdown`` +
  ``summary``). ``after_tick`` observes the :class:`~drivers.vehicle.Vehicle`, publishes the
  state on the blackboard (``safety_state``, ``safety_fault``, ``safety_faults``) and, to
  take over, raises :class:`bt_engine.runner.Abort`. The runner then halts the tree and calls
  every hook's ``shutdown``; the supervisor is the *first* hook, so its ``shutdown`` flies the
  recovery (through the Vehicle API, stepping the platform itself, bounded by
  ``safety.max_recovery_s``) before the platform's own shutdown, which then finds the drone
  down. ``shutdown`` also covers every other way a run ends with the drone in the air:
  operator interrupt (SIGINT/SIGTERM; a second one cuts the motors), an exception in a leaf,
  a tree that failed, a time limit.

See ``docs/safety.md`` for the policies, their defaults and the ordering.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from drivers.types import FlightState

#: Every fault the supervisor knows, most severe first, with a one-line description.
FAULTS: dict[str, str] = {
    "crash": "crash detected (or the motors stopped without being asked)",
    "battery_critical": "battery below the critical voltage",
    "link_lost": "no telemetry from the drone",
    "geofence": "outside the geofence",
    "mocap_lost": "motion capture stale or dropped",
    "battery_low": "battery below the low voltage",
    "camera_stalled": "camera stopped delivering frames",
    "operator_interrupt": "operator interrupt (SIGINT/SIGTERM)",
    "leaf_exception": "an exception inside a leaf",
}

#: What a policy may do when it takes over.
ACTIONS: dict[str, str] = {
    "report": "report only (the mission decides)",
    "land": "land where it is",
    "hold_then_land": "hold position for hold_s (or until the fault clears), then land",
    "return_and_land": "fly back above the take-off point, then land",
    "return_inside_and_land": "stop, hold for hold_s, fly back inside the geofence, then land",
    "motors_off": "cut the motors and disarm",
}

#: Faults detected by observation every tick (the other two come from how the run ended).
OBSERVED = (
    "crash",
    "battery_critical",
    "link_lost",
    "geofence",
    "mocap_lost",
    "battery_low",
    "camera_stalled",
)
#: Faults that stay active once seen (a sagging battery recovers when the load drops).
LATCHED = ("crash", "battery_critical", "battery_low")


@dataclass(frozen=True)
class Policy:
    """What to do about one fault: ``action`` (see :data:`ACTIONS`) after ``grace_s``.

    ``grace_s`` is how long the mission tree keeps control after the fault is detected (it may
    react with ``FaultActive``/``IsSafe``, and a transient fault may clear). ``hold_s`` is the
    hold time of ``hold_then_land`` / ``return_inside_and_land``.
    """

    action: str = "land"
    grace_s: float = 0.0
    hold_s: float = 0.0


DEFAULT_POLICIES: dict[str, Policy] = {
    "crash": Policy("motors_off"),
    "battery_critical": Policy("land"),
    "link_lost": Policy("hold_then_land", 0.0, 1.0),
    "geofence": Policy("return_inside_and_land", 0.0, 0.5),
    "mocap_lost": Policy("hold_then_land", 1.0, 0.5),
    "battery_low": Policy("return_and_land", 2.0),
    "camera_stalled": Policy("report"),
    "operator_interrupt": Policy("land"),
    "leaf_exception": Policy("land"),
}


@dataclass
class SafetyConfig:
    """The rig's ``safety:`` section (see ``rigs/sim.yaml``)."""

    enabled: bool = True
    policies: dict[str, Policy] = field(default_factory=lambda: dict(DEFAULT_POLICIES))
    battery_low_v: float = 3.3
    battery_critical_v: float = 3.1
    geofence_enabled: bool = True
    geofence_min_m: tuple[float, float, float] = (-1.5, -3.0, -0.5)
    geofence_max_m: tuple[float, float, float] = (9.2, 3.0, 2.5)
    geofence_margin_m: float = 0.3
    land_speed_mps: float = 0.3
    return_speed_mps: float = 0.5
    max_recovery_s: float = 30.0

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SafetyConfig:
        """Build from validated rig data (``rig.data["safety"]``); missing keys keep defaults."""
        c = cls()
        if not data:
            return c
        pol = dict(DEFAULT_POLICIES)
        for name, p in (data.get("policies") or {}).items():
            base = pol.get(name, Policy())
            pol[name] = Policy(
                p.get("action", base.action),
                float(p.get("grace_s", base.grace_s)),
                float(p.get("hold_s", base.hold_s)),
            )
        c.policies = pol
        c.enabled = bool(data.get("enabled", c.enabled))
        for key in (
            "battery_low_v",
            "battery_critical_v",
            "land_speed_mps",
            "return_speed_mps",
            "max_recovery_s",
        ):
            if key in data:
                setattr(c, key, float(data[key]))
        g = data.get("geofence") or {}
        c.geofence_enabled = bool(g.get("enabled", c.geofence_enabled))
        if "min_m" in g:
            c.geofence_min_m = tuple(float(v) for v in g["min_m"])  # type: ignore[assignment]
        if "max_m" in g:
            c.geofence_max_m = tuple(float(v) for v in g["max_m"])  # type: ignore[assignment]
        c.geofence_margin_m = float(g.get("margin_m", c.geofence_margin_m))
        return c

    def inside(self, p: tuple[float, float, float], margin_m: float = 0.0) -> bool:
        """True if ``p`` is inside the geofence box shrunk by ``margin_m``."""
        lo, hi = self.geofence_min_m, self.geofence_max_m
        return all(lo[i] + margin_m <= p[i] <= hi[i] - margin_m for i in range(3))

    def nearest_inside(self, p: tuple[float, float, float]) -> tuple[float, float, float]:
        """The point of the box shrunk by ``geofence_margin_m`` nearest to ``p``."""
        lo, hi, m = self.geofence_min_m, self.geofence_max_m, self.geofence_margin_m
        out = []
        for i in range(3):
            a, b = lo[i] + m, hi[i] - m
            if a > b:  # box thinner than twice the margin: its middle
                a = b = 0.5 * (lo[i] + hi[i])
            out.append(min(max(p[i], a), b))
        return (out[0], out[1], out[2])


@dataclass(frozen=True)
class Observation:
    """What the monitor sees at one tick. ``None`` means "not available / not monitored"."""

    t_s: float
    airborne: bool
    landing: bool = False
    crashed: bool = False
    link_ok: bool = True
    mocap_ok: bool | None = None
    camera_ok: bool | None = None
    battery_v: float | None = None
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tree_running: bool = True


@dataclass
class FaultRecord:
    """One detection of a fault: when it started, when it cleared (None: still active)."""

    fault: str
    t_s: float
    cleared_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {
            "fault": self.fault,
            "t_s": round(self.t_s, 3),
            "cleared_s": None if self.cleared_s is None else round(self.cleared_s, 3),
        }


class FaultMonitor:
    """Pure fault logic: feed :meth:`update` one observation per tick."""

    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self.since: dict[str, float] = {}  # active fault -> detection time
        self.history: list[FaultRecord] = []
        self._open: dict[str, FaultRecord] = {}

    def conditions(self, o: Observation) -> dict[str, bool]:
        """Which observed fault conditions hold in ``o`` (before latching)."""
        c = self.config
        up = o.airborne
        v = o.battery_v
        return {
            "crash": o.crashed,
            "battery_critical": up and v is not None and 0.0 < v < c.battery_critical_v,
            "link_lost": up and not o.link_ok,
            "geofence": up and c.geofence_enabled and not c.inside(o.position),
            "mocap_lost": up and o.mocap_ok is False,
            "battery_low": up and v is not None and 0.0 < v < c.battery_low_v,
            "camera_stalled": up and o.camera_ok is False,
        }

    def active(self) -> list[str]:
        """Active faults, most severe first."""
        return [f for f in FAULTS if f in self.since]

    def is_active(self, fault: str) -> bool:
        """True if ``fault`` is active (``any``: any fault at all)."""
        return bool(self.since) if fault == "any" else fault in self.since

    def actionable(self) -> list[str]:
        """Active faults whose policy does something (not ``report``), most severe first."""
        return [f for f in self.active() if self.config.policies[f].action != "report"]

    def update(self, o: Observation) -> str | None:
        """Update the fault states; return the fault to act on now, or None.

        The supervisor acts on the most severe actionable fault whose grace period is over, or
        at once on any actionable fault if the tree is no longer running while the drone is
        airborne. While the drone is landing (the tree is bringing it down) it waits, unless
        the policy cuts the motors.
        """
        for name, cond in self.conditions(o).items():
            if cond and name not in self.since:
                self.since[name] = o.t_s
                rec = FaultRecord(name, o.t_s)
                self.history.append(rec)
                self._open[name] = rec
            elif not cond and name in self.since and name not in LATCHED:
                del self.since[name]
                self._open.pop(name).cleared_s = o.t_s
        for name in self.actionable():
            pol = self.config.policies[name]
            if pol.action == "motors_off":
                return name
            if not o.airborne:
                continue
            if not o.tree_running:
                return name
            if o.landing:
                continue
            if o.t_s - self.since[name] >= pol.grace_s - 1e-9:
                return name
        return None


def _fmt(v: float) -> str:
    return f"{v:g}"


def describe_action(policy: Policy) -> str:
    """A short human description of what ``policy`` does."""
    a = policy.action
    if a == "hold_then_land":
        return f"hold up to {_fmt(policy.hold_s)} s, then land"
    if a == "return_inside_and_land":
        return f"stop, hold {_fmt(policy.hold_s)} s, fly back inside the geofence, land"
    return ACTIONS.get(a, a)


class SafetySupervisor:
    """The runner hook (see the module docstring). Put it *first* in the runner's hooks.

    Args:
        config: the policies.
        vehicle: the :class:`~drivers.vehicle.Vehicle` to watch and fly.
        platform: the platform hook (its ``before_tick(t)`` steps a lock-step simulator; its
            ``summary()`` gives ground truth for the final state), optional.
        mission: the mission (blackboard, tree status), optional.
        clock: the mission clock (default: the mission's).
    """

    STEP_S = 0.02

    def __init__(
        self,
        config: SafetyConfig,
        vehicle: Any,
        platform: Any = None,
        mission: Any = None,
        clock: Any = None,
    ) -> None:
        self.config = config
        self.vehicle = vehicle
        self.platform = platform
        self.mission = mission
        self.clock = clock if clock is not None else getattr(mission, "clock", None)
        self.monitor = FaultMonitor(config)
        self.home: tuple[float, float, float] | None = None
        self.fault: str | None = None  # the fault that ended the run (or is being handled)
        self.fault_t_s: float | None = None
        self.acted_s: float | None = None
        self.steps: list[dict[str, Any]] = []
        self.state = "ok"
        self.recovered = False
        self.recovery_s = 0.0
        self.interrupted = False
        self._published: dict[str, Any] = {}
        if mission is not None:
            mission.ctx.resources["safety"] = self
        self._publish()

    @classmethod
    def from_rig(cls, rig: Any, platform: Any, mission: Any = None) -> SafetySupervisor:
        """Build from a :class:`drivers.rig.Rig` and its platform."""
        config = SafetyConfig.from_dict(rig.data.get("safety"))
        return cls(config, platform.vehicle, platform, mission)

    # ------------------------------------------------------------------ observing
    def observe(self, t_s: float) -> Observation:
        """Read the vehicle into an :class:`Observation`."""
        v = self.vehicle
        h = v.health
        mocap_ok = None
        if v.mocap is not None and v.config.pose_source == "mocap" and h.mocap.samples > 0:
            mocap_ok = h.mocap.healthy
        camera_ok = None
        if v.camera is not None and h.camera.samples > 0:
            camera_ok = h.camera.healthy
        volts = v.battery.voltage_v
        m = self.mission
        running = True
        if m is not None:
            running = m.status.value == "RUNNING"
        return Observation(
            t_s=t_s,
            airborne=v.is_flying,
            landing=v.flight_state == FlightState.LANDING,
            crashed=v.is_crashed or v.flight_state == FlightState.EMERGENCY,
            link_ok=h.link.healthy,
            mocap_ok=mocap_ok,
            camera_ok=camera_ok,
            battery_v=volts if volts > 0 else None,
            position=v.position,
            tree_running=running,
        )

    def active_faults(self) -> list[str]:
        """Faults active now, most severe first (operator interrupt / leaf exception included
        once the run has ended that way)."""
        out = self.monitor.active()
        if self.fault is not None and self.fault not in out:
            out.append(self.fault)
        return out

    def fault_active(self, fault: str) -> bool:
        """True if ``fault`` (or, for ``any``, any fault) is active."""
        if fault == "any":
            return bool(self.active_faults())
        return fault in self.active_faults()

    def is_safe(self) -> bool:
        """True while no fault the supervisor would act on is active."""
        return not self.monitor.actionable() and self.fault is None

    def _publish(self) -> None:
        m = self.mission
        active = self.active_faults()
        if self.state in ("ok", "fault"):
            self.state = "fault" if active else "ok"
        values = {
            "safety_state": self.state,
            "safety_fault": active[0] if active else "",
            "safety_faults": active,
        }
        if m is None:
            self._published = values
            return
        for k, val in values.items():
            if self._published.get(k) != val or m.scope.get(k, None) != val:
                m.scope.set(k, val)
        self._published = values

    # ------------------------------------------------------------------ hooks
    def before_tick(self, t_s: float) -> None:
        """Nothing: the platform steps first, the supervisor looks after the tree tick."""

    def after_tick(self, t_s: float) -> None:
        """Check every fault; publish; on a fault to act on, raise ``Abort`` (ends the run)."""
        if not self.config.enabled or self.fault is not None:
            return
        v = self.vehicle
        if not v.is_flying and not v.is_crashed:
            self.home = v.position
        elif self.home is None and v.motion is not None and v.motion.kind == "takeoff":
            self.home = tuple(v.motion.goal)  # take-off started this tick: above its start
        obs = self.observe(t_s)
        act_on = self.monitor.update(obs)
        if act_on is None:
            self._publish()
            return
        from bt_engine.runner import Abort

        self.fault = act_on
        self.fault_t_s = self.monitor.since.get(act_on, t_s)
        self.acted_s = t_s
        self.state = "recovering"
        self._publish()
        pol = self.config.policies[act_on]
        raise Abort(f"safety: {act_on} ({FAULTS[act_on]}) -> {describe_action(pol)}")

    def shutdown(self, reason: str) -> None:
        """Bring the drone down according to why the run ended (bounded), then disarm."""
        if self.recovered:
            return
        self.recovered = True
        v = self.vehicle
        if self.fault is None:
            if reason.startswith("operator interrupt"):
                self.fault = "operator_interrupt"
            elif reason.startswith("internal error"):
                self.fault = "leaf_exception"
            elif v.is_flying and self.monitor.active():
                self.fault = self.monitor.active()[0]  # e.g. the tree gave up on a stalled camera
            if self.fault is not None:
                self.fault_t_s = self.monitor.since.get(self.fault, self._now())
                self.acted_s = self._now()
        action = "none"
        if self.fault is not None:
            action = self.config.policies[self.fault].action
        if v.is_flying and action in ("none", "report"):
            action = "land"  # the run is over: never leave a drone in the air
        t0 = self._now()
        try:
            if v.is_flying or action == "motors_off":
                self.state = "recovering"
                self._fly(action)
        except KeyboardInterrupt:  # second SIGINT/SIGTERM: emergency stop
            self.interrupted = True
            v.emergency_stop()
            self._step("emergency stop (second interrupt)")
        self.recovery_s = self._now() - t0
        if not v.is_flying and not v.is_crashed and v.is_armed:
            v.disarm()
            self._step("disarm")
        self.state = "finished"
        self._publish()

    # ------------------------------------------------------------------ recovery flight
    def _now(self) -> float:
        if self.clock is not None:
            return float(self.clock.now())
        return float(getattr(self.vehicle, "now_s", 0.0))

    def _step(self, what: str) -> None:
        self.steps.append({"t_s": round(self._now(), 3), "action": what})

    def _advance(self) -> None:
        """One recovery step: move the clock on (sleep on a wall clock) and step the platform."""
        t = self._now() + self.STEP_S
        if self.clock is not None:
            self.clock.sleep_until(t)
            t = self._now()
        hook = getattr(self.platform, "before_tick", None)
        if hook is not None:
            hook(t)
        else:
            self.vehicle.update(t)

    def _wait(self, done, limit_s: float, deadline: float) -> bool:
        """Step until ``done()`` or ``limit_s`` passed (or the overall deadline); True if done."""
        end = min(self._now() + limit_s, deadline)
        while True:
            if done():
                return True
            if self._now() >= end - 1e-9:
                return False
            self._advance()

    def _critical(self) -> bool:
        v = self.vehicle.battery.voltage_v
        return 0.0 < v < self.config.battery_critical_v

    def _fly(self, action: str) -> None:
        v, c = self.vehicle, self.config
        deadline = self._now() + c.max_recovery_s
        pol = self.config.policies.get(self.fault or "", Policy(action))
        down = lambda: not v.is_flying  # noqa: E731
        if action == "motors_off":
            v.emergency_stop()
            self._step("motors off")
            return
        if action == "hold_then_land":
            v.hover()
            self._step(f"hold (up to {_fmt(pol.hold_s)} s)")
            fault = self.fault

            def cleared() -> bool:
                obs = self.observe(self._now())
                return not self.monitor.conditions(obs).get(fault or "", False)

            self._wait(cleared, pol.hold_s, deadline)
        elif action == "return_and_land" and self.home is not None:
            x, y, z = v.position
            hx, hy, _ = self.home
            p = v.go_to(hx, hy, z, speed_mps=c.return_speed_mps)
            self._step(f"return to ({hx:.2f}, {hy:.2f}) at {z:.2f} m")
            dist = math.hypot(hx - x, hy - y)
            limit = 10.0 + 2.0 * dist / max(c.return_speed_mps, 1e-3)
            self._wait(
                lambda: p.reached or p.failed or p.cancelled or self._critical() or down(),
                limit,
                deadline,
            )
            if self._critical():
                self._step("battery critical: land here")
        elif action == "return_inside_and_land":
            v.stop()
            self._step(f"stop, hold {_fmt(pol.hold_s)} s")
            self._wait(lambda: False, pol.hold_s, deadline)
            target = c.nearest_inside(v.position)
            p = v.go_to(*target, speed_mps=c.return_speed_mps)
            self._step("fly inside the geofence to ({:.2f}, {:.2f}, {:.2f})".format(*target))
            self._wait(lambda: p.reached or p.failed or p.cancelled or down(), 20.0, deadline)
        if v.is_flying:
            if v.flight_state != FlightState.LANDING:
                v.land(c.land_speed_mps)
            self._step("land")
            if not self._wait(down, c.max_recovery_s, deadline) and v.is_flying:
                v.emergency_stop()
                self._step(f"motors off: not landed within {_fmt(c.max_recovery_s)} s")

    # ------------------------------------------------------------------ outputs
    def final_state(self) -> tuple[str, bool]:
        """("landed" | "crashed" | "flying" | "motors_off", disarmed) - ground truth if known."""
        summ = getattr(self.platform, "summary", None)
        if summ is not None:
            s = summ()
            if "crashed" in s and "landed" in s:
                state = "crashed" if s["crashed"] else "landed" if s["landed"] else "flying"
                return state, not s.get("armed", self.vehicle.is_armed)
        v = self.vehicle
        fs = v.flight_state
        state = {
            FlightState.CRASHED: "crashed",
            FlightState.LANDED: "landed",
            FlightState.EMERGENCY: "motors_off",
        }.get(fs, "flying")
        return state, not v.is_armed

    def summary(self) -> dict[str, Any]:
        """Key ``safety`` of ``summary.json``: which fault ended the run, when, what was done."""
        state, disarmed = self.final_state()
        pol = self.config.policies.get(self.fault or "")
        return {
            "enabled": self.config.enabled,
            "fault": self.fault,
            "description": FAULTS.get(self.fault or ""),
            "t_s": None if self.fault_t_s is None else round(self.fault_t_s, 3),
            "acted_s": None if self.acted_s is None else round(self.acted_s, 3),
            "policy": None if pol is None else describe_action(pol),
            "actions": list(self.steps),
            "recovery_s": round(self.recovery_s, 3),
            "final_state": state,
            "disarmed": disarmed,
            "faults_seen": [r.as_dict() for r in self.monitor.history],
        }
