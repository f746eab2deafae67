"""Specification of the btrun script language (BehaviorTree.CPP v4 scripting dialect)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bt_engine.script import (
    MAX_DEPTH,
    MAX_SOURCE_LENGTH,
    DictEnv,
    Script,
    ScriptEnv,
    ScriptError,
    parse_script,
)

ENUMS = {"FIXED_YAW": 2, "RED": 1, "BLUE": 3}


def run(code: str, enums: dict[str, int] | None = None, **entries: object) -> object:
    """Execute ``code`` against a fresh blackboard holding ``entries``."""
    return parse_script(code).execute(DictEnv(dict(entries)), enums)


def error(code: str, enums: dict[str, int] | None = None, **entries: object) -> ScriptError:
    """Parse and execute ``code``, which must fail with a ScriptError; return it."""
    with pytest.raises(ScriptError) as info:
        run(code, enums, **entries)
    return info.value


# --------------------------------------------------------------------------- literals


@pytest.mark.parametrize(
    ("code", "value"),
    [
        ("42", 42),
        ("2.5", 2.5),
        (".5", 0.5),
        ("1e3", 1000.0),
        ("1.5E-2", 0.015),
        ("0x1F", 31),
        ("0xff", 255),
        ("'hello world'", "hello world"),
        ('"double quotes"', "double quotes"),
        ("'it''s'", None),  # no escapes: two adjacent strings are a syntax error
        ("''", ""),
        ("true", True),
        ("false", False),
        ("  7  ", 7),
        ("9223372036854775807", 2**63 - 1),
        ("9223372036854775808", 9.223372036854775808e18),  # beyond int64 -> float
    ],
)
def test_literals(code: str, value: object) -> None:
    if value is None:
        assert error(code).column == 4
    else:
        result = run(code)
        assert result == value and type(result) is type(value)


def test_hex_literal_must_fit_in_64_bits() -> None:
    assert error("1 + 0x10000000000000000").column == 4


# --------------------------------------------------------------------------- operators


@pytest.mark.parametrize(
    ("code", "value"),
    [
        # arithmetic: int op int stays int, except / which is true division (like BT.CPP's double)
        ("7 + 2", 9),
        ("7 - 2", 5),
        ("7 * 2", 14),
        ("7 / 2", 3.5),
        ("8 / 2", 4.0),
        ("7 % 3", 1),
        ("-7 % 3", -1),  # C semantics: the sign follows the dividend
        ("7 % -3", 1),
        ("7.5 % 2", 1.5),
        ("1 + 2.5", 3.5),
        ("true + 1", 2),
        ("9223372036854775807 + 1", 9.223372036854775808e18),  # leaves int64 -> float
        # unary
        ("-3", -3),
        ("--3", 3),
        ("-2.5", -2.5),
        ("!true", False),
        ("!0", True),
        ("!''", True),
        ("not false", True),
        ("~0", -1),
        ("~5", -6),
        # bitwise
        ("6 & 3", 2),
        ("6 | 3", 7),
        ("6 ^ 3", 5),
        ("0xF0 | 0x0F", 255),
        ("4.0 & 5", 4),  # integral floats are accepted
        # strings
        ("'a' + 'b'", "ab"),
        ("'a' .. 'b'", "ab"),
        ("'n=' .. 3", "n=3"),
        ("'x=' .. 2.5 .. ', ok=' .. true", "x=2.5, ok=true"),
        ("1 .. 2", "12"),
        # comparisons give bools
        ("1 == 1", True),
        ("1 != 1", False),
        ("1 < 2", True),
        ("2 > 1", True),
        ("2 <= 2", True),
        ("2 >= 3", False),
        ("1 == 1.0", True),
        ("0.1 + 0.2 == 0.3", True),  # BT.CPP compares doubles with float epsilon
        ("1.0 == 1.001", False),
        ("'abc' == 'abc'", True),
        ("'abc' < 'abd'", True),
        ("'10' < '9'", True),  # two strings compare as text
        ("true == 1", True),
        # logic
        ("true && false", False),
        ("true || false", True),
        ("1 and 2", True),
        ("0 or ''", False),
        ("'yes' && 3", True),
        # ternary
        ("true ? 'a' : 'b'", "a"),
        ("0 ? 'a' : 'b'", "b"),
        ("false ? 1 : true ? 2 : 3", 2),
        ("'false' ? 1 : 2", 2),  # a string spelling a bool is converted
    ],
)
def test_operators(code: str, value: object) -> None:
    result = run(code)
    assert result == value and type(result) is type(value)


@pytest.mark.parametrize(
    ("code", "value"),
    [
        ("1 + 2 * 3", 7),
        ("(1 + 2) * 3", 9),
        ("10 - 4 - 3", 3),  # left-associative
        ("64 / 4 / 2", 8.0),
        ("2 * 3 % 4", 2),
        ("-2 * 3", -6),
        ("-(2 + 3)", -5),
        ("!false == true", True),  # unary binds tightest
        ("1 + 2 == 3", True),  # arithmetic above comparison
        ("6 & 3 == 2", True),  # bitwise above comparison (BT.CPP), unlike C
        ("1 | 2 & 0", 1),  # & above | and ^
        ("1 + 1 & 3", 2),  # arithmetic above bitwise
        ("'v' .. 1 + 2", "v3"),  # arithmetic above ..
        ("'ab' .. 'c' == 'abc'", True),  # .. above comparison
        ("1 < 2 && 3 < 4", True),  # comparison above logic
        ("true || true && false", True),  # && above || (C rules; BT.CPP has them equal)
        ("false && true || true", True),
        ("true ? 1 : 0 + 10", 1),  # ternary below everything but assignment
        ("false || true ? 'y' : 'n'", "y"),
    ],
)
def test_precedence(code: str, value: object) -> None:
    assert run(code) == value


def test_logic_short_circuits() -> None:
    env = DictEnv({"x": 0})
    assert parse_script("x != 0 && 10 / x > 1").execute(env) is False
    assert parse_script("x == 0 || missing").execute(env) is True
    parse_script("false && (y := 1); true || (y := 2)").execute(env)
    assert not env.has("y")


def test_ternary_evaluates_only_the_chosen_branch() -> None:
    assert run("true ? 1 : missing") == 1
    assert run("false ? 1 / 0 : 'ok'") == "ok"


# --------------------------------------------------------------------------- blackboard


def test_names_read_the_blackboard() -> None:
    assert run("speed * 2", speed=1.5) == 3.0
    assert run("snake_case_2 + 1", snake_case_2=1) == 2


def test_root_keys_keep_their_at_sign() -> None:
    env = DictEnv({"@mode": "takeoff"})
    assert parse_script("@mode == 'takeoff'").execute(env) is True
    parse_script("@target := 3").execute(env)
    assert env.data == {"@mode": "takeoff", "@target": 3}


def test_create_assignment_creates_or_overwrites() -> None:
    env = DictEnv()
    script = parse_script("count := 1")
    assert script.execute(env) == 1
    assert env.data == {"count": 1}
    parse_script("count := 'one'").execute(env)
    assert env.data == {"count": "one"}


def test_plain_assignment_requires_an_existing_entry() -> None:
    env = DictEnv({"x": 1})
    assert parse_script("x = 5").execute(env) == 5
    assert env.data["x"] == 5
    err = error("y = 5", x=1)
    assert "does not exist" in err.message and ":=" in err.message
    assert err.column == 2


def test_assignment_is_not_equality() -> None:
    assert error("x = = 1", x=1).column == 4
    assert run("x == 1", x=1) is True


@pytest.mark.parametrize(
    ("code", "start", "value"),
    [
        ("n += 2", 5, 7),
        ("n -= 2", 5, 3),
        ("n *= 2", 5, 10),
        ("n /= 2", 5, 2.5),
        ("n %= 2", 5, 1),
        ("n += ' world'", "hello", "hello world"),
        ("n += 1", "41", 42),  # numeric string from XML is converted
    ],
)
def test_compound_assignment(code: str, start: object, value: object) -> None:
    env = DictEnv({"n": start})
    assert parse_script(code).execute(env) == value
    assert env.data["n"] == value


def test_compound_assignment_requires_an_existing_entry() -> None:
    err = error("total += 1")
    assert "total" in err.message and err.column == 6


def test_assignment_is_right_associative_and_returns_the_value() -> None:
    env = DictEnv()
    assert parse_script("a := b := 4").execute(env) == 4
    assert env.data == {"a": 4, "b": 4}


def test_statements_run_in_order_and_the_last_gives_the_value() -> None:
    env = DictEnv()
    assert parse_script("a := 1; b := a + 1; a + b").execute(env) == 3
    assert parse_script("a := 5;").execute(env) == 5  # trailing ; allowed
    assert parse_script(";; a ;;").execute(env) == 5


@pytest.mark.parametrize("code", ["1 := 2", "(a + b) := 1", "a + b = 1", "-x += 1", "RED + 1 = 3"])
def test_assignment_target_must_be_a_name(code: str) -> None:
    err = error(code, a=1, b=2, x=3)
    assert "must be a blackboard entry name" in err.message


def test_numeric_strings_are_converted_when_mixed_with_numbers() -> None:
    assert run("alt > 1.5", alt="2.0") is True
    assert run("count == 3", count="3") is True
    assert run("mask & 1", mask="0x3") == 1
    assert run("x - 1", x=" 10 ") == 9
    assert run("armed == true", armed="true") is True
    assert run("n + 1", n="1") == 2
    assert run("'1' + '1'") == "11"  # but two strings concatenate


def test_truthiness_of_strings() -> None:
    assert run("s ? 1 : 0", s="0") == 0
    assert run("s ? 1 : 0", s="FALSE") == 0
    assert run("s ? 1 : 0", s="") == 0
    assert run("s ? 1 : 0", s="anything") == 1


def test_equality_between_non_scalar_entries() -> None:
    assert run("a == b", a=[1, 2], b=[1, 2]) is True
    assert run("a != 1", a=[1]) is True
    assert error("a < b", a=[1], b=[2]).column == 2


def test_numpy_like_numbers_are_numbers() -> None:
    np = pytest.importorskip("numpy")
    assert run("x * 2", x=np.float64(1.5)) == 3.0
    assert run("x + 1 == 3", x=np.int64(2)) is True
    assert run("x & 1", x=np.int32(3)) == 1


# --------------------------------------------------------------------------- enums


def test_enums_evaluate_to_integers() -> None:
    assert run("FIXED_YAW", ENUMS) == 2
    assert run("mode == FIXED_YAW", ENUMS, mode=2) is True
    assert run("color := RED; color", ENUMS) == 1


def test_enums_shadow_entries_and_cannot_be_assigned() -> None:
    assert run("RED", ENUMS, RED=99) == 1
    err = error("RED := 5", ENUMS)
    assert "enum" in err.message and err.column == 4


def test_string_holding_an_enum_name_compares_with_the_enum() -> None:
    assert run("color == BLUE", ENUMS, color="BLUE") is True
    assert run("color != RED", ENUMS, color="BLUE") is True


def test_without_enums_an_enum_name_is_an_unknown_entry() -> None:
    err = error("FIXED_YAW")
    assert "unknown blackboard entry 'FIXED_YAW'" in err.message


# --------------------------------------------------------------------------- reads / writes


@pytest.mark.parametrize(
    ("code", "reads", "writes"),
    [
        ("a + b", {"a", "b"}, set()),
        ("a := 1", set(), {"a"}),
        ("a = b", {"b"}, {"a"}),
        ("a += 1", {"a"}, {"a"}),
        ("a := a + 1", {"a"}, {"a"}),
        ("@x := y; z ? @x : w", {"y", "z", "@x", "w"}, {"@x"}),
        ("'a' .. 1", set(), set()),
        ("FIXED_YAW == m", {"FIXED_YAW", "m"}, set()),  # enums are only known at run time
    ],
)
def test_reads_and_writes(code: str, reads: set[str], writes: set[str]) -> None:
    script = parse_script(code)
    assert script.reads == frozenset(reads)
    assert script.writes == frozenset(writes)
    assert isinstance(script.reads, frozenset) and isinstance(script.writes, frozenset)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("code", "column", "fragment"),
    [
        ("", 0, "empty script"),
        ("   ", 0, "empty script"),
        ("1 +", 3, "expected a value"),
        ("(1 + 2", 6, "expected ')'"),
        ("1 + 2)", 5, "expected ';'"),
        ("a b", 2, "expected ';'"),
        ("'open", 0, "unterminated string"),
        ("x := 'a", 5, "unterminated string"),
        ("1 # 2", 2, "unexpected character '#'"),
        ("a.b", 1, "unexpected character '.'"),
        ("@", 0, "unexpected character '@'"),
        ("true ? 1", 8, "expected ':'"),
        ("1 < 2 < 3", 6, "cannot be chained"),
        ("*3", 0, "expected a value"),
        ("a = ", 4, "expected a value"),
    ],
)
def test_syntax_errors_have_columns(code: str, column: int, fragment: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_script(code)
    assert info.value.column == column
    assert fragment in info.value.message
    assert str(info.value) == info.value.message


@pytest.mark.parametrize(
    ("code", "column", "fragment"),
    [
        ("1 / 0", 2, "division by zero"),
        ("1.5 / 0.0", 4, "division by zero"),
        ("x /= 0", 2, "division by zero"),
        ("5 % 0", 2, "modulo by zero"),
        ("1 + nope", 4, "unknown blackboard entry 'nope'"),
        ("'a' - 1", 4, "expected a number, got string 'a'"),
        ("-'a'", 0, "expected a number"),
        ("'a' * 2", 4, "expected a number"),
        ("1.5 & 1", 4, "need integers"),
        ("~'x'", 0, "expected a number"),
        ("'a' < 1", 4, "cannot compare"),
        ("1 == 'one'", 2, "cannot compare"),
        ("n ? 1 : 2", 2, "None"),
        ("n + 1", 2, "None"),
        ("s += 1", 2, "expected a number"),
    ],
)
def test_runtime_errors_have_columns(code: str, column: int, fragment: str) -> None:
    err = error(code, x=1, n=None, s="text")
    assert err.column == column
    assert fragment in err.message


def test_failed_statement_stops_the_script() -> None:
    env = DictEnv()
    with pytest.raises(ScriptError):
        parse_script("a := 1; b := 1 / 0; c := 3").execute(env)
    assert env.data == {"a": 1}


def test_script_error_defaults_to_unknown_column() -> None:
    assert ScriptError("boom").column == -1
    assert ScriptError("boom", 3).column == 3


# --------------------------------------------------------------------------- hostile input


def test_source_length_is_limited() -> None:
    assert run("1" + " " * (MAX_SOURCE_LENGTH - 1)) == 1
    with pytest.raises(ScriptError, match="longer than"):
        parse_script("1" * (MAX_SOURCE_LENGTH + 1))


@pytest.mark.parametrize(
    "code",
    [
        "(" * 4000 + "1" + ")" * 4000,
        "-" * 9000 + "1",
        "!" * 9000 + "1",
        "+".join(["1"] * 4000),
        "a := " * 1500 + "1",
        "true ? " * 800 + "1" + " : 0" * 800,
        "x .. " * 1500 + "x",
    ],
)
def test_deep_nesting_is_a_script_error_not_a_recursion_error(code: str) -> None:
    with pytest.raises(ScriptError, match="nested deeper"):
        parse_script(code)


def test_moderate_nesting_is_fine() -> None:
    depth = MAX_DEPTH // 2
    assert run("(" * depth + "1" + ")" * depth) == 1
    assert run("+".join(["1"] * depth)) == depth


def test_runaway_growth_is_bounded() -> None:
    env = DictEnv({"n": 3, "s": "ab"})
    square, double = parse_script("n *= n"), parse_script("s := s .. s")
    for _ in range(12):
        square.execute(env)
    assert isinstance(env.data["n"], float)  # left int64: became a double, like BT.CPP
    with pytest.raises(ScriptError, match="string longer"):
        for _ in range(40):
            double.execute(env)


def test_python_is_not_reachable() -> None:
    for code in ["__import__('os')", "x.__class__", "open('f')", "[1]", "{}", "lambda: 1"]:
        with pytest.raises(ScriptError):
            run(code, x=1)


def test_non_string_source_is_a_script_error() -> None:
    with pytest.raises(ScriptError):
        parse_script(None)  # type: ignore[arg-type]
    with pytest.raises(ScriptError):
        parse_script(["x"])  # type: ignore[arg-type]


_SCRIPT_CHARS = st.sampled_from(
    list("0123456789abxyz_@.'\" ()!~-+*/%&|^<>=:?;\t\n")
    + ["x", "0x", "1e9", ":=", "..", "&&", "||", "==", "true", "not ", " and ", "RED", "'3'"]
)


@settings(max_examples=400, deadline=None)
@given(st.one_of(st.text(max_size=60), st.lists(_SCRIPT_CHARS, max_size=40).map("".join)))
def test_random_input_only_ever_raises_script_error(code: str) -> None:
    entries = {"x": 3, "y": 0.5, "z": "7", "a": "text", "b": True, "@x": 1, "ab": None}
    try:
        script = parse_script(code)
    except ScriptError as err:
        assert -1 <= err.column <= len(code)
        return
    env = DictEnv(dict(entries))
    try:
        script.execute(env, ENUMS)
    except ScriptError as err:
        assert -1 <= err.column <= len(code)
    assert set(env.data) - set(entries) <= script.writes


# --------------------------------------------------------------------------- the API


def test_parse_results_are_cached_and_reusable() -> None:
    assert parse_script("x + 1") is parse_script("x + 1")
    script = parse_script("x + 1")
    assert script.source == "x + 1"
    assert [script.execute(DictEnv({"x": i})) for i in range(3)] == [1, 2, 3]


def test_dict_env_is_a_script_env_over_the_given_dict() -> None:
    data: dict[str, object] = {}
    env = DictEnv(data)
    assert isinstance(env, ScriptEnv)
    env.set("k", 1)
    assert data == {"k": 1} and env.has("k") and env.get("k") == 1
    with pytest.raises(KeyError):
        env.get("missing")


class _CountingEnv:
    """A custom environment: scripts only use get/set/has."""

    def __init__(self) -> None:
        self.data: dict[str, object] = {"v": 1}
        self.calls: list[str] = []

    def get(self, key: str) -> object:
        self.calls.append(f"get {key}")
        return self.data[key]

    def set(self, key: str, value: object) -> None:
        self.calls.append(f"set {key}")
        self.data[key] = value

    def has(self, key: str) -> bool:
        self.calls.append(f"has {key}")
        return key in self.data


def test_custom_environment() -> None:
    env = _CountingEnv()
    assert parse_script("v = v + 1").execute(env) == 2
    assert env.calls == ["has v", "get v", "set v"]


def test_script_object_shape() -> None:
    script = parse_script("a := b")
    assert isinstance(script, Script)
    assert repr(script) == "Script('a := b')"
    assert math.isclose(parse_script("1 / 3").execute(DictEnv()), 1 / 3)
