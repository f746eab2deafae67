"""Built-in control nodes with BehaviorTree.CPP v4 semantics, tick for tick.

Each class documents what it does per tick. ``tests/test_differential_btcpp.py`` checks every
one against BehaviorTree.CPP itself (through ``behaviortreepy``) on random trees.

Note on "wake-up": in a BehaviorTree.CPP tree built by its factory every node has a wake-up
signal, so ``SequenceWithMemory`` (and ``Repeat``) hand control back (return RUNNING) after a
child that went from IDLE to SUCCESS within one tick, when more children remain. A plain
``Sequence`` does not. btrun reproduces this so that files behave the same in both engines.
"""

from __future__ import annotations

from bt_engine import async_controls, switch  # noqa: F401  (register their built-ins too)
from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    ControlNode,
    NodeRuntimeError,
    NodeStatus,
)
from bt_engine.ports import INT, input_port
from bt_engine.registry import REGISTRY
from bt_engine.spec import plural

CATEGORY = "built-in"


class Sequence(ControlNode):
    """Tick children in order; fail as soon as one fails.

    Per tick: resume at the child that was RUNNING. A RUNNING child makes the Sequence
    RUNNING; a FAILURE halts all children and makes it FAILURE (the next tick restarts from
    the first child); when every child has succeeded (or was SKIPPED) it returns SUCCESS
    (SKIPPED if all were skipped)::

        Sequence
        ├── TakeOff
        ├── GoTo
        └── Land
    """

    bt_id = "Sequence"
    category = CATEGORY

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.current = 0
        self.skipped = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        st = self.bt_status
        if st is IDLE or st is SKIPPED:
            self.skipped = 0
        self.set_status(RUNNING)
        while self.current < n:
            child_status = children[self.current].execute_tick()
            if child_status is RUNNING:
                return RUNNING
            if child_status is FAILURE:
                self.reset_children()
                self.current = 0
                return FAILURE
            if child_status is SKIPPED:
                self.skipped += 1
            self.current += 1
        all_skipped = self.skipped == n
        self.reset_children()
        self.current = 0
        self.skipped = 0
        return SKIPPED if all_skipped else SUCCESS

    def halt(self) -> None:
        self.current = 0
        super().halt()


class SequenceWithMemory(ControlNode):
    """Like Sequence, but a failure does not restart it: the next tick retries the failed child.

    Per tick: resume at the current child. RUNNING -> RUNNING. FAILURE -> halt the current and
    later children, return FAILURE, keep the index. SUCCESS -> next child; if that child went
    from IDLE to SUCCESS in this tick and more remain, return RUNNING (BehaviorTree.CPP's
    wake-up). All done -> SUCCESS (SKIPPED if all skipped). Alias: ``SequenceStar`` (v3).
    """

    bt_id = "SequenceWithMemory"
    aliases = ("SequenceStar",)
    category = CATEGORY

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.current = 0
        self.skipped = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        st = self.bt_status
        if st is IDLE or st is SKIPPED:
            self.skipped = 0
        self.set_status(RUNNING)
        while self.current < n:
            child = children[self.current]
            prev = child.bt_status
            child_status = child.execute_tick()
            if child_status is RUNNING:
                return RUNNING
            if child_status is FAILURE:
                for i in range(self.current, n):
                    self.halt_child(i)
                return FAILURE
            if child_status is SUCCESS:
                self.current += 1
                if prev is IDLE and self.current < n:
                    self.emit_wake_up()
                    return RUNNING
            else:
                self.current += 1
                self.skipped += 1
        all_skipped = self.skipped == n
        self.reset_children()
        self.current = 0
        self.skipped = 0
        return SKIPPED if all_skipped else SUCCESS


class ReactiveSequence(ControlNode):
    """Re-check every child from the first on every tick; at most one may be RUNNING.

    Per tick: tick children in order. FAILURE -> halt all, FAILURE. RUNNING -> halt every
    other child, RUNNING. SUCCESS -> go on. All succeeded -> SUCCESS (SKIPPED if all were).
    Use it to guard an action with conditions that must keep holding::

        ReactiveSequence
        ├── BatteryAbove percent=20
        └── GoTo
    """

    bt_id = "ReactiveSequence"
    category = CATEGORY
    #: BT.CPP >= 4.6 no longer throws when a second child returns RUNNING (EnableException)
    throw_if_multiple_running = False

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.running_child = -1

    def tick_impl(self) -> NodeStatus:
        return _reactive_tick(self, stop_on=FAILURE, finish=SUCCESS)


