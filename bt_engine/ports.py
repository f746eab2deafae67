"""Port declarations and port types.

A node declares its ports once (direction, type, default, description). The declaration is
the single source of truth for validation, XML/YAML conversion, ``btrun nodes``, the Groot2
palette and the generated node reference.

Values arrive as text from XML (``"1;2;0.5"``) and as native values from YAML
(``[1, 2, 0.5]``); every type converts both, and writes text back for XML.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any


class PortValueError(ValueError):
    """A value that does not convert to a port's type; the message says what was expected."""


def _odd_digits(text: str) -> bool:
    """True for number text Python reads but BehaviorTree.CPP and a reader do not: ``_``
    between digits (``0_5`` is 5.0 to ``float``) or digits outside ASCII (``１０``, ``٣``)."""
    return "_" in text or not text.isascii()


class PortType:
    """Base class of port types: a name for files and docs, and two conversions."""

    name = "any"
    expected = "any value"

    def samples(self) -> tuple[Any, ...] | None:
        """Values a port of this type may hold, to tell whether another type can read them
        (:func:`bt_engine.validate_types.converts_from`); None: any value at all."""
        return None

    def convert(self, value: Any) -> Any:
        """Convert ``value`` (text from XML or a native YAML value) or raise PortValueError."""
        return value

    def to_text(self, value: Any) -> str:
        """Return ``value`` as XML attribute text that :meth:`convert` reads back."""
        if isinstance(value, bool):
            return "true" if value else "false"
        return str(value)

    def to_yaml(self, value: Any) -> Any:
        """Return ``value`` as a plain YAML value."""
        return value

    def __repr__(self) -> str:
        return f"<PortType {self.name}>"


class AnyType(PortType):
    """Any value; text stays text (BehaviorTree.CPP's ``AnyTypeAllowed``)."""


class StringType(PortType):
    """Text."""

    name = "string"
    expected = "text"

    def convert(self, value: Any) -> str:
        if isinstance(value, (dict, list)):
            raise PortValueError(f"expected {self.expected}, got a {type(value).__name__}")
        if isinstance(value, bool):
            return "true" if value else "false"
        return str(value)


class FloatType(PortType):
    """A real number (``1.5``, ``-2``, ``1e-3``)."""

    name = "float"
    expected = "a number"

    def samples(self) -> tuple[Any, ...]:
        return (0.0, 1.5)

    def convert(self, value: Any) -> float:
        if isinstance(value, bool):
            raise PortValueError(f"expected {self.expected}, got boolean {value}")
        if isinstance(value, str) and _odd_digits(value):
            raise PortValueError(f"expected {self.expected} (plain digits), got {_short(value)}")
        try:
            out = float(value.strip() if isinstance(value, str) else value)
        except (TypeError, ValueError):
            raise PortValueError(f"expected {self.expected}, got {_short(value)}") from None
        if not math.isfinite(out):  # NaN and +-inf never reach a leaf (or a set-point)
            raise PortValueError(f"expected a finite number, got {_short(value)}")
        return out

    def to_text(self, value: Any) -> str:
        return repr(float(value))


class IntType(PortType):
    """A whole number (``3``, ``-1``, ``0x10``)."""

    name = "int"
    expected = "a whole number"

    def samples(self) -> tuple[Any, ...]:
        return (0, 1, 2)

    def convert(self, value: Any) -> int:
        if isinstance(value, bool):
            raise PortValueError(f"expected {self.expected}, got boolean {value}")
        if isinstance(value, int):
            return value
        if isinstance(value, float):
            if value.is_integer():
                return int(value)
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if isinstance(value, str):
            text = value.strip()
            if _odd_digits(text):
                raise PortValueError(
                    f"expected {self.expected} (plain digits), got {_short(value)}"
                )
            try:
                return int(text, 0)
            except ValueError:
                pass
            try:
                f = float(text)
            except ValueError:
                f = math.nan
            if f.is_integer():
                return int(f)
        raise PortValueError(f"expected {self.expected}, got {_short(value)}")


class BoolType(PortType):
    """``true``/``false`` (also ``1``/``0``, ``yes``/``no``, any case)."""

    name = "bool"
    expected = "true or false"
    _TRUE = {"true", "1", "yes", "on"}
    _FALSE = {"false", "0", "no", "off"}

    def samples(self) -> tuple[Any, ...]:
        return (True, False)

    def convert(self, value: Any) -> bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, int) and value in (0, 1):
            return bool(value)
        if isinstance(value, str):
            low = value.strip().lower()
            if low in self._TRUE:
                return True
            if low in self._FALSE:
                return False
        raise PortValueError(f"expected {self.expected}, got {_short(value)}")


