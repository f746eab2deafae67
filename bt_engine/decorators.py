"""Built-in decorators with BehaviorTree.CPP v4 semantics, and the SubTree node.

Time-based decorators (``Timeout``, ``Delay``) read the mission clock injected into the
mission context, never ``time.*``: on the simulated clock they are exact and deterministic.
"""

from __future__ import annotations

from bt_engine import entry_updated, precondition  # noqa: F401  (register their built-ins)
from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    DecoratorNode,
    NodeStatus,
)
from bt_engine.ports import BOOL, INT, input_port
from bt_engine.registry import REGISTRY

CATEGORY = "built-in"
TIME_EPS = 1e-9  # mission-time comparison tolerance


class Inverter(DecoratorNode):
    """Swap the child's SUCCESS and FAILURE; RUNNING and SKIPPED pass through."""

    bt_id = "Inverter"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is SUCCESS:
            self.halt_child()
            return FAILURE
        if st is FAILURE:
            self.halt_child()
            return SUCCESS
        return st


class ForceSuccess(DecoratorNode):
    """Return SUCCESS whenever the child finishes (SUCCESS or FAILURE)."""

    bt_id = "ForceSuccess"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.halt_child()
            return SUCCESS
        return st


class ForceFailure(DecoratorNode):
    """Return FAILURE whenever the child finishes (SUCCESS or FAILURE)."""

    bt_id = "ForceFailure"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.halt_child()
            return FAILURE
        return st


