"""The runner hook of the safety supervisor: the one place where safety meets the engine.

:class:`~drivers.safety.supervisor.SafetySupervisor` watches the Vehicle and decides; it
knows nothing of missions. :class:`SafetyHook` plugs it into a run: it is the runner's
*first* hook, tells the supervisor whether the tree still runs, writes what the supervisor
publishes on the mission's blackboard (``safety_state``, ``safety_fault``,
``safety_faults``; only when a value changes), makes it reachable to the safety conditions
(``mission.ctx.resources["safety"]``) and turns a take-over into
:class:`bt_engine.runner.Abort`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bt_engine.mission import Mission
from bt_engine.runner import Abort
from bt_engine.validate import KNOWN_ENTRIES
from drivers.safety.supervisor import SafetySupervisor

#: The blackboard entries the hook writes (scripts may read them: validation knows them).
PUBLISHED = ("safety_state", "safety_fault", "safety_faults")
KNOWN_ENTRIES.update(PUBLISHED)


class SafetyHook:
    """Runner hook around a supervisor (``before_tick``/``after_tick``/``shutdown``/``summary``).

    Args:
        make_supervisor: builds the supervisor from the keyword arguments ``clock``,
            ``tree_running`` and ``publish`` this hook supplies, e.g.
            ``lambda **kw: SafetySupervisor.from_rig(rig, platform, **kw)``.
        mission: the mission whose tree and blackboard the supervisor watches (optional).
        clock: the mission clock (default: the mission's).
    """

    def __init__(
        self,
        make_supervisor: Callable[..., SafetySupervisor],
        mission: Mission | None = None,
        clock: Any = None,
    ) -> None:
        self.mission = mission
        self._last: dict[str, Any] = {}
        kw: dict[str, Any] = {
            "clock": clock if clock is not None else getattr(mission, "clock", None)
        }
        if mission is not None:
            kw["tree_running"] = lambda: mission.status.value == "RUNNING"
            kw["publish"] = self._write
        self.supervisor = make_supervisor(**kw)
        if mission is not None:
            mission.ctx.resources["safety"] = self.supervisor

    def _write(self, values: dict[str, Any]) -> None:
        scope = self.mission.scope  # type: ignore[union-attr]
        for k, val in values.items():
            if self._last.get(k) != val or scope.get(k, None) != val:
                scope.set(k, val)
        self._last = values

    def before_tick(self, t_s: float) -> None:
        """Nothing: the platform steps first; the supervisor looks after the tree tick."""

    def after_tick(self, t_s: float) -> None:
        """Let the supervisor check every fault; raise :class:`Abort` if it takes over."""
        reason = self.supervisor.after_tick(t_s)
        if reason is not None:
            raise Abort(reason)

    def shutdown(self, reason: str) -> None:
        """Fly the recovery the way the run ended calls for (see the supervisor)."""
        self.supervisor.shutdown(reason)

    def summary(self) -> dict[str, Any]:
        """Key ``safety`` of ``summary.json``."""
        return self.supervisor.summary()


def make_safety_hook(rig: Any, platform: Any, mission: Mission | None) -> SafetyHook | None:
    """The safety hook of a run on ``platform`` (None for a platform without a Vehicle)."""
    if getattr(platform, "vehicle", None) is None:
        return None
    return SafetyHook(lambda **kw: SafetySupervisor.from_rig(rig, platform, **kw), mission)
