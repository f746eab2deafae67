"""The values of the script language of :mod:`bt_engine.script`, and its operators.

Conversions between numbers, text and bools (numeric strings, truthiness, int64 results that
become floats), the arithmetic, bitwise, concatenation and comparison operators as tables,
and the limits on the values a script builds (``MAX_NUMBER_LENGTH``, ``MAX_STRING_LENGTH``,
``MAX_TEXT_PER_RUN``; :mod:`bt_engine.script` re-exports them). The helpers raise
:class:`_OpError`, which the compiled script turns into a ``ScriptError`` at the operator's
column. The semantics are described in :mod:`bt_engine.script`.
"""

from __future__ import annotations

import math
import numbers
import operator
import re
import threading
from collections.abc import Callable, Mapping
from typing import Any

MAX_STRING_LENGTH = 65_536  # longest string a script may build by concatenation
MAX_TEXT_PER_RUN = 1_048_576  # characters of new text one run of a script may build in all
MAX_NUMBER_LENGTH = 400  # longest number literal or numeric string (a double has <= 309 digits)
_I64 = 1 << 63
_EPS = 1.1920928955078125e-07  # std::numeric_limits<float>::epsilon(), used by BT.CPP's ==


class _OpError(Exception):
    """Raised by value helpers; converted to ScriptError with the operator's column."""


# Anchored patterns without overlapping quantifiers (``\d+\.?\d*`` backtracks quadratically on
# a long run of digits): each digit run is followed by something a digit cannot be, so a
# failed match gives up in linear time. Inputs are also capped at MAX_NUMBER_LENGTH.
_DEC_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_HEX_RE = re.compile(r"[+-]?0[xX][0-9a-fA-F]+")
#: what is left of the text-building budget of the running script (see Script.execute)
_BUDGET = threading.local()


def _desc(v: Any) -> str:
    if isinstance(v, str):
        return f"string {v[:40]!r}" + ("..." if len(v) > 40 else "")
    return f"{type(v).__name__} {str(v)[:40]}"


def _number(text: str) -> int | float:
    """The value of a (possibly signed) numeric literal already matched by ``_DEC_RE`` or ``_HEX_RE``."""
    t = text.strip().lower()
    if "0x" in t:
        v = int(t, 16) if len(t) <= 20 else _I64
        if not -_I64 <= v < _I64:
            raise _OpError(f"hex number {t[:20]} does not fit in 64 bits")
        return v
    if "." in t or "e" in t:
        return float(t)
    return _fix(int(t)) if len(t) <= 40 else float(t)


def _str_num(s: str) -> int | float | bool | None:
    """The number (or bool, for 'true'/'false') a string spells, or None.

    Linear in ``len(s)``; a string of more than ``MAX_NUMBER_LENGTH`` characters (once
    stripped) is never a number.
    """
    t = s.strip()
    if len(t) > MAX_NUMBER_LENGTH:
        return None
    if _DEC_RE.fullmatch(t) or _HEX_RE.fullmatch(t):
        return _number(t)
    low = t.lower()
    return True if low == "true" else False if low == "false" else None


def _too_long(s: str) -> str:
    """A note for an error about ``s`` if it is too long to be read as a number."""
    if len(s.strip()) > MAX_NUMBER_LENGTH:
        return f" (numbers are at most {MAX_NUMBER_LENGTH} characters: MAX_NUMBER_LENGTH)"
    return ""


def _num(v: Any) -> int | float | bool:
    t = type(v)
    if t is int or t is float or t is bool:
        return v
    if t is str:
        n = _str_num(v)
        if n is None:
            raise _OpError(f"expected a number, got {_desc(v)}{_too_long(v)}")
        return n
    if isinstance(v, numbers.Integral):
        return int(v)
    if isinstance(v, numbers.Real):
        return float(v)
    raise _OpError(f"expected a number, got {'None' if v is None else _desc(v)}")


def _int(v: Any) -> int:
    n = _num(v)
    if type(n) is float:
        if not n.is_integer():
            raise _OpError(f"bitwise operators need integers, got {n!r}")
        n = int(n)
    if not -_I64 <= n < _I64:
        raise _OpError(f"{n} does not fit in 64 bits")
    return int(n)


def _fix(r: Any) -> Any:
    return float(r) if type(r) is int and not -_I64 <= r < _I64 else r


