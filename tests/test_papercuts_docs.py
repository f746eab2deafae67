"""User reports on the help texts, the node catalogue, the docs and summary.json: each test
reads what a user reads (a help text, the README, a doc, ``btrun nodes``, summary.json) and
checks it against what btrun does."""

from __future__ import annotations

import argparse
import glob
import os
import re

import pytest
from helpers import REPO

import nodes  # noqa: F401  (register the drone leaves before the registry is read)
from bt_engine.catalogue import (
    catalogue_markdown,
    catalogue_text,
    doc_blocks,
    groot_palette,
    markdown_text,
    node_summary,
    plain_text,
)
from bt_engine.registry import REGISTRY


def _read(*parts: str) -> str:
    with open(os.path.join(REPO, *parts), encoding="utf-8") as f:
        return f.read()


# -- 1. every --set example names a key the rig loader takes ------------------------------

#: ``--set KEY=VALUE`` in prose and command lines (quoted or not)
_SET_EXAMPLE = re.compile(r"--set[ =]+[\"']?([A-Za-z_][\w.\-]*)=([^\s\"'`),;\]]+)")
#: a bare ``KEY=VALUE`` in the help of the --set option itself
_HELP_EXAMPLE = re.compile(r"(?<![\w.])([A-Za-z_]\w*(?:\.\w+)+)=([^\s,;)]+)")
#: the docs' stand-ins for any key or value (dotted.key=value, world.KEY=VALUE, x.y=...)
_PLACEHOLDER_VALUES = {"value", "VALUE", "...", "v"}