class EnumType(PortType):
    """One of a set of names; Aerostack2-style integers are accepted too.

    >>> YAW = EnumType("YawMode", {"KEEP_YAW": 0, "PATH_FACING": 1, "FIXED_YAW": 2})
    >>> YAW.convert("1"), YAW.convert("fixed_yaw")
    ('PATH_FACING', 'FIXED_YAW')
    """

    def __init__(self, name: str, members: Mapping[str, int]) -> None:
        self.name = name
        self.members = dict(members)
        self._by_value = {v: k for k, v in self.members.items()}
        self._by_upper = {k.upper(): k for k in self.members}
        listing = ", ".join(f"{k} ({v})" for k, v in self.members.items())
        self.expected = f"one of {listing}"

    def samples(self) -> tuple[Any, ...]:
        return tuple(self.members)

    def convert(self, value: Any) -> str:
        if isinstance(value, bool):
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if isinstance(value, int) and value in self._by_value:
            return self._by_value[value]
        if isinstance(value, str):
            text = value.strip()
            if text.upper() in self._by_upper:
                return self._by_upper[text.upper()]
            try:
                number = int(text) if not _odd_digits(text) else None
            except ValueError:
                number = None
            if number in self._by_value:
                return self._by_value[number]
        raise PortValueError(f"expected {self.expected}, got {_short(value)}")

    def value_of(self, member: str) -> int:
        """Return the integer of a member name."""
        return self.members[member]


def _floats(parts: Sequence[Any], what: str) -> tuple[float, ...]:
    out = []
    for p in parts:
        if isinstance(p, bool):
            raise PortValueError(f"expected {what}, got boolean {p}")
        if isinstance(p, str) and _odd_digits(p):
            raise PortValueError(f"expected {what} (plain digits), got {_short(p)} in it")
        try:
            f = float(p.strip() if isinstance(p, str) else p)
        except (TypeError, ValueError):
            raise PortValueError(f"expected {what}, got {_short(p)} in it") from None
        if not math.isfinite(f):
            raise PortValueError(f"expected {what}, got {_short(p)} in it")
        out.append(f)
    return tuple(out)


class Vec3Type(PortType):
    """Three numbers: ``"x;y;z"`` in XML (Aerostack2 syntax), ``[x, y, z]`` in YAML."""

    name = "vec3"
    expected = 'three numbers "x;y;z"'

    def samples(self) -> tuple[Any, ...]:
        return ((0.0, 0.0, 0.0),)

    def convert(self, value: Any) -> tuple[float, float, float]:
        if isinstance(value, str):
            count = value.count(";") + value.count(",") + 1  # before splitting a huge value
            if count != 3:
                raise PortValueError(
                    f"expected {self.expected}, got {count} value(s) in {_short(value)}"
                )
            parts: Sequence[Any] = [p for p in re.split(r"[;,]", value)]
        elif isinstance(value, (list, tuple)):
            parts = value
        else:
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if len(parts) != 3:
            raise PortValueError(
                f"expected {self.expected}, got {len(parts)} value(s) in {_short(value)}"
            )
        x, y, z = _floats(parts, self.expected)
        return (x, y, z)

    def to_text(self, value: Any) -> str:
        return ";".join(_num_text(v) for v in value)

    def to_yaml(self, value: Any) -> list[float]:
        return [float(v) for v in value]


class PathType(PortType):
    """A list of points: ``"x;y;z|x;y;z"`` in XML, ``[[x, y, z], ...]`` in YAML."""

    name = "path"
    expected = 'points "x;y;z|x;y;z|..."'

    def samples(self) -> tuple[Any, ...]:
        return (((0.0, 0.0, 0.0),), ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)))

    def convert(self, value: Any) -> tuple[tuple[float, float, float], ...]:
        if isinstance(value, str):
            chunks: Sequence[Any] = [c for c in value.split("|") if c.strip()]
        elif isinstance(value, (list, tuple)):
            chunks = value
        else:
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if not chunks:
            raise PortValueError(f"expected {self.expected}, got an empty path")
        vec = Vec3Type()
        points = []
        for i, c in enumerate(chunks):
            try:
                points.append(vec.convert(c))
            except PortValueError as exc:
                raise PortValueError(f"point {i + 1}: {exc}") from None
        return tuple(points)

    def to_text(self, value: Any) -> str:
        return "|".join(";".join(_num_text(v) for v in p) for p in value)

    def to_yaml(self, value: Any) -> list[list[float]]:
        return [[float(v) for v in p] for p in value]


def split_queue(text: str) -> list[str]:
    """Split ``"a;b;c"`` into queue items as BehaviorTree.CPP's ``splitString(str, ';')``
    does: ``""`` is no item, a trailing ``;`` adds none, ``"a;;b"`` has an empty middle one."""
    parts = text.split(";")
    if parts[-1] == "":
        parts.pop()
    return parts


