"""The base classes of every node: BehaviorTree.CPP v4 tick semantics on py_trees behaviours.

Each node is a :class:`py_trees.behaviour.Behaviour`, so py_trees' displays and visitors work
on a btrun tree, but the tick follows BehaviorTree.CPP v4 (``TreeNode::executeTick``):
pre-conditions (``_failureIf``, ``_successIf``, ``_skipIf``, ``_while``) are checked, then the
node's own :meth:`BTNode.tick_impl`, then post-conditions (``_onSuccess``, ``_onFailure``,
``_post``); ``_onHalted`` runs when a running node is halted.

Status mapping onto py_trees (``node.status``):

====================  =========================
BehaviorTree.CPP       py_trees ``Status``
====================  =========================
IDLE                   INVALID
SKIPPED                INVALID (``bt_status`` keeps SKIPPED)
RUNNING                RUNNING
SUCCESS                SUCCESS
FAILURE                FAILURE
====================  =========================

``node.bt_status`` always holds the exact BehaviorTree.CPP status.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import py_trees
from py_trees.common import Status as PTStatus

from bt_engine import node_checks as checks
from bt_engine.node_checks import CHANGE_LIMIT, compact_changes
from bt_engine.ports import ANY, NO_DEFAULT, STRING, Port, PortValueError
from bt_engine.watchdog import TickOverrun

if TYPE_CHECKING:
    from bt_engine.blackboard import Scope
    from bt_engine.clock import Clock
    from bt_engine.script import Script
    from bt_engine.spec import Loc


class NodeStatus(enum.Enum):
    """BehaviorTree.CPP v4 node statuses."""

    IDLE = "IDLE"
    RUNNING = "RUNNING"
    SUCCESS = "SUCCESS"
    FAILURE = "FAILURE"
    SKIPPED = "SKIPPED"

    # Members are singletons compared by identity, so the identity hash is consistent with
    # equality; Enum's own __hash__ is a Python-level call, and set_status hashes a status
    # twice per node per tick (bench/tick_overhead.py: ~15% of a tick).
    __hash__ = object.__hash__

    def __str__(self) -> str:
        return self.value


IDLE = NodeStatus.IDLE
RUNNING = NodeStatus.RUNNING
SUCCESS = NodeStatus.SUCCESS
FAILURE = NodeStatus.FAILURE
SKIPPED = NodeStatus.SKIPPED

TO_PY_TREES = {
    IDLE: PTStatus.INVALID,
    SKIPPED: PTStatus.INVALID,
    RUNNING: PTStatus.RUNNING,
    SUCCESS: PTStatus.SUCCESS,
    FAILURE: PTStatus.FAILURE,
}

# Order matters: BehaviorTree.CPP checks pre-conditions in this order.
PRE_CONDITIONS = ("_failureIf", "_successIf", "_skipIf", "_while")
POST_CONDITIONS = ("_onHalted", "_onFailure", "_onSuccess", "_post")


class NodeRuntimeError(RuntimeError):
    """A node could not run (e.g. an input entry is missing); carries the node's location."""

    def __init__(self, node: BTNode, message: str) -> None:
        self.node = node
        where = f"{node.loc}: " if node.loc is not None else ""
        super().__init__(f"{where}{node.bt_id} '{node.name}': {message}")


class PortRangeError(NodeRuntimeError):
    """A value read from the blackboard outside its port's declared range."""


