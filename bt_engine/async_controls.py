"""BehaviorTree.CPP v4's ``AsyncSequence`` and ``AsyncFallback``, tick for tick.

BehaviorTree.CPP registers them as its ``SequenceNode`` and ``FallbackNode`` built with
``make_async``: the same nodes as ``Sequence`` and ``Fallback``, except that after a child
that went from IDLE to SUCCESS (a Sequence) or FAILURE (a Fallback) within one tick, when
more children remain, they hand control back: emit a wake-up and return RUNNING, so the
next child starts at the next root tick (``Tree::tickOnce`` ticks the root again at once).
Other branches (a ReactiveSequence's conditions) are re-checked between two children.
"""

from __future__ import annotations

from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    ControlNode,
    MissionContext,
    NodeStatus,
)
from bt_engine.registry import REGISTRY

CATEGORY = "built-in"


class _AsyncChain(ControlNode):
    """The children in order until one returns ``stop`` (Sequence: FAILURE; Fallback:
    SUCCESS); a child that returned ``go_on`` from IDLE yields the tick (see the module)."""

    stop: NodeStatus = FAILURE
    go_on: NodeStatus = SUCCESS

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
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
            if child_status is self.stop:
                self.reset_children()
                self.current = 0
                return child_status
            self.current += 1
            if child_status is SKIPPED:
                self.skipped += 1
            elif prev is IDLE and self.current < n:
                self.emit_wake_up()
                return RUNNING
        all_skipped = self.skipped == n
        self.reset_children()
        self.current = 0
        self.skipped = 0
        return SKIPPED if all_skipped else self.go_on

    def halt(self) -> None:
        self.current = 0
        self.skipped = 0
        super().halt()


class AsyncSequence(_AsyncChain):
    """Like Sequence, but yields the tick after each child that succeeded at once.

    Per tick: resume at the current child. RUNNING -> RUNNING. FAILURE -> halt all, FAILURE
    (the next run restarts from the first child). SUCCESS -> next child, but if that child
    went from IDLE to SUCCESS within this tick and more remain, return RUNNING and ask for
    another root tick (BehaviorTree.CPP's wake-up: within one ``Mission.tick`` the tree is
    ticked again, so other branches are re-checked between two children). All succeeded ->
    SUCCESS (SKIPPED if all were skipped).
    """

    bt_id = "AsyncSequence"
    category = CATEGORY
    stop, go_on = FAILURE, SUCCESS


class AsyncFallback(_AsyncChain):
    """Like Fallback, but yields the tick after each child that failed at once.

    Per tick: resume at the current child. RUNNING -> RUNNING. SUCCESS -> halt all, SUCCESS.
    FAILURE -> next child, but if that child went from IDLE to FAILURE within this tick and
    more remain, return RUNNING and ask for another root tick (BehaviorTree.CPP's wake-up).
    All failed -> FAILURE (SKIPPED if all were skipped).
    """

    bt_id = "AsyncFallback"
    category = CATEGORY
    stop, go_on = SUCCESS, FAILURE


for _cls in (AsyncSequence, AsyncFallback):
    REGISTRY.register(_cls)
