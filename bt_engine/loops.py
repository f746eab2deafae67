"""The queue loops of BehaviorTree.CPP v4: ``LoopString``, ``LoopInt``, ``LoopDouble``,
``LoopBool`` (BehaviorTree.CPP's ``LoopNode<T>``, ``decorators/loop_node.h``; see
docs/references.md, ``[btcpp]``).

Each pops the front item of ``queue`` into ``value`` and ticks its child, one item per tick
at most: after the child finishes with SUCCESS (or SKIPPED) the loop returns RUNNING and
pops the next item at the next tick; a FAILURE of the child ends the loop with FAILURE; an
empty queue (when the child is not RUNNING) returns ``if_empty``. The loop never loops
within one tick and never emits a wake-up, exactly as ``LoopNode::tick``.

``queue`` is either a literal (``queue="A-01;A-02"``, ``[A-01, A-02]`` in YAML), copied
afresh each time the loop starts from IDLE (after it finished or was halted), or a
blackboard entry (``queue="{todo}"``) holding a list or ``;``-separated text, which the loop
consumes: after each pop the entry holds a new list of the items left (BehaviorTree.CPP pops
its shared deque in place; entries are read by name, so the effect is the same).
"""

from __future__ import annotations

from collections import deque
from typing import Any

from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    DecoratorNode,
    MissionContext,
    NodeRuntimeError,
    NodeStatus,
)
from bt_engine.ports import (
    BOOL,
    FLOAT,
    INT,
    STRING,
    PortType,
    PortValueError,
    QueueType,
    inout_port,
    input_port,
    output_port,
)
from bt_engine.registry import REGISTRY

CATEGORY = "built-in"


class StatusType(PortType):
    """A node status a node may return: ``SUCCESS``, ``FAILURE``, ``SKIPPED`` or ``RUNNING``
    (BehaviorTree.CPP's ``NodeStatus``; any case). Converts to :class:`NodeStatus`."""

    name = "NodeStatus"
    expected = "SUCCESS, FAILURE, SKIPPED or RUNNING"
    _BY_NAME = {s.value: s for s in (SUCCESS, FAILURE, SKIPPED, RUNNING)}

    def convert(self, value: Any) -> NodeStatus:
        if isinstance(value, NodeStatus) and value is not IDLE:
            return value
        if isinstance(value, str):
            status = self._BY_NAME.get(value.strip().upper())
            if status is not None:
                return status
        raise PortValueError(f"expected {self.expected}, got {value!r}"[:300])

    def to_text(self, value: Any) -> str:
        return value.value if isinstance(value, NodeStatus) else str(value)

    def to_yaml(self, value: Any) -> str:
        return self.to_text(value)


STATUS = StatusType()


class LoopNode(DecoratorNode):
    """Base of the queue loops; a subclass declares its ports (see :func:`_ports`)."""

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.child_running = False
        #: the private copy of a literal queue, made when the loop starts from IDLE
        self.items: deque[Any] = deque()

    def tick_impl(self) -> NodeStatus:
        key = self.output_key("queue")  # None: a literal queue
        popped = False
        if self.bt_status is IDLE:
            self.child_running = False
            if key is None:
                self.items = deque(self.get_input("queue"))
        if not self.child_running:
            if key is None:
                if self.items:
                    value = self.items.popleft()
                    popped = True
            else:
                queue = self._shared_queue(key)
                if queue:
                    value = queue[0]
                    self.set_output("queue", queue[1:])
                    popped = True
            if popped:
                self.set_output("value", value)
        if not popped and not self.child_running:
            return self.get_input("if_empty")
        if self.bt_status is IDLE:
            self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        self.child_running = st is RUNNING
        if st is SUCCESS or st is FAILURE:
            self.halt_child()
        return FAILURE if st is FAILURE else RUNNING

    def _shared_queue(self, key: str) -> list[Any]:
        """The items of the blackboard queue ``{key}``, converted (raises if unusable)."""
        queue = self.get_input("queue")  # converted by QueueType; raises if the entry is unset
        if queue is None:
            raise NodeRuntimeError(
                self, f"input port 'queue' reads blackboard entry {{{key}}}, which is None"
            )
        return queue


def _doc(bt_id: str, item: str, example: str, child: str) -> str:
    return f"""Tick the child once per {item} popped from ``queue`` into ``value``.

    Per tick, while the child is not RUNNING, pop the front item into ``value``; if the
    queue is empty, return ``if_empty`` (SUCCESS by default). Then tick the child: RUNNING
    or SUCCESS -> RUNNING (the next item comes at the next tick), FAILURE -> FAILURE (the
    rest of the queue is left). So a queue of n items takes n + 1 ticks at least.
    A literal ``queue`` is copied each time the loop starts; a blackboard ``queue`` (a
    list, or text split on ``;``) is consumed: the entry keeps the items not yet popped.
    BehaviorTree.CPP's ``LoopNode``::

        {bt_id} queue="{example}" value="{{item}}"
        └── {child}
    """


def _ports(element: PortType, what: str, example: str) -> tuple:
    return (
        inout_port(
            "queue",
            QueueType(element),
            description=f'{what} to loop over ("{example}"), or a blackboard entry (consumed)',
            takes_literal=True,
        ),
        input_port("if_empty", STATUS, "SUCCESS", "status returned when the queue is empty"),
        output_port("value", element, "the item popped for this run of the child"),
    )


class LoopString(LoopNode):
    __doc__ = _doc(
        "LoopString", "text", "A-01-1;A-02-1;A-03-1", 'SubTree ID="Inspect" pallet="{item}"'
    )
    bt_id = "LoopString"
    category = CATEGORY
    ports = _ports(STRING, "texts", "a;b;c")


class LoopInt(LoopNode):
    __doc__ = _doc("LoopInt", "whole number", "1;2;3", 'Script code="total += item"')
    bt_id = "LoopInt"
    category = CATEGORY
    ports = _ports(INT, "whole numbers", "1;2;3")


class LoopDouble(LoopNode):
    __doc__ = _doc("LoopDouble", "number", "0.5;1.0;1.5", 'Script code="total += item"')
    bt_id = "LoopDouble"
    category = CATEGORY
    ports = _ports(FLOAT, "numbers", "0.5;1;1.5")


class LoopBool(LoopNode):
    __doc__ = _doc("LoopBool", "boolean", "true;false", 'ScriptCondition code="item"')
    bt_id = "LoopBool"
    category = CATEGORY
    ports = _ports(BOOL, "booleans", "true;false")


for _cls in (LoopString, LoopInt, LoopDouble, LoopBool):
    REGISTRY.register(_cls)
