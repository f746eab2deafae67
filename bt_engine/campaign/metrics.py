"""A campaign's metrics: values read out of a run's ``summary.json``.

A metric is a *path* into the summary (``status``, ``mission_time_s``,
``blackboard.pallet_id``, ``perception.blocks[0]``, ``motions[kind=GoTo].settle_s``) or an
*operation* on paths (``{equals: [blackboard.pallet_id, sim.scan_pallet]}``,
``{length: perception.blocks}``, ``{max: motions[*].track_max_m}``).

Path syntax: names separated by dots; after a name, any number of selectors in brackets:
``[2]`` / ``[-1]`` an item of a list, ``[*]`` every item, ``[key=value]`` the items whose
``key`` reads ``value``. Once ``[*]`` or ``[key=value]`` has been used the path yields a list
(one value per selected item). A path that does not exist in a summary gives ``None``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

#: Comparisons of two operands (paths, or ``{value: literal}``): name -> test.
COMPARISONS: dict[str, Any] = {
    "equals": lambda a, b: a == b,
    "not_equals": lambda a, b: a != b,
    "less": lambda a, b: a < b,
    "less_equal": lambda a, b: a <= b,
    "greater": lambda a, b: a > b,
    "greater_equal": lambda a, b: a >= b,
}
#: Reductions of one operand (usually a list): name -> function of a non-empty list.
REDUCTIONS: dict[str, Any] = {
    "length": len,
    "min": min,
    "max": max,
    "sum": sum,
    "mean": lambda v: sum(v) / len(v),
}
OPERATIONS = (*COMPARISONS, *REDUCTIONS)

_SEGMENT = re.compile(r"([^.\[\]]*)((?:\[[^\[\]]*\])*)")
_SELECTOR = re.compile(r"\[([^\[\]]*)\]")


@dataclass(frozen=True)
class Step:
    """One step of a path: a mapping key, a list index, ``*`` or a ``key=value`` filter."""

    kind: str  # "key", "index", "all", "filter"
    key: str = ""
    index: int = 0
    value: str = ""


def parse_path(text: str) -> list[Step]:
    """The steps of a metric path; raises ValueError saying what is wrong with it."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError("a metric path must be a non-empty string such as blackboard.pallet_id")
    steps: list[Step] = []
    for part in re.split(r"\.(?![^\[]*\])", text.strip()):  # not the dots inside [...]
        m = _SEGMENT.fullmatch(part)
        if m is None:
            raise ValueError(f"cannot read path segment {part!r} (brackets unbalanced?)")
        name, selectors = m.group(1).strip(), m.group(2)
        if not name:
            raise ValueError(f"empty name in path {text!r} (two dots, or a leading dot?)")
        if name:
            steps.append(Step("key", key=name))
        for sel in _SELECTOR.findall(selectors):
            sel = sel.strip()
            if sel == "*":
                steps.append(Step("all"))
            elif re.fullmatch(r"-?\d+", sel):
                steps.append(Step("index", index=int(sel)))
            elif "=" in sel and sel.split("=", 1)[0].strip():
                k, v = sel.split("=", 1)
                steps.append(Step("filter", key=k.strip(), value=v.strip()))
            else:
                raise ValueError(
                    f"selector [{sel}] in {text!r}: expected [N], [-N], [*] or [key=value]"
                )
    return steps


def _matches(item: Any, key: str, value: str) -> bool:
    return isinstance(item, dict) and key in item and _text(item[key]) == value


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _walk(value: Any, steps: list[Step]) -> tuple[Any, bool]:
    """(value, is_list_of_selected) of ``steps`` applied to ``value``."""
    for i, step in enumerate(steps):
        if step.kind == "key":
            value = value.get(step.key) if isinstance(value, dict) else None
        elif step.kind == "index":
            ok = isinstance(value, list) and -len(value) <= step.index < len(value)
            value = value[step.index] if ok else None
        else:
            if not isinstance(value, list):
                return None, True
            items = (
                value
                if step.kind == "all"
                else [v for v in value if _matches(v, step.key, step.value)]
            )
            rest = steps[i + 1 :]
            return [_walk(item, rest)[0] for item in items], True
        if value is None:
            return None, False
    return value, False


