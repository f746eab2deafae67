"""BehaviorTree.CPP v4's ``Switch2`` .. ``Switch6`` (``controls/switch_node.h``), tick for tick.

``SwitchN`` has ``N`` cases and ``N + 1`` children, the last the default. Per tick it reads
``variable`` and the ``case_k`` ports as text and ticks the child of the first case that
matches (:func:`check_string_equality`, BehaviorTree.CPP 4.8's ``CheckStringEquality``), else
the default. A missing ``variable`` (not given, or an entry that does not exist) selects the
default; a missing case never matches.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

from bt_engine.node import RUNNING, SKIPPED, ControlNode, MissionContext, NodeStatus
from bt_engine.ports import STRING, input_port
from bt_engine.registry import REGISTRY

CATEGORY = "built-in"

#: BehaviorTree.CPP 4.8 as built in behaviortreepy compares numbers with ``std::stoi`` and
#: ``std::stod`` (its ``<charconv>`` branch is not compiled in): C ``strtol`` / ``strtod``
#: on a leading part of the text, which may start with white space and a sign; the rest of
#: the text is ignored (``"2abc"`` reads as 2)
_SPACE_SIGN = r"[ \t\n\v\f\r]*([-+]?)"
_INT_PREFIX = re.compile(_SPACE_SIGN + r"([0-9]+)", re.ASCII)
_HEX_PREFIX = re.compile(
    _SPACE_SIGN + r"(0[xX](?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][-+]?[0-9]+)?)",
    re.ASCII,
)
_REAL_PREFIX = re.compile(
    _SPACE_SIGN
    + r"((?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?)",
    re.ASCII | re.IGNORECASE,
)
_INT_MIN, _INT_MAX = -(2**31), 2**31 - 1  # std::stoi: a C++ int, else out_of_range
_FLT_EPSILON = 1.1920928955078125e-07  # double(std::numeric_limits<float>::epsilon())
_DBL_MIN = 2.2250738585072014e-308  # below it strtod reports ERANGE: std::stod throws


def _to_int(text: str, enums: Mapping[str, int] | None) -> int | None:
    """``ToInt`` of CheckStringEquality: an enum name, else ``std::stoi``; None if it throws."""
    if enums and text in enums:
        return int(enums[text])
    m = _INT_PREFIX.match(text)
    if m is None:
        return None
    value = int(m.group(2)) * (-1 if m.group(1) == "-" else 1)
    return value if _INT_MIN <= value <= _INT_MAX else None


def _to_real(text: str) -> float | None:
    """``ToReal`` of CheckStringEquality: ``std::stod``; None if it throws (no number, or
    ``strtod`` reports ERANGE: overflow, or underflow below the smallest normal double)."""
    m = _HEX_PREFIX.match(text)
    if m is not None:
        body = m.group(2)
        digits = body[2:].lower().split("p")[0]
        value = float.fromhex(body if "p" in body.lower() else body + "p0")
    else:
        m = _REAL_PREFIX.match(text)
        if m is None:
            return None
        body = m.group(2)
        if body[:1] in "nN":
            return math.nan
        if body[:1] in "iI":
            return -math.inf if m.group(1) == "-" else math.inf
        digits = re.split("[eE]", body)[0]
        value = float(body)
    if math.isinf(value) or abs(value) < _DBL_MIN and any(c not in "0." for c in digits):
        return None
    return -value if m.group(1) == "-" else value


def check_string_equality(a: str, b: str, enums: Mapping[str, int] | None = None) -> bool:
    """BehaviorTree.CPP 4.8's ``details::CheckStringEquality``: equal texts; else both read
    as ints (an enum name, or a leading decimal int; the rest of the text is ignored) and
    equal; else both read as doubles (likewise) within ``float`` epsilon."""
    if a == b:
        return True
    ia, ib = _to_int(a, enums), _to_int(b, enums)
    if ia is not None and ib is not None and ia == ib:
        return True
    ra, rb = _to_real(a), _to_real(b)
    return ra is not None and rb is not None and abs(ra - rb) <= _FLT_EPSILON


def port_text(value: Any) -> str | None:
    """A blackboard value read by a ``std::string`` port, as BehaviorTree.CPP converts it
    (``Any::convert<std::string>``): text as is, whole numbers and booleans in decimal,
    doubles as ``std::to_string`` (``%f``); None for anything else (the read fails)."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "%f" % value  # noqa: UP031 - std::to_string(double)
    return None


class SwitchNode(ControlNode):
    """Base of ``Switch2`` .. ``Switch6``; a subclass sets ``cases`` and its ports."""

    cases = 0

    def __init__(self, name: str, ctx: MissionContext | None = None) -> None:
        super().__init__(name, ctx)
        self.running_child = -1

    def _text(self, port: str) -> str | None:
        """The port as text, None if it has no value (BT.CPP's ``getInput`` failing)."""
        entry = self.input_entry(port)
        if entry is None:
            return self.get_input(port)
        if not self.scope.has(entry):
            return None
        return port_text(self.scope.get(entry))

    def tick_impl(self) -> NodeStatus:
        match = self.cases  # the default
        variable = self._text("variable")
        if variable is not None:
            enums = self.ctx.enums if self.ctx is not None else None
            for index in range(self.cases):
                value = self._text(f"case_{index + 1}")
                if value is not None and check_string_equality(variable, value, enums):
                    match = index
                    break
        if self.running_child != -1 and self.running_child != match:
            self.halt_child(self.running_child)
        status = self.children[match].execute_tick()
        if status is SKIPPED:
            self.running_child = -1
            return SKIPPED
        if status is RUNNING:
            self.running_child = match
        else:
            self.reset_children()
            self.running_child = -1
        return status

    def halt(self) -> None:
        self.running_child = -1
        super().halt()


def _switch(n: int) -> type[SwitchNode]:
    cases = " ".join(f'case_{k}="..."' for k in range(1, n + 1))
    doc = f"""Tick the child of the first case equal to ``variable``, else the last child.

    {n} cases, {n + 1} children (the last is the default). Per tick ``variable`` is compared
    with ``case_1`` .. ``case_{n}`` in order: equal as text, or as numbers (the leading
    number of each text; an enum name counts as its value), as BehaviorTree.CPP 4.8 does.
    The matching child is ticked and its status returned; a different child that was
    RUNNING is halted first. ``variable`` unset (or an entry that does not exist) selects
    the default::

        Switch{n} variable="{{mode}}" {cases}
        ├── ...  (one per case)
        └── ...  (default)
    """
    ports = (
        input_port("variable", STRING, None, "the value to match (text; {entry} to read one)"),
        *(
            input_port(f"case_{k}", STRING, None, f"value that selects child {k}")
            for k in range(1, n + 1)
        ),
    )
    return type(
        f"Switch{n}",
        (SwitchNode,),
        {
            "__doc__": doc,
            "__module__": __name__,
            "bt_id": f"Switch{n}",
            "category": CATEGORY,
            "cases": n,
            "children_range": (n + 1, n + 1),
            "ports": ports,
        },
    )


Switch2, Switch3, Switch4, Switch5, Switch6 = (_switch(n) for n in range(2, 7))

for _cls in (Switch2, Switch3, Switch4, Switch5, Switch6):
    REGISTRY.register(_cls)
