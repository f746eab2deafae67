"""Safety conditions: IsSafe, NoFault, FaultActive - let a mission react to a fault first.

The safety supervisor (:mod:`drivers.safety.supervisor`) checks every fault after each tick and keeps
its state on the blackboard (``safety_state``, ``safety_fault``, ``safety_faults``). These
conditions read it, so a tree can handle a fault itself within the policy's grace period::

    ReactiveFallback
    ├── NoFault fault=battery_low
    └── Sequence  (return home and land before the supervisor does)

Fault names: ``crash``, ``battery_critical``, ``link_lost``, ``geofence``, ``mocap_lost``,
``battery_low``, ``camera_stalled``, ``operator_interrupt``, ``leaf_exception``, or ``any``.
"""

from __future__ import annotations

from typing import Any

from bt_engine.node import BTNode, ConditionNode, NodeRuntimeError
from bt_engine.ports import PortValueError, StringType, input_port
from bt_engine.registry import register
from drivers.safety.policies import FAULTS
from nodes.common import CATEGORY_CHECK


class FaultNameType(StringType):
    """A fault name of :data:`drivers.safety.policies.FAULTS` or ``any`` (checked when loading)."""

    name = "fault"
    expected = "a fault name (" + ", ".join([*FAULTS, "any"]) + ")"

    def convert(self, value: Any) -> str:
        text = super().convert(value).strip()
        if text != "any" and text not in FAULTS:
            raise PortValueError(f"expected {self.expected}, got {value!r}")
        return text


FAULT_NAME = FaultNameType()


def _active(node: BTNode) -> list[str]:
    """Active faults: from the supervisor if the run has one, else the blackboard entry."""
    sup = node.ctx.resources.get("safety") if node.ctx is not None else None
    if sup is not None:
        return list(sup.active_faults())
    scope = node.scope
    if scope is not None and scope.has("safety_faults"):
        value = scope.get("safety_faults")
        return [str(v) for v in value] if isinstance(value, (list, tuple)) else [str(value)]
    raise NodeRuntimeError(node, "no safety supervisor in this run (needs a rig with safety)")


def _is_active(node: BTNode, fault: str) -> bool:
    active = _active(node)
    return bool(active) if fault == "any" else fault in active


@register
class IsSafe(ConditionNode):
    """SUCCESS while no fault the supervisor would act on is active (report-only faults,
    such as a stalled camera, do not count)."""

    bt_id = "IsSafe"
    category = CATEGORY_CHECK

    def check(self) -> bool:
        sup = self.ctx.resources.get("safety") if self.ctx is not None else None
        if sup is not None:
            return bool(sup.is_safe())
        return not [f for f in _active(self) if f != "camera_stalled"]


@register
class NoFault(ConditionNode):
    """SUCCESS while ``fault`` (or, with ``any``, every fault) is not active."""

    bt_id = "NoFault"
    category = CATEGORY_CHECK
    ports = (input_port("fault", FAULT_NAME, "any", "fault name, or any"),)

    def check(self) -> bool:
        return not _is_active(self, self.get_input("fault"))


@register
class FaultActive(ConditionNode):
    """SUCCESS while ``fault`` (or, with ``any``, some fault) is active."""

    bt_id = "FaultActive"
    category = CATEGORY_CHECK
    ports = (input_port("fault", FAULT_NAME, "any", "fault name, or any"),)

    def check(self) -> bool:
        return _is_active(self, self.get_input("fault"))