def read_path(summary: dict, steps: list[Step]) -> Any:
    """The value at a parsed path in ``summary`` (None where it does not exist)."""
    return _walk(summary, steps)[0]


@dataclass(frozen=True)
class Operand:
    """A path into the summary, or a literal (``{value: ...}`` in the campaign file)."""

    path: tuple[Step, ...] = ()
    literal: Any = None
    is_literal: bool = False

    def read(self, summary: dict) -> Any:
        """This operand's value for one run."""
        return self.literal if self.is_literal else read_path(summary, list(self.path))


@dataclass(frozen=True)
class Metric:
    """One column of the results table, computed from each run's summary.

    ``op`` is ``"path"`` (the value at ``operands[0]``), a comparison or a reduction.
    ``wall_clock`` metrics (latencies, wall times) differ between identical runs, so they
    are kept apart from the deterministic columns (:data:`TIMING_COLUMNS` in results).
    """

    name: str
    op: str
    operands: tuple[Operand, ...] = field(default_factory=tuple)
    text: str = ""  # as written, for the report
    wall_clock: bool = False
    #: the campaign file's value (a worker rebuilds the metric from it)
    source: Any = None

    def evaluate(self, summary: dict) -> Any:
        """The metric's value for one run (None when a path is missing or a value does not
        compare)."""
        values = [o.read(summary) for o in self.operands]
        if self.op == "path":
            return _plain(values[0])
        if self.op in COMPARISONS:
            a, b = values
            try:
                return bool(COMPARISONS[self.op](a, b))
            except TypeError:
                return None
        v = values[0]
        if not isinstance(v, list):
            return None
        if self.op != "length":
            v = [x for x in v if _number(x)]
            if not v:
                return None
        return _plain(REDUCTIONS[self.op](v))


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _plain(value: Any) -> Any:
    """JSON-friendly: NaN and infinities become None (Parquet, CSV and JSON agree)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def metric_from_data(name: str, data: Any) -> Metric:
    """Build a metric from its campaign-file value (a path string, ``{path: ...,
    wall_clock: true}`` or ``{operation: ...}``); raises ValueError with what was expected."""
    source = data
    wall_clock = False
    if isinstance(data, dict):
        wall_clock = data.get("wall_clock", False)
        if not isinstance(wall_clock, bool):
            raise ValueError(f"wall_clock: expected true or false, got {wall_clock!r}")
    if isinstance(data, dict) and "path" in data:
        extra = set(data) - {"path", "wall_clock"}
        if extra:
            raise ValueError(f"unknown key {sorted(extra)[0]!r} (expected path, wall_clock)")
        data = data["path"]
    if isinstance(data, str):
        steps = tuple(parse_path(data))
        return Metric(name, "path", (Operand(steps),), data, wall_clock, source)
    if not isinstance(data, dict) or not data:
        raise ValueError(
            f"expected a summary path (e.g. blackboard.pallet_id) or an operation "
            f"({', '.join(OPERATIONS)}), got {data!r}"
        )
    ops = [k for k in data if k != "wall_clock"]
    if len(ops) != 1 or ops[0] not in OPERATIONS:
        raise ValueError(
            f"expected one operation of {', '.join(OPERATIONS)} (and optionally wall_clock), "
            f"got {sorted(map(str, data))}"
        )
    op = ops[0]
    arg = data[op]
    if op in COMPARISONS:
        if not isinstance(arg, list) or len(arg) != 2:
            raise ValueError(f"{op}: expected a list of two operands [path, path], got {arg!r}")
        operands = tuple(_operand(a, op) for a in arg)
    else:
        if not isinstance(arg, str):
            raise ValueError(f"{op}: expected one summary path, got {arg!r}")
        operands = (Operand(tuple(parse_path(arg))),)
    return Metric(name, op, operands, f"{op} {arg}", wall_clock, source)


def _operand(data: Any, op: str) -> Operand:
    if isinstance(data, dict) and set(data) == {"value"}:
        return Operand(literal=data["value"], is_literal=True)
    if isinstance(data, str):
        return Operand(tuple(parse_path(data)))
    raise ValueError(f"{op}: an operand is a summary path or {{value: literal}}, got {data!r}")