@dataclass
class MissionContext:
    """What nodes of one mission share: its clock, the vehicle (if any) and resources.

    ``resources`` is a free dictionary for plug-in packages (perception models, galleries).
    ``enums`` are the integer values scripts may name (``FIXED_YAW``).
    """

    clock: Clock
    vehicle: Any = None
    resources: dict[str, Any] = field(default_factory=dict)
    enums: dict[str, int] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    #: set by a node that wants the root ticked again at once (BehaviorTree.CPP wake-up)
    woken: bool = False
    #: ``_onHalted`` scripts that failed: halting goes on (every node is halted), then the
    #: runner ends the run with the first of these as its reason
    halt_errors: list[str] = field(default_factory=list)
    #: set by the tick watchdog when a tick overran its budget: the loops that can keep one
    #: tick going (Repeat, RetryUntilSuccessful, the wake-up re-ticks) stop at their next turn
    stop_reason: str | None = None
    #: set while the mission is prepared (models, galleries load before the first tick):
    #: messages are shown at once, stamped with wall time, not at the first tick
    echo: Callable[[str], None] | None = None

    def check_stop(self) -> None:
        """Raise :class:`~bt_engine.watchdog.TickOverrun` if the watchdog asked to stop."""
        if self.stop_reason is not None:
            raise TickOverrun(self.stop_reason)

    def log(self, message: str) -> None:
        """Record a message from a node (shown by the runner, written to the tick log)."""
        self.messages.append(message)
        if self.echo is not None:
            self.echo(message)


_LITERAL, _REF = 0, 1