class ReactiveFallback(ControlNode):
    """Re-check every child from the first on every tick until one succeeds.

    Per tick: SUCCESS -> halt all, SUCCESS. RUNNING -> halt every other child, RUNNING.
    FAILURE -> try the next. All failed -> FAILURE (SKIPPED if all were skipped).
    """

    bt_id = "ReactiveFallback"
    category = CATEGORY
    #: BT.CPP >= 4.6 no longer throws when a second child returns RUNNING (EnableException)
    throw_if_multiple_running = False

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.running_child = -1

    def tick_impl(self) -> NodeStatus:
        return _reactive_tick(self, stop_on=SUCCESS, finish=FAILURE)


def _reactive_tick(node, stop_on: NodeStatus, finish: NodeStatus) -> NodeStatus:
    all_skipped = True
    if node.bt_status is IDLE:
        node.running_child = -1
    node.set_status(RUNNING)
    children = node.children
    for index, child in enumerate(children):
        child_status = child.execute_tick()
        if child_status is not SKIPPED:
            all_skipped = False
        if child_status is RUNNING:
            for i in range(len(children)):
                if i != index:
                    node.halt_child(i)
            if node.running_child == -1:
                node.running_child = index
            elif node.throw_if_multiple_running and node.running_child != index:
                raise NodeRuntimeError(
                    node, "only a single child can return RUNNING (BehaviorTree.CPP rule)"
                )
            return RUNNING
        if child_status is stop_on:
            node.reset_children()
            return stop_on
        if child_status is SKIPPED:
            node.halt_child(index)
    node.reset_children()
    return SKIPPED if all_skipped else finish


class Fallback(ControlNode):
    """Try children in order until one succeeds (a "selector").

    Per tick: resume at the RUNNING child. SUCCESS -> halt all, SUCCESS (restart next time).
    FAILURE -> next child. All failed -> FAILURE (SKIPPED if all were skipped).
    """

    bt_id = "Fallback"
    category = CATEGORY

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.current = 0
        self.skipped = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        st = self.bt_status
        if st is IDLE or st is SKIPPED:
            self.skipped = 0
        self.set_status(RUNNING)
        while self.current < n:
            child_status = children[self.current].execute_tick()
            if child_status is RUNNING:
                return RUNNING
            if child_status is SUCCESS:
                self.reset_children()
                self.current = 0
                return SUCCESS
            if child_status is SKIPPED:
                self.skipped += 1
            self.current += 1
        all_skipped = self.skipped == n
        self.reset_children()
        self.current = 0
        self.skipped = 0
        return SKIPPED if all_skipped else FAILURE

    def halt(self) -> None:
        self.current = 0
        super().halt()


def _threshold(value: int, n: int) -> int:
    return max(n + value + 1, 0) if value < 0 else value


class Parallel(ControlNode):
    """Tick all unfinished children every tick; succeed or fail by counting results.

    ``success_count`` children must succeed (negative counts from the number of children,
    -1 = all) and ``failure_count`` failures make it fail (default 1). When it finishes, the
    still-running children are halted. Use it to run a detector while the drone scans::

        Parallel success_count=1
        ├── ScanLine
        └── DetectBlocks
    """

    bt_id = "Parallel"
    category = CATEGORY
    ports = (
        input_port("success_count", INT, -1, "children that must succeed (-1: all)"),
        input_port("failure_count", INT, 1, "failures that make the node fail (-1: all)"),
    )

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.completed: set[int] = set()
        self.successes = 0
        self.failures = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        s_raw = self.get_input("success_count")
        f_raw = self.get_input("failure_count")
        need_success = _threshold(s_raw, n)
        need_failure = _threshold(f_raw, n)
        if n < need_success:
            raise NodeRuntimeError(
                self, f"success_count={s_raw} but only {plural(n, 'child', 'children')}"
            )
        if n < need_failure:
            raise NodeRuntimeError(
                self, f"failure_count={f_raw} but only {plural(n, 'child', 'children')}"
            )
        self.set_status(RUNNING)
        skipped = 0
        for i, child in enumerate(children):
            if i not in self.completed:
                child_status = child.execute_tick()
                if child_status is SKIPPED:
                    skipped += 1
                elif child_status is SUCCESS:
                    self.completed.add(i)
                    self.successes += 1
                elif child_status is FAILURE:
                    self.completed.add(i)
                    self.failures += 1
            if self.successes >= need_success or (
                s_raw < 0 and self.successes + skipped >= need_success
            ):
                self._clear()
                self.reset_children()
                return SUCCESS
            if n - self.failures < need_success or self.failures == need_failure:
                self._clear()
                self.reset_children()
                return FAILURE
        return SKIPPED if skipped == n else RUNNING

    def _clear(self) -> None:
        self.completed.clear()
        self.successes = 0
        self.failures = 0

    def halt(self) -> None:
        self._clear()
        super().halt()