class QueueType(PortType):
    """A queue of values of one type (BehaviorTree.CPP's ``SharedQueue<T>``).

    ``"a;b;c"`` in XML (split on ``;``, see :func:`split_queue`), ``[a, b, c]`` in YAML; a
    single number or boolean is a queue of one. Each item converts with ``element``; an item
    may not contain ``;`` (the separator, so that YAML lists convert to XML unchanged).
    """

    def __init__(self, element: PortType) -> None:
        self.element = element
        self.name = f"{element.name} queue"
        self.expected = f'a queue of {element.name} items "a;b;c"'

    def samples(self) -> tuple[Any, ...] | None:
        items = self.element.samples()
        if items is None:
            return None
        return tuple([v] for v in items) + (list(items) * 3,)

    def convert(self, value: Any) -> list[Any]:
        if isinstance(value, str):
            parts: list[Any] = split_queue(value)
        elif isinstance(value, (list, tuple, deque)):
            parts = list(value)
            for i, p in enumerate(parts):
                if isinstance(p, str) and ";" in p:
                    raise PortValueError(
                        f"item {i + 1} of the queue, {_short(p)}, contains ';' "
                        "(the separator of queue items)"
                    )
        elif isinstance(value, (bool, int, float)):
            parts = [value]
        else:
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        out = []
        for i, p in enumerate(parts):
            try:
                out.append(self.element.convert(p))
            except PortValueError as exc:
                raise PortValueError(f"item {i + 1} of the queue: {exc}") from None
        return out

    def to_text(self, value: Any) -> str:
        return ";".join(self.element.to_text(v) for v in value)

    def to_yaml(self, value: Any) -> list[Any]:
        return [self.element.to_yaml(v) for v in value]


