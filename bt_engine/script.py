"""A small, safe interpreter for the BehaviorTree.CPP v4 scripting language.

Used by the ``Script``/``ScriptCondition`` nodes and by the ``_skipIf``, ``_successIf``,
``_failureIf``, ``_while``, ``_onSuccess``, ``_onFailure`` and ``_post`` attributes.
Mission files come from users, so the code is tokenized, parsed to an AST by a Pratt parser
and compiled to nested closures; nothing is ever handed to ``eval``/``exec``.

Values and operators (conversions, truthiness, the operator tables, the limits on the text
a script builds) are in :mod:`bt_engine.script_values`; this module holds the language: the
tokenizer, the parser, the compiler and :func:`parse_script`.

Precedence, lowest first (binary operators are left-associative unless noted):

=============  ==========================  ==================================================
statements     ``a; b; c``                 the script's value is the last statement's value
assignment     ``:= = += -= *= /= %=``     right-assoc; ``=`` and ``op=`` need an existing entry
ternary        ``c ? a : b``               right-assoc
or / and       ``|| or`` / ``&& and``      short-circuit, give a bool
comparison     ``== != < > <= >=``         give a bool; not chainable (``a < b < c`` is an error)
concat         ``..``                      operands converted to text
bitwise        ``| ^`` / ``&``             int64 operands
arithmetic     ``+ -`` / ``* / %``         ``str + str`` concatenates
unary          ``- ! not ~``
atoms          numbers (``42 2.5 1e3 0x1F``), ``'text'`` or ``"text"``, ``true false``,
               enum names, entry names (``name``, ``@root_name``), ``( ... )``
=============  ==========================  ==================================================

Semantics (BT.CPP stores every number as a double; we keep Python ints where exact):

* ``int + - * % int`` gives an int, ``/`` always gives a float (``5 / 2 == 2.5``, as in BT.CPP);
  ints outside int64 become floats. ``%`` follows C (sign of the dividend). Dividing by zero
  is a :class:`ScriptError`.
* Unlike BT.CPP, ``&&`` binds tighter than ``||`` (C rules) and both short-circuit. Like
  BT.CPP, bitwise operators bind tighter than comparisons (``x & 4 == 4`` works).
* Strings spelling a number (``'12'``, ``'0x1f'``, ``'2.5'``) or a bool (``'true'``) are
  converted when combined with a number, since XML blackboard values are often strings; two
  strings compare as text. A non-numeric string compared with a number may name an enum.
* ``==``/``!=`` involving a float allow BT.CPP's tolerance (float epsilon, ~1.2e-7).
* Truthiness: numbers are true when non-zero, numeric/bool strings as converted, other
  strings when non-empty; ``None`` is an error.
* Names resolve to an enum first (as in BT.CPP), then to the blackboard; ``@`` keys are passed
  unchanged to the environment, which maps them to the root blackboard.

Limits (mission files come from users; every one is a :class:`ScriptError` naming it):
``MAX_SOURCE_LENGTH`` characters of source, ``MAX_DEPTH`` levels of nesting,
``MAX_NUMBER_LENGTH`` characters in a number (a longer numeric string is text),
``MAX_STRING_LENGTH`` characters in a string a script builds and ``MAX_TEXT_PER_RUN``
characters of new text built by one run of a script. Numbers are recognised in linear time
(no backtracking regular expression). Integers never grow beyond int64 (they become floats).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Mapping
from typing import Any, Protocol, runtime_checkable

from bt_engine.script_values import (
    _BINARY,
    _BUDGET,
    _COMPARE,
    _UNARY,
    MAX_NUMBER_LENGTH,
    MAX_TEXT_PER_RUN,
    _number,
    _operands,
    _OpError,
    _truth,
)
from bt_engine.script_values import MAX_STRING_LENGTH as MAX_STRING_LENGTH
from bt_engine.script_values import _str_num as _str_num

__all__ = [
    "DictEnv",
    "Script",
    "ScriptEnv",
    "ScriptError",
    "constant_failure",
    "parse_script",
]

MAX_SOURCE_LENGTH = 10_000
MAX_DEPTH = 100  # nesting depth of expressions (parentheses, operands, unary chains)


class ScriptError(Exception):
    """Syntax or runtime error in a script.

    Attributes:
        message: human-readable description of the problem.
        column: 0-based offset in the source where the problem is, or -1 if unknown.
    """

    def __init__(self, message: str, column: int = -1):
        super().__init__(message)
        self.message = message
        self.column = column


@runtime_checkable
class ScriptEnv(Protocol):
    """The blackboard as seen by a script: ``get`` raises ``KeyError`` for a missing entry,
    ``set`` creates or overwrites an entry, ``has`` tells whether an entry exists."""

    def get(self, key: str) -> Any: ...
    def set(self, key: str, value: Any) -> None: ...
    def has(self, key: str) -> bool: ...


class DictEnv:
    """A :class:`ScriptEnv` backed by a plain dict (the dict passed in is used, not copied)."""

    def __init__(self, data: dict[str, Any] | None = None) -> None:
        self.data: dict[str, Any] = {} if data is None else data

    def get(self, key: str) -> Any:
        return self.data[key]

    def set(self, key: str, value: Any) -> None:
        self.data[key] = value

    def has(self, key: str) -> bool:
        return key in self.data

    def __repr__(self) -> str:
        return f"DictEnv({self.data!r})"


Evaluator = Callable[[ScriptEnv, Mapping[str, int]], Any]
_NO_ENUMS: Mapping[str, int] = {}


class Script:
    """A parsed script: immutable, shareable, and cheap to execute repeatedly."""

    __slots__ = ("source", "reads", "writes", "creates", "regrouped", "_run")

    def __init__(
        self,
        source: str,
        reads: frozenset[str],
        writes: frozenset[str],
        run: Evaluator,
        creates: frozenset[str] | None = None,
        regrouped: tuple[int, ...] = (),
    ):
        self.source = source
        #: columns of operators BehaviorTree.CPP 4 groups otherwise (``a - b - c``: it
        #: computes ``a - (b - c)``); ``btrun validate`` warns of them
        self.regrouped = regrouped
        self.reads = reads  # entry names read (may include enum names: enums are runtime data)
        self.writes = writes  # entry names assigned by any assignment operator
        # entry names assigned with ':=', the one operator that creates a missing entry
        self.creates = writes if creates is None else creates
        self._run = run

    def execute(self, env: ScriptEnv, enums: Mapping[str, int] | None = None) -> Any:
        """Run the script against ``env`` and return the value of its last statement.

        ``enums`` maps constant names (e.g. ``FIXED_YAW``) to integers; they shadow entries.
        Raises :class:`ScriptError` on runtime errors (unknown entry, type error, ...).
        """
        budget = _BUDGET.__dict__
        outer = budget.get("left")
        budget["left"] = MAX_TEXT_PER_RUN
        try:
            return self._run(env, _NO_ENUMS if enums is None else enums)
        finally:
            budget["left"] = outer

    def __repr__(self) -> str:
        return f"Script({self.source!r})"


# --------------------------------------------------------------------------- tokenizer

_TOKEN_RE = re.compile(
    r"""(?P<ws>\s+)
    |(?P<num>0[xX][0-9a-fA-F]+|(?:[0-9]+\.[0-9]+|\.[0-9]+|[0-9]+)(?:[eE][+-]?[0-9]+)?)
    |(?P<str>'[^']*'|"[^"]*")
    |(?P<name>@?[^\W\d]\w*)
    |(?P<op>:=|==|!=|<=|>=|&&|\|\||\+=|-=|\*=|/=|%=|\.\.|[-+*/%<>!~&|^?:();=])
    |(?P<bad>.)""",
    re.VERBOSE | re.DOTALL,
)
_KEYWORDS = {"and": "&&", "or": "||", "not": "not"}


def _tokenize(code: str) -> list[tuple[str, Any, int]]:
    """Return ``(kind, value, column)`` tuples; kinds are num, str, name, op, end."""
    tokens: list[tuple[str, Any, int]] = []
    for m in _TOKEN_RE.finditer(code):
        kind, text, col = m.lastgroup, m.group(), m.start()
        if kind == "ws":
            continue
        if kind == "bad":
            what = "unterminated string" if text in "'\"" else f"unexpected character {text!r}"
            raise ScriptError(what, col)
        if kind == "num":
            if len(text) > MAX_NUMBER_LENGTH:
                msg = f"number longer than {MAX_NUMBER_LENGTH} characters (MAX_NUMBER_LENGTH)"
                raise ScriptError(msg, col)
            try:
                tokens.append(("num", _number(text), col))
            except _OpError as e:
                raise ScriptError(str(e), col) from None
        elif kind == "str":
            tokens.append(("str", text[1:-1], col))
        elif kind == "name" and text in ("true", "false"):
            tokens.append(("num", text == "true", col))
        elif kind == "name" and text in _KEYWORDS:
            tokens.append(("op", _KEYWORDS[text], col))
        else:
            tokens.append((kind, text, col))
    tokens.append(("end", None, len(code)))
    return tokens


# --------------------------------------------------------------------------- parser

# Infix binding powers. Nodes are tuples: (kind, column, depth, *payload).
_ASSIGN_OPS = (":=", "=", "+=", "-=", "*=", "/=", "%=")
_INFIX: dict[str, int] = {op: 1 for op in _ASSIGN_OPS}
_INFIX.update({"?": 2, "||": 3, "&&": 4, "..": 6, "|": 7, "^": 7, "&": 8})
_INFIX.update({op: 5 for op in _COMPARE})
_INFIX.update({"+": 9, "-": 9, "*": 10, "/": 10, "%": 10})
_UNARY_BP = 11


class _Parser:
    def __init__(self, code: str) -> None:
        self.tokens = _tokenize(code)
        self.pos = 0
        self.nesting = 0
        self.reads: dict[int, str] = {}  # column -> name, for every name read
        self.writes: set[str] = set()
        self.creates: set[str] = set()  # targets of ':=' (the others need the entry to exist)
        self.grouped: set[int] = set()  # ids of the nodes written in parentheses
        #: columns of operators that BehaviorTree.CPP 4 groups otherwise: it takes a chain
        #: of + - or of * / % from the right (10 - 4 - 2 is 8 there, 4 here)
        self.regrouped: list[int] = []

    def peek(self) -> tuple[str, Any, int]:
        return self.tokens[self.pos]

    def next(self) -> tuple[str, Any, int]:
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def expect(self, op: str) -> None:
        kind, value, col = self.next()
        if kind != "op" or value != op:
            raise ScriptError(f"expected '{op}' but found {_show(kind, value)}", col)

    def node(self, kind: str, col: int, *kids: tuple, payload: tuple = ()) -> tuple:
        depth = 1 + max((k[2] for k in kids), default=0)
        if depth > MAX_DEPTH:
            raise ScriptError(f"expression nested deeper than {MAX_DEPTH} levels", col)
        return (kind, col, depth, *payload, *kids)

    def statements(self) -> list[tuple]:
        stmts = []
        while True:
            while self.peek()[:2] == ("op", ";"):
                self.pos += 1
            if self.peek()[0] == "end":
                break
            stmts.append(self.expr(0))
            kind, value, col = self.peek()
            if kind != "end" and value != ";":
                raise ScriptError(f"expected ';' or end of script, found {_show(kind, value)}", col)
        if not stmts:
            raise ScriptError("empty script", 0)
        return stmts

    def expr(self, min_bp: int) -> tuple:
        self.nesting += 1
        if self.nesting > MAX_DEPTH:
            raise ScriptError(f"expression nested deeper than {MAX_DEPTH} levels", self.peek()[2])
        left = self.prefix()
        while True:
            kind, op, col = self.peek()
            bp = _INFIX.get(op, -1) if kind == "op" else -1
            if bp < min_bp or bp < 0:
                break
            self.pos += 1
            if bp == 1:  # assignment, right-associative
                if left[0] != "name":
                    raise ScriptError(f"left side of '{op}' must be a blackboard entry name", col)
                if op in (":=", "="):  # a plain assignment does not read its target
                    del self.reads[left[1]]
                self.writes.add(left[3])
                if op == ":=":
                    self.creates.add(left[3])
                left = self.node("assign", col, self.expr(1), payload=(op, left[3]))
            elif bp == 2:  # ternary: c ? a : b
                then = self.expr(1)
                self.expect(":")
                left = self.node("if", col, left, then, self.expr(2))
            elif bp == 5:  # comparison, non-associative
                left = self.node("cmp", col, left, self.expr(6), payload=(op,))
                kind, op, col = self.peek()
                if kind == "op" and op in _COMPARE:
                    raise ScriptError("comparisons cannot be chained; combine them with &&", col)
            else:
                if (
                    bp in (9, 10)
                    and left[0] == "bin"
                    and left[3] in ("-", "/", "%")
                    and _INFIX[left[3]] == bp
                    and id(left) not in self.grouped
                ):
                    self.regrouped.append(col)
                left = self.node("bin", col, left, self.expr(bp + 1), payload=(op,))
        self.nesting -= 1
        return left

    def prefix(self) -> tuple:
        kind, value, col = self.next()
        if kind in ("num", "str"):
            return self.node("const", col, payload=(value,))
        if kind == "name":
            self.reads[col] = value
            return self.node("name", col, payload=(value,))
        if kind == "op" and value in _UNARY:
            return self.node("unary", col, self.expr(_UNARY_BP), payload=(value,))
        if kind == "op" and value == "(":
            inner = self.expr(0)
            self.expect(")")
            self.grouped.add(id(inner))
            return inner
        raise ScriptError(f"expected a value but found {_show(kind, value)}", col)


def _show(kind: str, value: Any) -> str:
    if kind == "end":
        return "end of script"
    return f"'{value}'" if kind in ("op", "name") else repr(value)


# --------------------------------------------------------------------------- compiler


_CAUGHT = (_OpError, ArithmeticError, TypeError, ValueError)  # the last: exotic entry types


def _fail(e: Exception, op: str, col: int) -> ScriptError:
    detail = str(e) if isinstance(e, _OpError) else f"{type(e).__name__}: {e}"
    return ScriptError(f"operator '{op}': {detail}", col)


def _compile(node: tuple) -> Evaluator:
    kind, col = node[0], node[1]
    if kind == "const":
        value = node[3]
        return lambda env, enums: value
    if kind == "name":
        return _compile_name(node[3], col)
    if kind == "if":
        c, a, b = (_compile(k) for k in node[3:6])

        def ternary(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
            try:
                cond = _truth(c(env, enums))
            except _CAUGHT as e:
                raise _fail(e, "?", col) from None
            return a(env, enums) if cond else b(env, enums)

        return ternary
    if kind == "cmp":
        return _compile_cmp(node[3], _compile(node[4]), _compile(node[5]), col)
    if kind == "assign":
        return _compile_assign(node[3], node[4], _compile(node[5]), col)
    op, arg = node[3], _compile(node[4])
    if kind == "unary":
        f = _UNARY[op]

        def unary(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
            try:
                return f(arg(env, enums))
            except _CAUGHT as e:
                raise _fail(e, op, col) from None

        return unary
    left, right = arg, _compile(node[5])
    if op in ("&&", "||"):
        is_and = op == "&&"

        def logic(env: ScriptEnv, enums: Mapping[str, int]) -> bool:
            try:
                if _truth(left(env, enums)) is not is_and:
                    return not is_and
                return _truth(right(env, enums))
            except _CAUGHT as e:
                raise _fail(e, op, col) from None

        return logic
    g = _BINARY[op]

    def binary(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
        try:
            return g(left(env, enums), right(env, enums))
        except _CAUGHT as e:
            raise _fail(e, op, col) from None

    return binary


def _compile_name(key: str, col: int) -> Evaluator:
    missing = object()

    def name(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
        value = enums.get(key, missing) if enums else missing
        if value is missing:
            try:
                value = env.get(key)
            except KeyError:
                raise ScriptError(f"unknown blackboard entry '{key}'", col) from None
        return value

    return name


def _compile_cmp(op: str, left: Evaluator, right: Evaluator, col: int) -> Evaluator:
    test, ordered = _COMPARE[op], op[0] in "<>"

    def compare(env: ScriptEnv, enums: Mapping[str, int]) -> bool:
        try:
            return test(*_operands(left(env, enums), right(env, enums), enums, ordered))
        except _CAUGHT as e:
            raise _fail(e, op, col) from None

    return compare


def _compile_assign(op: str, key: str, rhs: Evaluator, col: int) -> Evaluator:
    f = _BINARY.get(op[0])

    def assign(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
        if enums and key in enums:
            raise ScriptError(f"cannot assign to enum constant '{key}'", col)
        if op == "=" and not env.has(key):
            msg = f"blackboard entry '{key}' does not exist; use ':=' to create it"
            raise ScriptError(msg, col)
        if f is None:  # := or =
            value = rhs(env, enums)
        else:
            if not env.has(key):
                raise ScriptError(f"blackboard entry '{key}' does not exist", col)
            value = rhs(env, enums)
            try:
                value = f(env.get(key), value)
            except _CAUGHT as e:
                raise _fail(e, op, col) from None
        env.set(key, value)
        return value

    return assign


# --------------------------------------------------------------------------- entry point


@functools.lru_cache(maxsize=2048)
def _parse_cached(code: str) -> Script:
    parser = _Parser(code)
    stmts = [_compile(s) for s in parser.statements()]
    if len(stmts) == 1:
        run = stmts[0]
    else:
        head, last = tuple(stmts[:-1]), stmts[-1]

        def run(env: ScriptEnv, enums: Mapping[str, int]) -> Any:
            for stmt in head:
                stmt(env, enums)
            return last(env, enums)

    reads, writes = frozenset(parser.reads.values()), frozenset(parser.writes)
    return Script(code, reads, writes, run, frozenset(parser.creates), tuple(parser.regrouped))


def parse_script(code: str) -> Script:
    """Parse ``code`` into a reusable :class:`Script` (results are cached by source text).

    Raises :class:`ScriptError` (with the 0-based column) on syntax errors, on sources longer
    than ``MAX_SOURCE_LENGTH`` characters and on nesting deeper than ``MAX_DEPTH``.
    """
    if not isinstance(code, str):
        raise ScriptError(f"script must be a string, not {type(code).__name__}")
    if len(code) > MAX_SOURCE_LENGTH:
        raise ScriptError(f"script longer than {MAX_SOURCE_LENGTH} characters", MAX_SOURCE_LENGTH)
    return _parse_cached(code)


def _constant(node: tuple) -> bool:
    """True when ``node`` reads and writes no entry: its value is the same at every run."""
    if node[0] == "const":
        return True
    if node[0] in ("name", "assign"):
        return False
    return all(_constant(k) for k in node[3:] if isinstance(k, tuple))


def _first_constant_failure(node: tuple) -> ScriptError | None:
    if node[0] == "const":
        return None
    if node[0] != "name" and _constant(node):
        try:
            Script("", frozenset(), frozenset(), _compile(node)).execute(DictEnv())
        except ScriptError as exc:
            return exc
        return None
    for kid in node[3:]:
        if isinstance(kid, tuple):
            found = _first_constant_failure(kid)
            if found is not None:
                return found
    return None


def constant_failure(code: str) -> ScriptError | None:
    """The error a part of ``code`` made of literals alone raises whenever it is evaluated
    (``1 / 0``, ``'a' - 1``, ``x ? 5 % 0 : 1``), or None; None too when ``code`` does not
    parse (:func:`parse_script` says why). The largest such parts are tried, as they run:
    ``false && 1 / 0`` never fails. Validation refuses these before flight; at run time they
    fail as BehaviorTree.CPP's scripts do."""
    try:
        parse_script(code)
        statements = _Parser(code).statements()
    except ScriptError:
        return None
    for statement in statements:
        found = _first_constant_failure(statement)
        if found is not None:
            return found
    return None
