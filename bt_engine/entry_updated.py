"""BehaviorTree.CPP v4's nodes that watch an entry's sequence id: ``SkipUnlessUpdated`` and
``WaitValueUpdate`` (``EntryUpdatedDecorator``, ``decorators/updated_decorator.h``) and
``WasEntryUpdated`` (``EntryUpdatedAction``, ``actions/updated_action.h``), tick for tick as
BehaviorTree.CPP 4.8.

An entry's sequence id counts its writes since it was created (any write counts, also of
the same value; an entry that does not exist has none): see
:meth:`bt_engine.blackboard.Scope.sequence_id`. Each node keeps the id it saw last
(initially 0), so an entry written before the node first looks counts as updated.
``entry`` names the entry, ``{key}`` or plain ``key`` alike (BehaviorTree.CPP reads the
port's text, not the entry's value).
"""

from __future__ import annotations

from typing import Any

from bt_engine.node import (
    FAILURE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    DecoratorNode,
    MissionContext,
    NodeStatus,
    SyncActionNode,
)
from bt_engine.ports import AnyType, PortValueError, input_port
from bt_engine.registry import REGISTRY

CATEGORY = "built-in"


class EntryName(AnyType):
    """The name of a blackboard entry: ``{key}`` (bound as a reference) or ``key``."""

    expected = "an entry name (key or {key})"

    def convert(self, value: Any) -> Any:
        if not isinstance(value, str) or not value.strip():
            raise PortValueError(f"expected {self.expected}, got {value!r:.60}")
        return value


ENTRY = EntryName()


def _entry_key(node: Any) -> str:
    return node.input_entry("entry") or node.get_input("entry")


class _EntryUpdatedDecorator(DecoratorNode):
    """Tick the child when ``entry`` was written since the last look, else return
    ``if_not_updated``; a RUNNING child is ticked until it finishes without a look."""

    if_not_updated: NodeStatus = SKIPPED
    ports = (input_port("entry", ENTRY, description="entry to check"),)

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.sequence_id = 0
        self.still_executing_child = False

    def tick_impl(self) -> NodeStatus:
        if not self.still_executing_child:
            current = self.scope.sequence_id(_entry_key(self))
            if current == 0:  # no such entry: the id seen last is kept
                return self.if_not_updated
            previous, self.sequence_id = self.sequence_id, current
            if previous == current:
                return self.if_not_updated
        status = self.children[0].execute_tick()
        self.still_executing_child = status is RUNNING
        return status

    def execute_tick(self) -> NodeStatus:
        # BT.CPP's DecoratorNode::executeTick: a child that finished is reset afterwards
        status = super().execute_tick()
        child = self.children[0]
        if child.bt_status is SUCCESS or child.bt_status is FAILURE:
            child.reset_status()
        return status

    def halt(self) -> None:
        # as BT.CPP 4.8 (EntryUpdatedDecorator::halt): neither the child nor the status is
        # reset here; the parent resets this node's status, a RUNNING child stays RUNNING
        self.still_executing_child = False


class SkipUnlessUpdated(_EntryUpdatedDecorator):
    """Tick the child only if ``entry`` was written since the last check; else SKIPPED.

    The first check finds an entry that exists updated. A child that returned RUNNING is
    ticked until it finishes without checking. As in BehaviorTree.CPP 4.8, a halt neither
    halts the child nor resets it (a RUNNING child stays RUNNING and continues the next
    time the entry is updated).
    """

    bt_id = "SkipUnlessUpdated"
    category = CATEGORY
    if_not_updated = SKIPPED


class WaitValueUpdate(_EntryUpdatedDecorator):
    """Return RUNNING until ``entry`` is written (since the last check), then tick the child.

    As SkipUnlessUpdated, but RUNNING instead of SKIPPED while the entry was not updated
    (or does not exist).
    """

    bt_id = "WaitValueUpdate"
    category = CATEGORY
    if_not_updated = RUNNING


class WasEntryUpdated(SyncActionNode):
    """SUCCESS if ``entry`` was written since this node last checked, else FAILURE.

    The first check finds an entry that exists updated; FAILURE while it does not exist.
    """

    bt_id = "WasEntryUpdated"
    category = CATEGORY
    ports = (input_port("entry", ENTRY, description="entry to check"),)

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.sequence_id = 0

    def tick_impl(self) -> NodeStatus:
        current = self.scope.sequence_id(_entry_key(self))
        if current == 0:
            return FAILURE
        previous, self.sequence_id = self.sequence_id, current
        return SUCCESS if previous != current else FAILURE


for _cls in (SkipUnlessUpdated, WaitValueUpdate, WasEntryUpdated):
    REGISTRY.register(_cls)