def _truth(v: Any) -> bool:
    t = type(v)
    if t is bool:
        return v
    if t is int or t is float:
        return v != 0
    if t is str:
        n = _str_num(v)
        return v != "" if n is None else n != 0
    if v is None:
        raise _OpError("cannot use None as a condition")
    return bool(v)


def _text(v: Any) -> str:
    t = type(v)
    if t is str:
        return v
    if t is bool:
        return "true" if v else "false"
    if t is float:
        return repr(v)
    if v is None:
        raise _OpError("cannot convert None to text")
    return str(v)


def _cat(a: str, b: str) -> str:
    n = len(a) + len(b)
    if n > MAX_STRING_LENGTH:
        raise _OpError(
            f"string longer than {MAX_STRING_LENGTH} characters (MAX_STRING_LENGTH): the "
            f"result would have {n}"
        )
    budget = _BUDGET.__dict__
    left = budget.get("left")
    if left is not None:
        if n > left:
            raise _OpError(
                f"one run of a script may build at most {MAX_TEXT_PER_RUN} characters of "
                "text (MAX_TEXT_PER_RUN)"
            )
        budget["left"] = left - n
    return a + b


def _arith(op: Callable[[Any, Any], Any], strings: bool = False) -> Callable[[Any, Any], Any]:
    def f(a: Any, b: Any) -> Any:
        ta, tb = type(a), type(b)
        if (ta is int or ta is float) and (tb is int or tb is float):
            return _fix(op(a, b))
        if strings and ta is str and tb is str:
            return _cat(a, b)
        return _fix(op(_num(a), _num(b)))

    return f


def _div(a: Any, b: Any) -> float:
    a, b = _num(a), _num(b)
    if b == 0:
        raise _OpError("division by zero")
    return a / b


def _mod(a: Any, b: Any) -> int | float:
    a, b = _num(a), _num(b)
    if b == 0:
        raise _OpError("modulo by zero")
    if type(a) is float or type(b) is float:
        return math.fmod(a, b)
    r = abs(a) % abs(b)
    return -r if a < 0 else r


def _bits(op: Callable[[int, int], int]) -> Callable[[Any, Any], int]:
    return lambda a, b: op(_int(a), _int(b))


_BINARY: dict[str, Callable[[Any, Any], Any]] = {
    "+": _arith(operator.add, strings=True),
    "-": _arith(operator.sub),
    "*": _arith(operator.mul),
    "/": _div,
    "%": _mod,
    "&": _bits(operator.and_),
    "|": _bits(operator.or_),
    "^": _bits(operator.xor),
    "..": lambda a, b: _cat(_text(a), _text(b)),
}
_UNARY: dict[str, Callable[[Any], Any]] = {
    "-": lambda v: _fix(-_num(v)),
    "!": lambda v: not _truth(v),
    "not": lambda v: not _truth(v),
    "~": lambda v: ~_int(v),
}
_REALS = (int, float, bool)


def _operands(a: Any, b: Any, enums: Mapping[str, int], ordered: bool) -> tuple[Any, Any]:
    """Make ``a`` and ``b`` comparable: both numbers or both strings."""
    ta, tb = type(a), type(b)
    if (ta in _REALS and tb in _REALS) or (ta is str and tb is str):
        return a, b
    scalar = (str, numbers.Real)
    if not isinstance(a, scalar) or not isinstance(b, scalar):
        if ordered or a is None or b is None:
            raise _OpError(f"cannot compare {_desc(a)} with {_desc(b)}")
        return a, b  # == and != between other objects use Python equality
    if isinstance(a, str):
        return _str_cmp(a, enums, b), _num(b)
    if isinstance(b, str):
        return _num(a), _str_cmp(b, enums, a)
    return _num(a), _num(b)


def _str_cmp(s: str, enums: Mapping[str, int], other: Any) -> Any:
    n = _str_num(s)
    if n is None:
        n = enums.get(s.strip())
        if n is None:
            raise _OpError(f"cannot compare {_desc(s)} with number {other!r}{_too_long(s)}")
    return n


def _eq(a: Any, b: Any) -> bool:
    if a == b:
        return True
    ta, tb = type(a), type(b)
    return (ta is float or tb is float) and ta in _REALS and tb in _REALS and abs(a - b) <= _EPS


_COMPARE: dict[str, Callable[[Any, Any], bool]] = {
    "==": _eq,
    "!=": lambda a, b: not _eq(a, b),
    "<": operator.lt,
    ">": operator.gt,
    "<=": operator.le,
    ">=": operator.ge,
}
