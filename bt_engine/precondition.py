"""BehaviorTree.CPP v4's ``Precondition`` decorator (``decorators/script_precondition.h``).

Tick for tick as BehaviorTree.CPP 4.8: the ``if`` script is evaluated only while the child
is not running; true -> the child is ticked (and then ticked, unchecked, until it finishes);
false -> ``else`` is returned and the child is not ticked.
"""

from __future__ import annotations

from typing import Any

from bt_engine.loops import STATUS
from bt_engine.node import (
    FAILURE,
    SUCCESS,
    DecoratorNode,
    MissionContext,
    NodeRuntimeError,
    NodeStatus,
    _truthy,
)
from bt_engine.ports import PortValueError, StringType, input_port
from bt_engine.registry import REGISTRY
from bt_engine.script import ScriptError, constant_failure, parse_script

CATEGORY = "built-in"


class ScriptText(StringType):
    """Text that is a valid script: a literal is parsed when the file loads (a bad one is a
    located error, as BehaviorTree.CPP refuses it when the tree is created)."""

    expected = "a script"

    def convert(self, value: Any) -> str:
        text = super().convert(value)
        try:
            parse_script(text)
            failure = constant_failure(text)
            if failure is not None:
                raise failure
        except ScriptError as exc:
            where = f" at column {exc.column + 1}" if getattr(exc, "column", -1) >= 0 else ""
            message = getattr(exc, "message", None) or str(exc)
            raise PortValueError(f"bad script {text!r}: {message}{where}") from None
        return text


SCRIPT = ScriptText()


class Precondition(DecoratorNode):
    """Tick the child only if the script in port ``if`` is true; else return port ``else``.

    ``if`` is evaluated only when the child is not running: once it was true, the child is
    ticked until it finishes (SUCCESS or FAILURE, then the child is reset), whatever ``if``
    says meanwhile. Use ``_while`` (or a ReactiveSequence) to stop a running child. As in
    BehaviorTree.CPP 4.8, a halt does not clear this: after a halt while the child was
    running, the next tick runs the child again without checking ``if``::

        Precondition if="battery > 30" else="SKIPPED"
        └── ScanFace
    """

    bt_id = "Precondition"
    category = CATEGORY
    ports = (
        input_port("if", SCRIPT, description="script; the child is ticked when it is true"),
        input_port("else", STATUS, "FAILURE", "status returned when the condition is false"),
    )

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.children_running = False
        self._code: str | None = None
        self._script = None

    def tick_impl(self) -> NodeStatus:
        code = self.get_input("if")
        if code != self._code:
            try:
                self._script = parse_script(code)
            except ScriptError as exc:
                raise NodeRuntimeError(self, f"script {code!r}: {exc}") from None
            self._code = code
        otherwise = self.get_input("else")
        if not self.children_running:
            try:
                self.children_running = _truthy(self._exec(self._script))
            except ScriptError as exc:
                raise NodeRuntimeError(self, f"script {code!r}: {exc}") from None
            if not self.children_running:
                return otherwise
        status = self.children[0].execute_tick()
        if status is SUCCESS or status is FAILURE:
            self.halt_child()
            self.children_running = False
        return status


REGISTRY.register(Precondition)