class BTNode(py_trees.behaviour.Behaviour):
    """Base of all btrun nodes. Subclasses implement :meth:`tick_impl` (and :meth:`halt`)."""

    bt_id: ClassVar[str] = ""
    kind: ClassVar[str] = "Action"
    ports: ClassVar[tuple[Port, ...]] = ()
    aliases: ClassVar[tuple[str, ...]] = ()
    category: ClassVar[str] = ""
    #: a tick that returns RUNNING is an error (BehaviorTree.CPP's SyncActionNode)
    never_running: ClassVar[bool] = False

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name)
        self.bt_status: NodeStatus = IDLE
        self.ctx = ctx
        self.scope: Scope | None = None
        self.loc: Loc | None = None
        self.path = name
        self.uid = 0
        self.tick_count = 0  # calls of execute_tick (the watchdog tells a hung leaf by it)
        self._bindings: dict[str, tuple[int, Any]] = {}
        self._pre: list[tuple[int, Script]] | None = None
        self._post: dict[str, Script] | None = None
        self._changes: list[tuple[BTNode, NodeStatus, NodeStatus]] | None = None

    # -- status -------------------------------------------------------------------------
    def set_status(self, status: NodeStatus) -> None:
        """Set the BehaviorTree.CPP status (and the py_trees one)."""
        old = self.bt_status
        if status is not old:
            try:
                self.status = TO_PY_TREES[status]
            except (KeyError, TypeError):  # a leaf that returned True, None, "SUCCESS" ...
                raise NodeRuntimeError(
                    self,
                    f"returned {status!r:.40}: a node returns SUCCESS, FAILURE or RUNNING "
                    "(bt_engine's NodeStatus)",
                ) from None
            self.bt_status = status
            changes = self._changes
            if changes is not None:
                changes.append((self, old, status))
                if len(changes) > CHANGE_LIMIT:  # a loop inside one tick: stay bounded
                    compact_changes(changes)

    def reset_status(self) -> None:
        """Back to IDLE (BehaviorTree.CPP ``resetStatus``)."""
        self.set_status(IDLE)

    # -- ticking ------------------------------------------------------------------------
    def execute_tick(self) -> NodeStatus:
        """Tick this node once, with pre/post-conditions, and return its new status."""
        self.tick_count += 1
        pre = self._pre
        try:
            if pre is not None:
                new = self._check_pre_conditions(pre)
                if new is None:
                    new = self.tick_impl()
            else:
                new = self.tick_impl()
        except Exception as exc:  # a plug-in's code: where in it (the reason names it)
            if not isinstance(exc, NodeRuntimeError):
                checks.note_raised_at(exc, type(self))
            raise
        if new is IDLE or (new is RUNNING and self.never_running):  # as BehaviorTree.CPP
            raise NodeRuntimeError(
                self, checks.IDLE_RETURNED if new is IDLE else checks.SYNC_RUNNING
            )
        if self._post is not None and (new is SUCCESS or new is FAILURE):
            self._run_post(new)
        # BT.CPP keeps the previous status (usually IDLE) of a skipped node; only the parent sees SKIPPED.
        if new is not SKIPPED:
            self.set_status(new)
        return new

    def tick_impl(self) -> NodeStatus:
        """The node's own work for one tick; return its status. Subclasses override."""
        raise NotImplementedError(f"{type(self).__name__}.tick_impl")

    def halt(self) -> None:
        """Stop whatever the node is doing and go back to IDLE. Subclasses extend."""
        self.reset_status()

    def halt_node(self) -> None:
        """Halt, then run the ``_onHalted`` script (BehaviorTree.CPP ``haltNode``)."""
        self.halt()
        if self._post is not None and "_onHalted" in self._post:
            try:
                self._exec(self._post["_onHalted"])
            except Exception as exc:  # nothing that happens while halting may stop the halt
                if self.ctx is None:
                    raise
                msg = f"{self.describe()} ({self.loc}): _onHalted failed: {exc}"
                self.ctx.halt_errors.append(msg)
                self.ctx.log(msg)

    def _exec(self, script: Script) -> Any:
        return script.execute(self.scope, self.ctx.enums if self.ctx else None)

    def _check_pre_conditions(self, pre: list[tuple[int, Script]]) -> NodeStatus | None:
        st = self.bt_status
        for index, script in pre:
            if st is IDLE or st is SKIPPED:
                if _truthy(self._exec(script)):
                    if index == 0:
                        return FAILURE
                    if index == 1:
                        return SUCCESS
                    if index == 2:
                        return SKIPPED
                elif index == 3:
                    return SKIPPED
            elif st is RUNNING and index == 3:
                if not _truthy(self._exec(script)):
                    self.halt_node()
                    return SKIPPED
        return None

    def _run_post(self, status: NodeStatus) -> None:
        post = self._post
        if status is SUCCESS and "_onSuccess" in post:
            self._exec(post["_onSuccess"])
        elif status is FAILURE and "_onFailure" in post:
            self._exec(post["_onFailure"])
        if "_post" in post:
            self._exec(post["_post"])

    # py_trees compatibility: a btrun node can be ticked by py_trees machinery too.
    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        """py_trees generator API: tick with BehaviorTree.CPP semantics, yield self."""
        self.execute_tick()
        yield self

    def update(self) -> PTStatus:
        """py_trees API: one tick, as a py_trees status."""
        return TO_PY_TREES[self.execute_tick()]

    def stop(self, new_status: PTStatus = PTStatus.INVALID) -> None:
        """py_trees API: stopping a node halts it."""
        if self.bt_status is RUNNING:
            self.halt_node()

    # -- ports --------------------------------------------------------------------------
    def bind_literal(self, port: str, value: Any) -> None:
        """Bind ``port`` to an already converted literal value (used by the builder)."""
        self._bindings[port] = (_LITERAL, value)

    def bind_entry(self, port: str, key: str) -> None:
        """Bind ``port`` to the blackboard entry ``key`` (used by the builder)."""
        self._bindings[port] = (_REF, key)

    def port_decl(self, name: str) -> Port | None:
        """Return the declared port called ``name``."""
        for p in type(self).ports:
            if p.name == name:
                return p
        return None

    def has_input(self, name: str) -> bool:
        """True if the port is bound in the file or has a default."""
        if name in self._bindings:
            kind, key = self._bindings[name]
            return kind == _LITERAL or self.scope.has(key)
        p = self.port_decl(name)
        return p is not None and p.default is not NO_DEFAULT

    def get_input(self, name: str, *, ranged: bool = True) -> Any:
        """Return the value of input port ``name`` converted to its declared type.

        Raises :class:`NodeRuntimeError` (located) if a referenced entry is missing or its
        value does not convert, :class:`PortRangeError` if a blackboard value is outside the
        port's range (``ranged=False``: not checked; the pre-flight checks say it their way).
        """
        b = self._bindings.get(name)
        if b is None:
            p = self.port_decl(name)
            if p is None:
                names = ", ".join(q.name for q in type(self).ports) or "none"
                raise NodeRuntimeError(
                    self, f"input port '{name}' is not declared by this node (its ports: {names})"
                )
            if p.default is NO_DEFAULT:
                raise NodeRuntimeError(self, f"input port '{name}' has no value")
            return p.type.convert(p.default) if p.default is not None else None
        kind, val = b
        if kind == _LITERAL:
            return val
        try:
            value = self.scope.get(val)
        except KeyError:
            raise NodeRuntimeError(
                self, f"input port '{name}' reads blackboard entry {{{val}}}, which is not set"
            ) from None
        p = self.port_decl(name)
        if p is not None and p.type is not ANY and p.type is not STRING and value is not None:
            try:
                converted = p.type.convert(value)
            except PortValueError as exc:
                raise NodeRuntimeError(self, f"input port '{name}' from {{{val}}}: {exc}") from None
            ranges = ranged and (p.low is not None or p.high is not None)
            outside = p.out_of_range(converted) if ranges else None
            if outside is not None:  # a value written in flight: the range a literal has too
                raise PortRangeError(self, f"input port '{name}' from {{{val}}}: {outside}")
            return converted
        return value

    def set_output(self, name: str, value: Any) -> bool:
        """Write output port ``name`` if the mission bound it; return True if written.
        A plug-in's node (a class outside btrun's own packages) raises
        :class:`NodeRuntimeError` (located) for a port it does not declare: a misspelt
        output name had dropped the value without a word. (btrun's own leaves share writes
        between kinds, e.g. every motion's ``distance_to_go``, and declare what they show.)"""
        b = self._bindings.get(name)
        if b is None or b[0] != _REF:
            if b is None and self.port_decl(name) is None and _plugin_class(type(self)):
                names = ", ".join(q.name for q in type(self).ports) or "none"
                raise NodeRuntimeError(
                    self, f"output port '{name}' is not declared by this node (its ports: {names})"
                )
            return False
        self.scope.set(b[1], value)
        return True

    def input_entry(self, name: str) -> str | None:
        """The blackboard entry an input port reads, or None (a literal or its default)."""
        b = self._bindings.get(name)
        return b[1] if b is not None and b[0] == _REF else None

    def output_key(self, name: str) -> str | None:
        """The blackboard entry an output port is bound to, or None."""
        b = self._bindings.get(name)
        return b[1] if b is not None and b[0] == _REF else None

    # -- helpers ------------------------------------------------------------------------
    def now(self) -> float:
        """Mission time in seconds from the injected clock."""
        return self.ctx.clock.now()

    def emit_wake_up(self) -> None:
        """Ask for another root tick right away (BehaviorTree.CPP ``emitWakeUpSignal``)."""
        if self.ctx is not None:
            self.ctx.woken = True

    def describe(self) -> str:
        """``ID 'name'`` for messages."""
        return self.bt_id if self.name == self.bt_id else f"{self.bt_id} '{self.name}'"