class Repeat(DecoratorNode):
    """Run the child ``num_cycles`` times in a row (-1: forever) while it succeeds.

    A child FAILURE makes the Repeat fail at once. After a child that finished within the
    tick it started, the Repeat returns RUNNING before the next cycle (BehaviorTree.CPP's
    wake-up), so a Repeat never spins inside one tick.
    """

    bt_id = "Repeat"
    category = CATEGORY
    ports = (input_port("num_cycles", INT, description="repetitions (-1: forever)", low=-1),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.count = 0

    def tick_impl(self) -> NodeStatus:
        cycles = self.get_input("num_cycles")
        do_loop = self.count < cycles or cycles == -1
        self.set_status(RUNNING)
        child = self.children[0]
        while do_loop:
            if self.ctx is not None and self.ctx.stop_reason is not None:
                self.ctx.check_stop()  # the watchdog: this tick has run too long
            prev = child.bt_status
            st = child.execute_tick()
            if st is SUCCESS:
                self.count += 1
                do_loop = self.count < cycles or cycles == -1
                self.halt_child()
                if prev is IDLE and do_loop:
                    self.emit_wake_up()
                    return RUNNING
            elif st is FAILURE:
                self.count = 0
                self.halt_child()
                return FAILURE
            elif st is RUNNING:
                return RUNNING
            else:
                self.halt_child()
                return SKIPPED
        self.count = 0
        return SUCCESS

    def halt(self) -> None:
        self.count = 0
        super().halt()


class RetryUntilSuccessful(DecoratorNode):
    """Retry a failing child up to ``num_attempts`` times (-1: forever).

    SUCCESS ends it with SUCCESS; after the last failed attempt it returns FAILURE.
    Alias: ``RetryUntilSuccesful`` (the historical BehaviorTree.CPP spelling).
    """

    bt_id = "RetryUntilSuccessful"
    aliases = ("RetryUntilSuccesful",)
    category = CATEGORY
    ports = (input_port("num_attempts", INT, description="attempts (-1: forever)", low=-1),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.tries = 0

    def tick_impl(self) -> NodeStatus:
        attempts = self.get_input("num_attempts")
        do_loop = self.tries < attempts or attempts == -1
        self.set_status(RUNNING)
        child = self.children[0]
        while do_loop:
            if self.ctx is not None and self.ctx.stop_reason is not None:
                self.ctx.check_stop()  # the watchdog: this tick has run too long
            prev = child.bt_status
            st = child.execute_tick()
            if st is SUCCESS:
                self.tries = 0
                self.halt_child()
                return SUCCESS
            if st is FAILURE:
                self.tries += 1
                do_loop = self.tries < attempts or attempts == -1
                self.halt_child()
                if prev is IDLE and do_loop:
                    self.emit_wake_up()
                    return RUNNING
            elif st is RUNNING:
                return RUNNING
            else:
                self.halt_child()
                return SKIPPED
        self.tries = 0
        return FAILURE

    def halt(self) -> None:
        self.tries = 0
        super().halt()


class Timeout(DecoratorNode):
    """Fail (and halt the child) if the child is still RUNNING ``msec`` after it started.

    The deadline is measured on the mission clock from the first tick.
    """

    bt_id = "Timeout"
    category = CATEGORY
    ports = (input_port("msec", INT, description="time limit in milliseconds", low=0),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.started = False
        self.deadline = 0.0

    def tick_impl(self) -> NodeStatus:
        child = self.children[0]
        if not self.started:
            msec = self.get_input("msec")
            self.started = True
            self.set_status(RUNNING)
            self.deadline = self.now() + msec / 1000.0 if msec > 0 else float("inf")
        elif child.bt_status is RUNNING and self.now() >= self.deadline - TIME_EPS:
            self.halt_child()
            self.started = False
            # BT.CPP's timer halts the child and emits a wake-up: tickOnce then re-ticks the root
            self.emit_wake_up()
            return FAILURE
        st = child.execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.started = False
            self.halt_child()
        return st

    def halt(self) -> None:
        self.started = False
        super().halt()


class Delay(DecoratorNode):
    """Wait ``delay_msec`` on the mission clock, then tick the child (RUNNING meanwhile)."""

    bt_id = "Delay"
    category = CATEGORY
    ports = (input_port("delay_msec", INT, description="delay in milliseconds", low=0),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.started = False
        self.fired = False
        self.until = 0.0

    def tick_impl(self) -> NodeStatus:
        if not self.started:
            self.started = True
            self.set_status(RUNNING)
            self.until = self.now() + self.get_input("delay_msec") / 1000.0
            self.fired = self.now() >= self.until - TIME_EPS
            if self.fired:
                self.emit_wake_up()
            # BT.CPP's timer callback runs on another thread: the first tick returns RUNNING
            return RUNNING
        if not self.fired:
            if self.now() < self.until - TIME_EPS:
                return RUNNING
            # the delay is over: BT.CPP's timer emits a wake-up, so tickOnce re-ticks the root
            self.fired = True
            self.emit_wake_up()
        st = self.children[0].execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.started = False
            self.halt_child()
        return st

    def halt(self) -> None:
        self.started = False
        super().halt()


class RunOnce(DecoratorNode):
    """Tick the child until it finishes once; afterwards return SKIPPED (``then_skip``,
    default) or the status it finished with."""

    bt_id = "RunOnce"
    category = CATEGORY
    ports = (
        input_port(
            "then_skip", BOOL, True, "after the first run: SKIPPED (true) or repeat the result"
        ),
    )

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.done = False
        self.result = SUCCESS

    def tick_impl(self) -> NodeStatus:
        skip = self.get_input("then_skip")
        if self.done:
            return SKIPPED if skip else self.result
        self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.done = True
            self.result = st
            self.halt_child()
        return st


class KeepRunningUntilFailure(DecoratorNode):
    """Return RUNNING while the child succeeds; FAILURE once it fails."""

    bt_id = "KeepRunningUntilFailure"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is FAILURE:
            self.halt_child()
            return FAILURE
        if st is SUCCESS:
            self.halt_child()
            return RUNNING
        if st is RUNNING:
            return RUNNING
        return self.bt_status


class SubTree(DecoratorNode):
    """Run another ``<BehaviorTree>`` of the mission in its own blackboard scope.

    Ports are remapped: ``<SubTree ID="Scan" speed="{scan_speed}"/>`` makes the subtree's
    ``speed`` the parent's ``scan_speed``; ``_autoremap="true"`` shares every entry by name.
    """

    bt_id = "SubTree"
    kind = "SubTree"
    aliases = ("SubTreePlus",)
    category = CATEGORY

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.subtree_id = ""

    def tick_impl(self) -> NodeStatus:
        if self.bt_status is IDLE:
            self.set_status(RUNNING)
        st = self.children[0].execute_tick()
        if st is SUCCESS or st is FAILURE:
            self.halt_child()
        return st


for _cls in (
    Inverter,
    ForceSuccess,
    ForceFailure,
    Repeat,
    RetryUntilSuccessful,
    Timeout,
    Delay,
    RunOnce,
    KeepRunningUntilFailure,
    SubTree,
):
    REGISTRY.register(_cls)