# The number of a duration, matched against text already stripped of spaces and unit: no
# two quantifiers here can match the same characters, so matching is linear (a pattern with
# ``\s*(unit)?\s*$`` backtracks quadratically on a long run of trailing spaces).
_DURATION_NUMBER = re.compile(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", re.ASCII)
_DURATION_UNITS = (("ms", 1e-3), ("min", 60.0), ("s", 1.0))


def _duration_seconds(text: str) -> float | None:
    """Seconds of ``"2.5"``, ``"2.5s"``, ``" 500 ms "``, ``"1min"``; None if not a duration."""
    t = text.strip()
    scale = 1.0
    for unit, factor in _DURATION_UNITS:
        if t.endswith(unit):
            t, scale = t[: -len(unit)].rstrip(), factor
            break
    if not _DURATION_NUMBER.fullmatch(t):
        return None
    return float(t) * scale


class DurationType(PortType):
    """A duration in seconds: ``2.5``, ``"2.5s"``, ``"500ms"``, ``"1min"`` (bare numbers are s)."""

    name = "duration"
    expected = 'a duration like "2.5", "2.5s" or "500ms"'

    def samples(self) -> tuple[Any, ...]:
        return (0.0, 1.5)

    def convert(self, value: Any) -> float:
        if isinstance(value, bool):
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if isinstance(value, (int, float)):
            seconds = float(value)
        elif isinstance(value, str):
            parsed = _duration_seconds(value)
            if parsed is None:
                raise PortValueError(f"expected {self.expected}, got {_short(value)}")
            seconds = parsed
        else:
            raise PortValueError(f"expected {self.expected}, got {_short(value)}")
        if not math.isfinite(seconds) or seconds < 0:
            raise PortValueError(f"expected {self.expected} (not negative), got {_short(value)}")
        return seconds

    def to_text(self, value: Any) -> str:
        return _num_text(value)


def _short(value: Any, limit: int = 200) -> str:
    """``repr(value)``, cut to about ``limit`` characters for messages."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"


def number_text(v: Any) -> str:
    """A number as mission files spell it: integral values without ".0" (50.0 -> "50")."""
    f = float(v)
    return str(int(f)) if f.is_integer() and abs(f) < 1e15 else repr(f)


_num_text = number_text


ANY = AnyType()
STRING = StringType()
FLOAT = FloatType()
INT = IntType()
BOOL = BoolType()
VEC3 = Vec3Type()
PATH = PathType()
DURATION = DurationType()

#: Type names as written in a ``<TreeNodesModel>`` ``type=`` attribute or a YAML model.
TYPES_BY_NAME: dict[str, PortType] = {
    "any": ANY,
    "string": STRING,
    "std::string": STRING,
    "float": FLOAT,
    "double": FLOAT,
    "int": INT,
    "unsigned": INT,
    "bool": BOOL,
    "vec3": VEC3,
    "path": PATH,
    "duration": DURATION,
}


class _NoDefault:
    def __repr__(self) -> str:
        return "NO_DEFAULT"

    def __bool__(self) -> bool:
        return False


NO_DEFAULT: Any = _NoDefault()

INPUT, OUTPUT, INOUT = "input", "output", "inout"


def range_words(low: float | None, high: float | None) -> str | None:
    """A port's range said in words (``0.01 to 3``, ``at least 0``, ``at most 5``); None
    when it has none."""
    if low is not None and high is not None:
        return f"{low:g} to {high:g}"
    if low is not None:
        return f"at least {low:g}"
    return f"at most {high:g}" if high is not None else None


@dataclass(frozen=True)
class Port:
    """One declared port of a node.

    ``direction`` is ``"input"``, ``"output"`` or ``"inout"``. A port without a default is
    required for inputs; outputs are never required (an unbound output is simply not written).
    ``takes_literal``: an inout port that may also be given a literal, which the node then
    works on privately (the ``queue`` of the Loop decorators); such a port is required
    unless it has a default. ``low`` / ``high``: the numbers the node can work with; a
    value outside (from the mission, its inputs or ``--set``) is refused before flight
    (:meth:`bt_engine.mission.Mission.preflight`), as are ``nan`` and ``inf``.
    """

    name: str
    direction: str = INPUT
    type: PortType = field(default=ANY)
    default: Any = NO_DEFAULT
    description: str = ""
    takes_literal: bool = False
    low: float | None = None
    high: float | None = None

    def out_of_range(self, value: Any) -> str | None:
        """Why ``value`` is outside :attr:`low` .. :attr:`high` (None if it is inside, has
        no range or is not a number)."""
        want = range_words(self.low, self.high)
        if want is None or isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        inside = (self.low is None or value >= self.low) and (
            self.high is None or value <= self.high
        )
        if inside and math.isfinite(value):
            return None
        what = f" ({self.description})" if self.description else ""
        return f"{self.name} {value!r}: expected {want}{what}"

    @property
    def required(self) -> bool:
        """True if a mission file must give this port a value."""
        return (self.direction == INPUT or self.takes_literal) and self.default is NO_DEFAULT

    @property
    def reads(self) -> bool:
        """True if the node reads this port."""
        return self.direction in (INPUT, INOUT)

    @property
    def writes(self) -> bool:
        """True if the node writes this port."""
        return self.direction in (OUTPUT, INOUT)


def input_port(
    name: str,
    type: PortType = ANY,
    default: Any = NO_DEFAULT,
    description: str = "",
    *,
    low: float | None = None,
    high: float | None = None,
) -> Port:
    """Declare an input port (required unless it has a default); ``low`` / ``high``: the
    numbers the node can work with, checked before flight."""
    return Port(name, INPUT, type, default, description, low=low, high=high)


def output_port(name: str, type: PortType = ANY, description: str = "") -> Port:
    """Declare an output port (bind it to a blackboard entry ``{key}`` in the mission)."""
    return Port(name, OUTPUT, type, NO_DEFAULT, description)


def inout_port(
    name: str,
    type: PortType = ANY,
    default: Any = NO_DEFAULT,
    description: str = "",
    takes_literal: bool = False,
) -> Port:
    """Declare a port the node both reads and writes (``takes_literal``: see :class:`Port`)."""
    return Port(name, INOUT, type, default, description, takes_literal)


_REF = re.compile(r"^\{\s*(@?[A-Za-z_][\w.\-/]*|=)\s*\}$")


def blackboard_ref(value: Any) -> str | None:
    """Return the entry name if ``value`` is a ``{key}`` reference (``"="`` for ``{=}``)."""
    if isinstance(value, str) and value.startswith("{") and value.endswith("}"):
        m = _REF.match(value.strip())
        if m:
            return m.group(1)
    return None


#: BehaviorTree.CPP's (and btrun's own) type names in a ``<TreeNodesModel>``, as port types
_DECLARED = {
    **dict.fromkeys(("double", "float"), FLOAT),
    **dict.fromkeys(
        ("int", "unsigned", "unsigned int", "long", "unsigned long", "int32_t", "int64_t"), INT
    ),
    "uint32_t": INT,
    "uint64_t": INT,
    "bool": BOOL,
    "std::string": STRING,
    "string": STRING,
    "vec3": Vec3Type(),
    "path": PATH,
    "duration": DURATION,
}


def declared_type(name: str | None) -> PortType | None:
    """The port type a ``<TreeNodesModel>`` port's ``type="..."`` names (``double``,
    ``int``, ``bool``, ``std::string``, btrun's ``vec3`` ...); None for a type btrun cannot
    check (a plug-in's, a C++ struct)."""
    return _DECLARED.get((name or "").strip())