def _truthy(value: Any) -> bool:
    if isinstance(value, str):
        low = value.strip().lower()
        if low in ("false", "0", ""):
            return False
        return True
    return bool(value)


class ControlNode(BTNode):
    """A node with one or more children."""

    kind = "Control"

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.children: list[BTNode] = []

    def add_child(self, child: BTNode) -> None:
        """Append a child (builder use)."""
        child.parent = self
        self.children.append(child)

    def halt_child(self, index: int) -> None:
        """Halt child ``index`` if running, then reset it to IDLE."""
        child = self.children[index]
        if child.bt_status is RUNNING:
            child.halt_node()
        child.reset_status()

    def reset_children(self) -> None:
        """Halt every running child and reset all to IDLE."""
        for child in self.children:
            if child.bt_status is RUNNING:
                child.halt_node()
            child.reset_status()

    def halt(self) -> None:
        self.reset_children()
        self.reset_status()


class DecoratorNode(BTNode):
    """A node with exactly one child."""

    kind = "Decorator"

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.children: list[BTNode] = []

    def add_child(self, child: BTNode) -> None:
        """Set the child (builder use)."""
        child.parent = self
        self.children = [child]

    @property
    def child(self) -> BTNode:
        """The decorated child."""
        return self.children[0]

    def halt_child(self) -> None:
        """Halt the child if running, then reset it to IDLE."""
        child = self.children[0]
        if child.bt_status is RUNNING:
            child.halt_node()
        child.reset_status()

    def halt(self) -> None:
        self.halt_child()
        self.reset_status()


