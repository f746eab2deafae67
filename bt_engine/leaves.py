"""Built-in leaves: AlwaysSuccess, AlwaysFailure, Sleep, SetBlackboard, UnsetBlackboard,
Script, ScriptCondition.

Scripts use the safe interpreter in :mod:`bt_engine.script` (no Python ``eval``).
"""

from __future__ import annotations

from bt_engine.node import (
    FAILURE,
    RUNNING,
    SUCCESS,
    ConditionNode,
    NodeRuntimeError,
    NodeStatus,
    StatefulActionNode,
    SyncActionNode,
    _truthy,
)
from bt_engine.ports import ANY, INT, STRING, blackboard_ref, input_port
from bt_engine.registry import REGISTRY
from bt_engine.script import ScriptError, parse_script

CATEGORY = "built-in"
#: tolerance when comparing mission times (so a 500 ms sleep at 10 Hz takes exactly 5 ticks)
TIME_EPS = 1e-9


class AlwaysSuccess(SyncActionNode):
    """Return SUCCESS."""

    bt_id = "AlwaysSuccess"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        return SUCCESS


class AlwaysFailure(SyncActionNode):
    """Return FAILURE."""

    bt_id = "AlwaysFailure"
    category = CATEGORY

    def tick_impl(self) -> NodeStatus:
        return FAILURE


class Sleep(StatefulActionNode):
    """RUNNING for ``msec`` milliseconds of mission time, then SUCCESS (0: SUCCESS at once)."""

    bt_id = "Sleep"
    category = CATEGORY
    ports = (input_port("msec", INT, description="how long, in milliseconds", low=0),)

    def __init__(self, name: str, ctx=None) -> None:
        super().__init__(name, ctx)
        self.until = 0.0

    def on_start(self) -> NodeStatus:
        msec = self.get_input("msec")
        if msec <= 0:
            return SUCCESS
        self.until = self.now() + msec / 1000.0
        return RUNNING

    def on_running(self) -> NodeStatus:
        if self.now() >= self.until - TIME_EPS:
            # BT.CPP's timer emits a wake-up when the time is up: tickOnce re-ticks the root
            self.emit_wake_up()
            return SUCCESS
        return RUNNING


class SetBlackboard(SyncActionNode):
    """Write ``value`` into the entry named by ``output_key`` (``key`` or ``{key}``).

    ``value`` may itself be ``{other}`` to copy another entry.
    """

    bt_id = "SetBlackboard"
    category = CATEGORY
    ports = (
        input_port("value", ANY, description="value to write (text, or {entry} to copy)"),
        input_port("output_key", STRING, description="name of the entry to write"),
    )

    def tick_impl(self) -> NodeStatus:
        key = self.get_input("output_key")
        key = blackboard_ref(key) or key
        self.scope.set(key, self.get_input("value"))
        return SUCCESS


class UnsetBlackboard(SyncActionNode):
    """Remove the entry ``key`` from this tree's blackboard; SUCCESS (also if it was not set).

    As BehaviorTree.CPP's ``Blackboard::unset``, only an entry of the node's own scope is
    removed: inside a SubTree, an entry reached through remapping or ``_autoremap``, and an
    ``@`` entry, are left as they are. ``key="{name}"`` removes the entry whose name the
    entry ``name`` holds.
    """

    bt_id = "UnsetBlackboard"
    category = CATEGORY
    ports = (input_port("key", STRING, description="Key of the entry to remove"),)

    def tick_impl(self) -> NodeStatus:
        self.scope.unset_local(self.get_input("key"))
        return SUCCESS


class _ScriptLeaf:
    """Shared by Script and ScriptCondition: the code is parsed once, at build time."""

    def _script(self):
        script = getattr(self, "_compiled", None)
        if script is None:
            code = self.get_input("code")
            try:
                script = parse_script(code)
            except ScriptError as exc:
                raise NodeRuntimeError(self, f"script {code!r}: {exc}") from None
            self._compiled = script
        return script

    def _run(self):
        try:
            return self._exec(self._script())
        except ScriptError as exc:
            raise NodeRuntimeError(self, f"script {self.get_input('code')!r}: {exc}") from None


class Script(_ScriptLeaf, SyncActionNode):
    """Run a script (``code``), e.g. ``count := count + 1; done := true``; SUCCESS."""

    bt_id = "Script"
    category = CATEGORY
    ports = (input_port("code", STRING, description="script to run"),)

    def tick_impl(self) -> NodeStatus:
        self._run()
        return SUCCESS


class ScriptCondition(_ScriptLeaf, ConditionNode):
    """SUCCESS if the script's value (``code``) is true, else FAILURE."""

    bt_id = "ScriptCondition"
    category = CATEGORY
    ports = (input_port("code", STRING, description="expression to test"),)

    def tick_impl(self) -> NodeStatus:
        return SUCCESS if _truthy(self._run()) else FAILURE


for _cls in (
    AlwaysSuccess,
    AlwaysFailure,
    Sleep,
    SetBlackboard,
    UnsetBlackboard,
    Script,
    ScriptCondition,
):
    REGISTRY.register(_cls)