def _parsers(parser: argparse.ArgumentParser, name: str = "btrun"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def _help_examples() -> list[tuple[str, str, str, str | None]]:
    """(where, key, value, rig) of every rig/world key in ``btrun ... --help``."""
    from bt_engine.cli import _parser
    from bt_engine.plugins import plugin_commands

    out = []
    for name, parser in _parsers(_parser(plugin_commands())):
        texts = [parser.description or "", parser.epilog or ""]
        for action in parser._actions:
            text = action.help or ""
            if "--set" in action.option_strings:
                out += [(f"{name} --set", k, v, None) for k, v in _HELP_EXAMPLE.findall(text)]
            texts.append(text)
        for text in texts:
            out += [(name, k, v, None) for k, v in _SET_EXAMPLE.findall(text)]
    return out


def _fleet_rig(fleet: str) -> str:
    """The rig a fleet file flies (a fleet command's ``--set`` applies to it)."""
    import yaml

    path = os.path.join(REPO, fleet)
    rig = yaml.safe_load(open(path))["rig"]
    return os.path.normpath(os.path.join(os.path.dirname(path), rig))


def _doc_examples() -> list[tuple[str, str, str, str | None]]:
    """(file:line, key, value, the line's --rig) of every ``--set`` in README and docs/."""
    out = []
    for path in ["README.md", *sorted(glob.glob(os.path.join(REPO, "docs", "*.md")))]:
        rel = os.path.relpath(os.path.join(REPO, path), REPO)
        for n, line in enumerate(_read(rel).splitlines(), 1):
            rig = re.search(r"--rig[ =]+(\S+)", line)
            fleet = re.search(r"(?:--fleet[ =]+|btrun fleet )(fleets/\S+\.yaml)", line)
            where = rig.group(1) if rig else _fleet_rig(fleet.group(1)) if fleet else None
            for key, value in _SET_EXAMPLE.findall(line):
                out.append((f"{rel}:{n}", key, value, where))
    return out


def test_every_set_example_in_help_readme_and_docs_is_a_valid_setting(monkeypatch):
    """``btrun run --help`` used to offer ``rig.realtime=1``, a key no rig has; every dotted
    key shown as a ``--set`` example goes through the loader ``btrun run`` uses."""
    from bt_engine.run_cmd import parse_sets
    from drivers.rig.loader import ConfigError, load_rig

    monkeypatch.chdir(REPO)
    help_examples = _help_examples()
    assert any(where == "btrun run --set" for where, *_ in help_examples)
    examples = help_examples + _doc_examples()
    bad = []
    checked = 0
    for where, key, value, rig in examples:
        if "." not in key or value in _PLACEHOLDER_VALUES:
            continue  # a blackboard input (plain key), or a stand-in for any key
        _, overrides, problems = parse_sets([f"{key}={value}"])
        assert not problems, (where, problems)
        try:
            load_rig(rig, overrides)
        except ConfigError as exc:
            bad.append(f"{where}: --set {key}={value}: {exc}")
        checked += 1
    assert not bad, "\n".join(bad)
    assert checked >= 10


def test_run_help_names_the_real_time_setting():
    text = _squash(_run_help())
    assert "rig.realtime" not in text and "clock.mode=realtime" in text


def _run_help() -> str:
    from bt_engine.cli import _parser

    (sub,) = [a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices["run"].format_help()


# -- 2. btrun nodes: whole first paragraphs, no reStructuredText --------------------------

_RST = re.compile(r"``|:\w+:`|::$", re.M)


def _squash(text: str) -> str:
    return " ".join(text.split())


def test_rst_inline_markup_to_plain_text_and_markdown():
    doc = (
        "Fit the face (:mod:`perception.face`, :class:`~perception.face.Face`) from\n"
        "``blocks``; run ``count := count + 1`` as in :func:`the docs <bt_engine.script>`.\n"
        "\n"
        "Use it so::\n"
        "\n"
        "    Parallel success_count=1\n"
        "    └── DetectBlocks\n"
        "\n"
        "Then `interpreted` text, a | pipe and <tags>."
    )
    blocks = doc_blocks(doc)
    assert [kind for kind, _ in blocks] == ["para", "para", "literal", "para"]
    assert blocks[1] == ("para", "Use it so:")
    assert blocks[2] == ("literal", "Parallel success_count=1\n└── DetectBlocks")
    assert plain_text(blocks[0][1]) == (
        "Fit the face (perception.face, Face) from blocks; run 'count := count + 1' as in the docs."
    )
    assert markdown_text(blocks[0][1]) == (
        "Fit the face (`perception.face`, `Face`) from `blocks`; run `count := count + 1` as "
        "in `the docs`."
    )
    assert plain_text(blocks[3][1]) == "Then interpreted text, a | pipe and <tags>."
    assert markdown_text(blocks[3][1]) == "Then `interpreted` text, a | pipe and \\<tags>."


def test_nodes_listing_shows_whole_first_paragraphs_without_rst():
    listing = catalogue_text(REGISTRY)
    verbose = catalogue_text(REGISTRY, verbose=True)
    palette = groot_palette(REGISTRY, include_builtins=True)
    assert not _RST.search(listing) and not _RST.search(verbose), "RST markup in btrun nodes"
    assert "``" not in palette and ":mod:`" not in palette
    flat = _squash(listing)
    for m in REGISTRY.models():
        paras = [t for kind, t in doc_blocks(m.description) if kind == "para"]
        if not paras:
            continue
        summary = node_summary(m)
        assert summary == plain_text(paras[0]), m.id
        assert _squash(summary) in flat, f"{m.id}: first paragraph not shown whole"
    # the report's examples: a description cut mid-sentence, a role shown raw
    assert "(the voltage reads high while a charging current flows)." in flat  # ChangeBattery
    assert "fit the face (perception.face)." in flat  # LocatePallet, was :mod:`perception.face`
    port = re.compile(r"^      (in |out|i/o) ")
    assert all(len(line) <= 100 for line in listing.splitlines() if not port.match(line))


def test_node_reference_is_markdown():
    """docs/nodes.md (``btrun nodes --markdown``): code spans, fenced literal blocks, table
    cells that keep their pipes; no reStructuredText outside the code blocks."""
    text = _read("docs", "nodes.md")
    assert text == catalogue_markdown(REGISTRY), "run: btrun nodes --markdown docs/nodes.md"
    prose = re.sub(r"```text\n.*?```", "", text, flags=re.S)
    assert "``" not in prose and not re.search(r":\w+:`", prose) and "::\n" not in prose
    assert "(`perception.face`)" in text
    assert "```text\nParallel success_count=1\n" in text
    assert "| waypoints x;y;z\\|x;y;z\\|... in m |" in text


# -- 3. printing a mission's tree and blackboard in Python --------------------------------


def test_btrun_displays_and_why_py_trees_blackboard_display_is_empty():
    import py_trees

    from bt_engine import Mission, Runner, SimClock
    from bt_engine.display import blackboard_text, mission_tree_text
    from drivers.rig.factory import make_platform
    from drivers.rig.loader import load_rig

    clock = SimClock()
    platform = make_platform(load_rig(None), clock, seed=0)
    m = Mission.from_file(
        os.path.join(REPO, "missions", "square.xml"), clock=clock, vehicle=platform.vehicle
    )
    try:
        Runner(m, rate_hz=50, hooks=[platform]).run_until(
            lambda m: m.status_of("corner_1/goto") == "RUNNING"
        )
        tree = mission_tree_text(m).splitlines()
        assert tree[0].startswith("Square  (tick ")
        assert tree[1] == "[*] Sequence 'square'  RUNNING"
        assert any(line.startswith("[+] ├── TakeOff 'takeoff'") for line in tree)
        assert any("GoTo 'goto'" in line and line.endswith("RUNNING") for line in tree)
        bb = blackboard_text(m)
        assert "height" in bb and "square/corner_1/pose : '2;0;1'" in bb
        # what README says: py_trees' display lists none of a mission's entries
        shown = py_trees.display.unicode_blackboard()
        assert "corner_1" not in shown and "/btrun/" not in shown
    finally:
        m.close()
    readme = _read("README.md")
    for name in ("unicode_blackboard", "blackboard_text(m)", "mission_tree_text(m)", "btrun show"):
        assert name in readme


# -- 4. the battery in summary.json ----------------------------------------------------------


def test_summary_battery_names_the_truth_and_the_gauge():
    from drivers.rig.harness import SimHarness
    from drivers.vehicle.battery import ocv_from_soc, percent_from_voltage

    h = SimHarness.create(seed=0)
    p = h.vehicle.takeoff(1.0)
    assert h.run_until(lambda: p.settled, timeout_s=10)
    h.run_for(5.0)
    battery = h.platform.summary()["battery"]
    assert "percent_reported" not in battery
    assert battery["percent_from_voltage"] == round(percent_from_voltage(battery["voltage_v"]), 1)
    assert battery["resting_voltage_v"] == pytest.approx(ocv_from_soc(battery["soc"]), abs=1e-3)
    assert battery["current_a"] > 1.0  # hovering: the voltage reads under load ...
    assert battery["percent_from_voltage"] < 100 * battery["soc"] - 20  # ... far below the charge
    doc = _read("docs", "vehicle.md")
    for key in battery:
        assert f"| `{key}` |" in doc, f"docs/vehicle.md does not explain sim.battery.{key}"


# -- 5. the README's missions table and sample output ---------------------------------------


def _missions_table(readme: str) -> str:
    start = readme.index("Missions (`missions/`")
    table = re.search(r"\n(\|.*\|\n)+", readme[start:])
    assert table is not None
    return table.group(0)


def test_readme_missions_table_names_every_file_in_missions():
    table = _missions_table(_read("README.md"))
    named = set(re.findall(r"`([\w./-]+\.(?:xml|yaml))`", table))
    files = {
        os.path.relpath(p, os.path.join(REPO, "missions"))
        for p in glob.glob(os.path.join(REPO, "missions", "**", "*"), recursive=True)
        if os.path.isfile(p)
    }
    assert files - named == set(), "add these to README's missions table"
    assert named - files == set(), "README's missions table names files that do not exist"


@pytest.mark.slow
def test_readme_sample_output_is_what_pallet_scan_prints(tmp_path, capsys, monkeypatch):
    from bt_engine.cli import main

    readme = _read("README.md")
    intro = readme.index("`btrun missions/pallet_scan.xml` prints")
    (sample,) = re.findall(r"```text\n(.*?)```", readme[intro:], re.S)[:1]
    monkeypatch.chdir(REPO)
    args = ["missions/pallet_scan.xml", "-q", "--no-report", "--no-mcap", "--out"]
    assert main([*args, str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out.splitlines()
    for line in sample.strip().splitlines():
        pattern = ".*".join(re.escape(part) for part in line.split("..."))
        assert any(re.fullmatch(pattern, o) for o in out), f"README: {line!r}\nbtrun: {out}"


# -- 6. Groot2: the root blackboard is the main tree's ID -----------------------------------


def test_groot2_doc_names_the_root_blackboard_as_the_server_answers_it():
    from bt_engine import Mission, SimClock
    from bt_engine.groot2 import Groot2Server

    doc = _read("docs", "monitoring.md")
    (row,) = [line for line in doc.splitlines() if line.startswith("| BLACKBOARD")]
    assert "`Main`" not in row and "main tree's ID" in row
    named = re.findall(r"For `missions/(\w+\.xml)` ask for\s+`(\w+)`", doc)
    named += re.findall(r"for `missions/(\w+\.xml)`\s+`(\w+)`", doc)
    assert len(named) >= 2
    for mission_file, tree_id in named:
        m = Mission.from_file(os.path.join(REPO, "missions", mission_file), clock=SimClock())
        try:
            with Groot2Server(m, port=0) as server:
                answered = server.blackboards(f"{tree_id};Main")
            assert tree_id in answered and "Main" not in answered, mission_file
        finally:
            m.close()


# -- 7. cflib.cpx: why btrun keeps its own CPX codec -----------------------------------------


def test_cpx_docs_say_why_cflibs_codec_is_not_used():
    import drivers.crazyflie.cpx as cpx

    for text in (cpx.__doc__ or "", _read("docs", "camera.md")):
        assert "cflib.cpx" in text and "length" in text and "resynchronis" in text