class ParallelAll(ControlNode):
    """Tick all children until every one has finished; fail if ``max_failures`` failed.

    Per tick: tick each unfinished child. When all are done, SUCCESS unless at least
    ``max_failures`` failed (negative counts from the number of children).
    """

    bt_id = "ParallelAll"
    category = CATEGORY
    ports = (input_port("max_failures", INT, 1, "failures that make the node fail"),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.completed: set[int] = set()
        self.failures = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        threshold = _threshold(self.get_input("max_failures"), n)
        if n < threshold:
            raise NodeRuntimeError(
                self, f"max_failures={threshold} but only {plural(n, 'child', 'children')}"
            )
        self.set_status(RUNNING)
        skipped = 0
        for i, child in enumerate(children):
            if i in self.completed:
                continue
            child_status = child.execute_tick()
            if child_status is SUCCESS:
                self.completed.add(i)
            elif child_status is FAILURE:
                self.completed.add(i)
                self.failures += 1
            elif child_status is SKIPPED:
                skipped += 1
        if skipped == n:
            return SKIPPED
        if skipped + len(self.completed) >= n:
            self.reset_children()
            self.completed.clear()
            status = FAILURE if self.failures >= threshold else SUCCESS
            self.failures = 0
            return status
        return RUNNING

    def halt(self) -> None:
        self.completed.clear()
        self.failures = 0
        super().halt()


class IfThenElse(ControlNode):
    """``IfThenElse(condition, then, [else])``: tick the condition once, then one branch.

    The condition may be RUNNING. SUCCESS -> tick ``then``; FAILURE -> tick ``else`` (or
    return FAILURE when there are only two children). The branch's result is returned.
    """

    bt_id = "IfThenElse"
    category = CATEGORY
    children_range = (2, 3)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.branch = 0

    def tick_impl(self) -> NodeStatus:
        children = self.children
        self.set_status(RUNNING)
        if self.branch == 0:
            cond = children[0].execute_tick()
            if cond is RUNNING:
                return RUNNING
            if cond is SUCCESS:
                self.branch = 1
            elif cond is FAILURE:
                if len(children) == 3:
                    self.branch = 2
                else:
                    return FAILURE
        if self.branch > 0:
            status = children[self.branch].execute_tick()
            if status is RUNNING:
                return RUNNING
            self.reset_children()
            self.branch = 0
            return status
        raise NodeRuntimeError(self, "the condition child returned SKIPPED")

    def halt(self) -> None:
        self.branch = 0
        super().halt()


class WhileDoElse(ControlNode):
    """``WhileDoElse(condition, do, [else])``: re-check the condition every tick.

    Condition SUCCESS -> halt ``else``, tick ``do``; FAILURE -> halt ``do``, tick ``else``
    (or FAILURE with two children). A switching condition halts the running branch.
    """

    bt_id = "WhileDoElse"
    category = CATEGORY
    children_range = (2, 3)

    def tick_impl(self) -> NodeStatus:
        children = self.children
        n = len(children)
        self.set_status(RUNNING)
        cond = children[0].execute_tick()
        if cond is RUNNING:
            return RUNNING
        status = IDLE
        if cond is SUCCESS:
            if n == 3:
                self.halt_child(2)
            status = children[1].execute_tick()
        elif cond is FAILURE:
            if n == 3:
                self.halt_child(1)
                status = children[2].execute_tick()
            else:
                status = FAILURE
        if status is RUNNING:
            return RUNNING
        self.reset_children()
        if status is IDLE:
            raise NodeRuntimeError(self, "the condition child returned SKIPPED")
        return status


for _cls in (
    Sequence,
    SequenceWithMemory,
    ReactiveSequence,
    ReactiveFallback,
    Fallback,
    Parallel,
    ParallelAll,
    IfThenElse,
    WhileDoElse,
):
    REGISTRY.register(_cls)