class LeafNode(BTNode):
    """A node without children."""

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.children = []


class SyncActionNode(LeafNode):
    """An action that finishes within one tick: :meth:`tick_impl` returns SUCCESS or FAILURE
    (RUNNING is an error of that tick, as in BehaviorTree.CPP)."""

    kind = "Action"
    never_running = True


class ConditionNode(LeafNode):
    """A check: implement :meth:`check` returning True (SUCCESS) or False (FAILURE)."""

    kind = "Condition"

    def check(self) -> bool:
        """Return True if the condition holds (anything but True or False is an error)."""
        raise NotImplementedError

    def tick_impl(self) -> NodeStatus:
        value = self.check()
        held = value if value is True or value is False else checks.check_result(value)
        if held is None:  # "no", 1, None...: an error, not whatever Python finds true
            raise NodeRuntimeError(self, checks.check_said(value))
        return SUCCESS if held else FAILURE


#: btrun's own packages: a node class defined elsewhere is a plug-in's
OWN_PACKAGES = frozenset(("bt_engine", "nodes", "drivers", "perception"))


def _plugin_class(cls: type) -> bool:
    """Whether node class ``cls`` is a plug-in's (defined outside btrun's own packages)."""
    return str(getattr(cls, "__module__", "")).partition(".")[0] not in OWN_PACKAGES


def unimplemented(cls: type) -> str | None:
    """What a leaf class lacks that its kind of node calls (``on_running`` of a
    :class:`StatefulActionNode`, ``check`` of a :class:`ConditionNode`), said as the
    registry refuses it; None when nothing is missing. A class that ticks its own way
    (overrides ``tick_impl``) lacks nothing."""
    if issubclass(cls, StatefulActionNode) and cls.tick_impl is StatefulActionNode.tick_impl:
        if cls.on_start is StatefulActionNode.on_start:
            return "does not define on_start: a StatefulActionNode calls it on its first tick"
    if issubclass(cls, ConditionNode) and cls.tick_impl is ConditionNode.tick_impl:
        if cls.check is ConditionNode.check:
            return "does not define check: a ConditionNode returns what check() returns"
    return None


class StatefulActionNode(LeafNode):
    """An action that may take many ticks (BehaviorTree.CPP ``StatefulActionNode``).

    On the first tick :meth:`on_start` runs; while RUNNING each tick calls :meth:`on_running`;
    a parent halting the node calls :meth:`on_halted`.
    """

    kind = "Action"

    def on_start(self) -> NodeStatus:
        """Start the action; return RUNNING, SUCCESS or FAILURE."""
        raise NotImplementedError

    def on_running(self) -> NodeStatus:
        """Continue the action; return RUNNING, SUCCESS or FAILURE."""
        raise NodeRuntimeError(  # it had been an empty NotImplementedError, in the air
            self,
            f"{type(self).__name__} returned RUNNING but does not define on_running (called "
            "on every tick while it is RUNNING)",
        )

    def on_halted(self) -> None:  # noqa: B027 - optional hook
        """Clean up when a parent halts the running action."""

    def tick_impl(self) -> NodeStatus:
        prev = self.bt_status
        if prev is IDLE:
            return self.on_start()
        if prev is RUNNING:
            return self.on_running()
        return prev

    def halt(self) -> None:
        try:
            if self.bt_status is RUNNING:
                self.on_halted()
        finally:  # an on_halted that raised (stopped by the watchdog) is not called again
            self.reset_status()
