"""Hostile values against the engine's parsers and the script interpreter: linear-time
parsing of durations and numbers, bounded digits, bounded text built by scripts.

Quadratic regular expressions run inside the C regex engine, where neither a signal nor
Ctrl-C stops them; the tests that feed them megabytes run in a child process, and the
child's time limit only keeps a broken build from hanging the test run (the fixed parsers
answer in milliseconds): no test measures time.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import tracemalloc

import pytest
from helpers import REPO, wrap, xml_mission

from bt_engine import Runner
from bt_engine.node import NodeRuntimeError
from bt_engine.ports import DURATION, PortValueError
from bt_engine.script import DictEnv, ScriptError, _str_num, parse_script

# the limits of bt_engine.script, spelt out so that each test names the value it relies on
MAX_NUMBER_LENGTH, MAX_STRING_LENGTH, MAX_TEXT_PER_RUN = 400, 65_536, 1_048_576

HANG_GUARD_S = 120  # not a performance bound: the fixed code answers in milliseconds


def _in_child(code: str) -> str:
    """Run ``code`` in a fresh interpreter (hang guard); return what it printed."""
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


# ---------------------------------------------------------------------- durations


@pytest.mark.parametrize(
    "text, seconds",
    [
        ("2.5", 2.5),
        (" 2.5s ", 2.5),
        ("500ms", 0.5),
        ("500 ms", 0.5),
        ("1min", 60.0),
        ("+3.", 3.0),
        ("1e3ms", 1.0),
        ("0", 0.0),
    ],
)
def test_durations_still_parse(text, seconds):
    assert DURATION.convert(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["", "s", ".5", "1e", "5 m", "5 sec", "-1", "1 2", "5MS", "1e999"])
def test_bad_durations_are_refused(text):
    with pytest.raises(PortValueError):
        DURATION.convert(text)


def test_duration_with_a_megabyte_of_spaces_is_parsed_in_linear_time():
    """The old pattern ``\\s*(ms|s|min)?\\s*$`` tried every split of the trailing spaces."""
    out = _in_child(
        """
        from bt_engine.ports import DURATION, PortValueError
        spaces = " " * 1_000_000
        print(DURATION.convert("1" + spaces + "s" + spaces))
        try:
            DURATION.convert("1" + spaces + "x")
        except PortValueError as exc:
            print(len(str(exc)) < 300)
        """
    )
    assert out.split() == ["1.0", "True"]


def test_validating_a_file_of_duration_spaces_is_linear(tmp_path):
    path = tmp_path / "d.xml"
    spaces = " " * 2_000_000
    path.write_text(wrap(f'<Hover duration="1{spaces}x"/>'))
    out = _in_child(
        f"""
        from bt_engine.cli import main
        print(main(["validate", {str(path)!r}]))
        """
    )
    assert out.strip() == "2"


# ------------------------------------------------------------------------ numbers


def test_limits_are_module_constants():
    from bt_engine import script

    assert script.MAX_NUMBER_LENGTH == MAX_NUMBER_LENGTH
    assert (script.MAX_STRING_LENGTH, script.MAX_TEXT_PER_RUN) == (
        MAX_STRING_LENGTH,
        MAX_TEXT_PER_RUN,
    )


def test_numeric_strings_are_bounded_in_length():
    assert _str_num("1" * MAX_NUMBER_LENGTH) == float("1" * MAX_NUMBER_LENGTH)
    assert _str_num("1" * (MAX_NUMBER_LENGTH + 1)) is None
    assert _str_num(" 0x1F ") == 31 and _str_num("-.5e-3") == -0.0005 and _str_num("5.") == 5.0
    assert _str_num("1e") is None and _str_num("1.2.3") is None and _str_num("true") is True


def test_long_number_literal_is_a_script_error():
    with pytest.raises(ScriptError, match="MAX_NUMBER_LENGTH"):
        parse_script("x := " + "9" * (MAX_NUMBER_LENGTH + 1))
    assert parse_script("9" * MAX_NUMBER_LENGTH).execute(DictEnv()) == float(
        "9" * MAX_NUMBER_LENGTH
    )


def test_comparing_a_164k_digit_string_with_a_number_is_linear():
    """``\\d+\\.?\\d*`` backtracked over every split of the digits (and Ctrl-C could not stop it)."""
    out = _in_child(
        """
        from bt_engine.script import DictEnv, ScriptError, parse_script
        env = DictEnv({"x": "1" * 164_000 + "x", "y": "7" * 164_000})
        for code in ("x == 1", "y == 1", "y < 2"):
            try:
                parse_script(code).execute(env)
            except ScriptError as exc:
                print("MAX_NUMBER_LENGTH" in str(exc) and len(str(exc)) < 300)
        """
    )
    assert out.split() == ["True", "True", "True"]


# ---------------------------------------------------------------- amplification


def _doubling(start: int, times: int) -> str:
    return f"s := '{'x' * start}'; " + " ".join("s := s .. s;" for _ in range(times))


def test_string_doubling_stops_at_the_length_limit():
    with pytest.raises(ScriptError, match=r"MAX_STRING_LENGTH") as info:
        parse_script(_doubling(64, 13)).execute(DictEnv())
    assert f"longer than {MAX_STRING_LENGTH} characters" in str(info.value)
    env = DictEnv()
    parse_script(_doubling(64, 10)).execute(env)  # exactly the limit is fine
    assert len(env.data["s"]) == MAX_STRING_LENGTH


def test_text_built_by_one_run_is_bounded():
    code = _doubling(64, 9) + " " + " ".join(f"a{i} := s .. s;" for i in range(40))
    with pytest.raises(ScriptError, match=r"MAX_TEXT_PER_RUN"):
        parse_script(code).execute(DictEnv())
    env = DictEnv()
    small = _doubling(64, 9) + " " + " ".join(f"a{i} := s .. s;" for i in range(10))
    parse_script(small).execute(env)  # well under the budget: runs, and runs again
    parse_script(small).execute(env)
    assert len(env.data["a9"]) == 2 * 64 * 2**9


def test_a_9kb_script_cannot_take_hundreds_of_megabytes():
    """The attack: double a string to the limit, then copy it into hundreds of entries."""
    code = _doubling(64, 10) + " " + "".join(f"e{i}:=s..'';" for i in range(600))
    assert len(code) < 9_500  # before the limits: 600 copies of a 64 KiB string
    tracemalloc.start()
    try:
        with pytest.raises(ScriptError, match=r"MAX_STRING_LENGTH|MAX_TEXT_PER_RUN"):
            parse_script(code).execute(DictEnv())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 * MAX_TEXT_PER_RUN + 8 * MAX_STRING_LENGTH


def test_amplification_in_a_script_node_is_the_node_s_located_failure():
    m = xml_mission(wrap('<Script name="grow" code="' + _doubling(64, 13) + '"/>'))
    with pytest.raises(NodeRuntimeError) as info:
        m.tick()
    message = str(info.value)
    assert message.startswith("inline.xml:3:1: Script 'grow': script ")
    assert "MAX_STRING_LENGTH" in message
    result = Runner(xml_mission(wrap('<Script code="' + _doubling(64, 13) + '"/>'))).run(10.0)
    assert result.status == "ABORTED" and "inline.xml:3:1" in result.reason
    assert "MAX_STRING_LENGTH" in result.reason


def test_integers_never_grow_without_bound():
    env = DictEnv({"n": 3})
    square = parse_script("n *= n")
    for _ in range(40):
        square.execute(env)
    assert isinstance(env.data["n"], float)  # int64 overflow became a double, like BT.CPP


def test_port_errors_quote_huge_values_briefly():
    from bt_engine.ports import VEC3

    for value in (";" * 1_000_000, "x" * 1_000_000):
        with pytest.raises(PortValueError) as info:
            VEC3.convert(value)
        assert len(str(info.value)) < 400
    with pytest.raises(PortValueError, match=r"got 2 value\(s\) in '8.9;1.1'"):
        VEC3.convert("8.9;1.1")
