"""Bounded input everywhere: rig, world, fleet and resume files that are not text (a FIFO,
``/dev/zero``, a folder, NUL bytes, non-UTF-8, too large) and resume state of the wrong
shape are one located line (``file:line:col: message``) with exit code 2 before anything
flies, never a hang, a MemoryError or a traceback; names used as folder names stay inside
``--out``; a damaged gallery's history is one line too."""

from __future__ import annotations

import json
import os
import re
import sqlite3
import threading
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from helpers import REPO

from bt_engine.cli import main
from bt_engine.spec import Loc, MissionError
from bt_engine.ticklog import read_log
from drivers.rig.loader import load_rig
from drivers.settings import ConfigError
from drivers.settings_yaml import MAX_SETTINGS_BYTES
from drivers.sim.world import load_world
from nodes.fleet.check import previous_run
from nodes.fleet.spec import load_fleet
from nodes.inventory import resolve_places
from nodes.inventory_log import MAX_INVENTORY_ROWS, InventoryError, read_inventory
from perception.gallery import Gallery, GalleryError

SQUARE = os.path.join(REPO, "missions", "square.xml")
INVENTORY = os.path.join(REPO, "missions", "inventory.xml")
AISLE = os.path.join(REPO, "rigs", "aisle.yaml")


def _unblock(path: str) -> None:
    """Wake a reader blocked on the FIFO ``path`` (a regression) with a NUL byte, so the
    test fails instead of hanging; nothing happens if no one has it open."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
    except OSError:  # no reader: the FIFO was refused unopened, as it should be
        return
    try:
        os.write(fd, b"\0")
    finally:
        os.close(fd)


@pytest.fixture
def make_fifo() -> Iterator[Callable[[str], str]]:
    """Make a named pipe at a path; a reader that opened it would block for ever (a
    regression), so a timer unblocks it and the test fails instead of hanging."""
    timers: list[threading.Timer] = []

    def make(path: str) -> str:
        os.mkfifo(path)
        timer = threading.Timer(30.0, _unblock, (path,))
        timer.daemon = True
        timer.start()
        timers.append(timer)
        return path

    yield make
    for timer in timers:
        timer.cancel()


@pytest.fixture
def fifo(tmp_path, make_fifo) -> str:
    """A named pipe (see :func:`make_fifo`)."""
    return make_fifo(str(tmp_path / "pipe.yaml"))


@pytest.fixture
def odd(tmp_path) -> dict[str, str]:
    """Files that are not settings text, by kind."""
    (tmp_path / "nul.yaml").write_bytes(b"vehicle:\n  mass_kg: 0.03\x00\n")
    (tmp_path / "latin1.yaml").write_bytes(b"# caf\xe9\nvehicle: {}\n")
    (tmp_path / "bell.yaml").write_bytes(b"vehicle:\n  name: a\x07b\n")
    with open(tmp_path / "huge.yaml", "wb") as f:
        f.truncate(MAX_SETTINGS_BYTES + 1)  # sparse: nothing written
    (tmp_path / "folder.yaml").mkdir()
    os.symlink("/dev/zero", tmp_path / "zero.yaml")
    return {p.stem: str(p) for p in tmp_path.iterdir()}


#: kind -> (line:col, the message's start)
SETTINGS_REFUSALS = {
    "zero": ("1:1", "{path} is a character device, not a regular file; {what} files are read"),
    "folder": ("1:1", "{path} is a directory, not a regular file; {what} files are read"),
    "nul": ("2:16", "the file holds a NUL byte (byte 24); {what} files are YAML text"),
    "latin1": ("1:6", "not UTF-8 text (byte 5)"),
    "bell": ("2:10", "character #x0007 is not allowed in YAML"),
    "huge": ("1:1", f"file is {MAX_SETTINGS_BYTES + 1} bytes; the limit is {MAX_SETTINGS_BYTES}"),
}


def _one_problem(capsys, argv: list[str]) -> str:
    """Run ``btrun argv``: exit code 2, one located problem line (and the count line), no
    traceback; return the problem line."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert len(lines) == 2 and lines[1] == "1 problem found; nothing was run.", lines
    return lines[0]


def _expect(line: str, path: str, kind: str, what: str) -> None:
    where, message = SETTINGS_REFUSALS[kind]
    assert line.startswith(f"{path}:{where}: {message.format(path=path, what=what)}"), line


# --- rig and world files ------------------------------------------------------------------


def test_a_fifo_as_the_rig_is_refused_unopened(fifo, capsys, tmp_path) -> None:
    out = str(tmp_path / "run")
    line = _one_problem(capsys, ["run", SQUARE, "--rig", fifo, "--out", out, "-q"])
    assert line == (
        f"{fifo}:1:1: {fifo} is a named pipe (FIFO), not a regular file; rig files are read "
        "from ordinary files"
    )
    assert not os.path.exists(out)
    line = _one_problem(capsys, ["rig", "check", fifo])
    assert line.startswith(f"{fifo}:1:1: {fifo} is a named pipe (FIFO)")


@pytest.mark.parametrize("kind", sorted(SETTINGS_REFUSALS))
def test_a_rig_that_is_not_bounded_text_is_one_located_line(odd, capsys, kind) -> None:
    path = odd[kind]
    _expect(_one_problem(capsys, ["rig", "check", path]), path, kind, "rig")
    with pytest.raises(ConfigError) as exc:
        load_rig(path)
    assert len(exc.value.problems) == 1


@pytest.mark.parametrize("kind", ["zero", "nul", "latin1", "folder"])
def test_a_world_path_override_that_is_not_bounded_text_is_refused(
    odd, capsys, tmp_path, kind
) -> None:
    path = odd[kind]
    argv = ["run", SQUARE, "--set", f"world.path={path}", "--out", str(tmp_path / "r"), "-q"]
    _expect(_one_problem(capsys, argv), path, kind, "world")


def test_a_fifo_world_is_refused(fifo) -> None:
    with pytest.raises(ConfigError, match="named pipe"):
        load_world(fifo)
    with pytest.raises(ConfigError, match="named pipe"):
        load_rig(None, {"world.path": fifo})


def test_world_dev_zero_on_the_command_line(capsys, tmp_path) -> None:
    argv = ["run", SQUARE, "--set", "world.path=/dev/zero", "--out", str(tmp_path / "r"), "-q"]
    assert _one_problem(capsys, argv) == (
        "/dev/zero:1:1: /dev/zero is a character device, not a regular file; world files are "
        "read from ordinary files"
    )


# --- fleet files ----------------------------------------------------------------------------


def _fleet(tmp_path, text: str, name: str = "fleet.yaml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _fleet_text(rig: str = AISLE, fleet_name: str = "aisle", drone: str = "cf1") -> str:
    return (
        f"name: {json.dumps(fleet_name)}\n"
        f"mission: {INVENTORY}\n"
        f"rig: {rig}\n"
        "drones:\n"
        f"  - {{name: {json.dumps(drone)}, pad: pad-1}}\n"
        "  - {name: cf2, pad: pad-2}\n"
    )


def test_a_fleet_rig_entry_that_is_a_fifo_or_a_device_is_refused(fifo, tmp_path, capsys) -> None:
    for rig, kind in ((fifo, "a named pipe (FIFO)"), ("/dev/zero", "a character device")):
        path = _fleet(tmp_path, _fleet_text(rig=rig))
        line = _one_problem(capsys, ["fleet", path, "--out", str(tmp_path / "out"), "-q"])
        assert line == (
            f"{rig}:1:1: {rig} is {kind}, not a regular file; rig files are read from "
            "ordinary files"
        )


def test_a_non_utf8_fleet_file_is_one_located_line(tmp_path, capsys) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_bytes(b"# caf\xe9\n" + _fleet_text().encode())
    line = _one_problem(capsys, ["fleet", str(path), "--out", str(tmp_path / "out"), "-q"])
    assert line == f"{path}:1:6: not UTF-8 text (byte 5)"


def test_a_fifo_fleet_file_is_refused(fifo, capsys, tmp_path) -> None:
    line = _one_problem(capsys, ["fleet", fifo, "--out", str(tmp_path / "out"), "-q"])
    assert line.startswith(f"{fifo}:1:1: {fifo} is a named pipe (FIFO), not a regular file")


@pytest.mark.parametrize(
    "fleet_name, drone, key, where",
    [
        ("aisle", "../../../x", "drone name '../../../x'", "5:12"),
        ("aisle", "a/b", "drone name 'a/b'", "5:12"),
        ("aisle", "..", "drone name '..'", "5:12"),
        ("aisle", "x" * 65, f"drone name '{'x' * 65}'", "5:12"),
        ("../../escape", "cf1", "fleet name '../../escape'", "1:7"),
        ("/tmp/abs", "cf1", "fleet name '/tmp/abs'", "1:7"),
        (".hidden", "cf1", "fleet name '.hidden'", "1:7"),
    ],
)
def test_names_used_as_folders_cannot_leave_the_run_folder(
    tmp_path, capsys, fleet_name, drone, key, where
) -> None:
    path = _fleet(tmp_path, _fleet_text(fleet_name=fleet_name, drone=drone))
    out = tmp_path / "deep" / "er" / "out"
    line = _one_problem(capsys, ["fleet", path, "--out", str(out), "-q"])
    assert line.startswith(f"{path}:{where}: {key} cannot be a folder name"), line
    assert sorted(os.listdir(tmp_path)) == ["fleet.yaml"]  # nothing written anywhere


def test_safe_names_still_load(tmp_path) -> None:
    path = _fleet(tmp_path, _fleet_text(fleet_name="aisle_2.v1-b", drone="cf-1.A_2"))
    assert [d.name for d in load_fleet(path).drones] == ["cf-1.A_2", "cf2"]


def test_a_fleet_resume_record_that_is_a_fifo_or_not_a_record_is_refused(
    make_fifo, tmp_path
) -> None:
    folder = tmp_path / "prev"
    folder.mkdir()
    make_fifo(str(folder / "fleet.json"))
    with pytest.raises(MissionError, match=r"fleet.json:1:1: .* is a named pipe \(FIFO\)"):
        previous_run(str(folder))
    os.remove(folder / "fleet.json")
    (folder / "fleet.json").write_text('{"seed": "x"}')
    with pytest.raises(MissionError, match="fleet.json:1:1: not a fleet record"):
        previous_run(str(folder))


# --- a mission's include and place list -----------------------------------------------------


def test_a_nul_byte_in_a_yaml_include_entry_is_located(tmp_path, capsys) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        'btrun: 1\nmain: Main\ninclude:\n  - "lib\\0x.yaml"\n'
        "trees:\n  Main:\n    AlwaysSuccess: {}\n"
    )
    assert _one_problem(capsys, ["validate", str(path)]) == (
        f"{path}:4:5: include: a file path cannot hold a NUL byte"
    )


def test_a_fifo_place_list_is_refused_unopened(make_fifo, tmp_path) -> None:
    csv = make_fifo(str(tmp_path / "places.csv"))
    world = load_rig(AISLE).load_world()
    places, problems = resolve_places(csv, world, Loc("m.xml", 3, 5))
    assert places == [] and [str(p) for p in problems] == [
        f"m.xml:3:5: place list: {csv} is a named pipe (FIFO), not a regular file; place "
        "lists are read from ordinary files"
    ]


# --- --resume: the tick log's header --------------------------------------------------------


@pytest.mark.parametrize(
    "first_line, message",
    [
        ("[1, 2]", "1:1: not a tick log: expected a JSON object, got [1, 2]"),
        ("5", "1:1: not a tick log: expected a JSON object, got 5"),
        ("garbage", "1:1: not a tick log: the line is not JSON"),
        ('{"header": 3}', "1:2: 'header' must be a JSON object, got 3"),
        ('{"header": {"seed": "x"}}', "1:13: header 'seed' must be an integer or null, got 'x'"),
        ('{"header": {"seed": true}}', "1:13: header 'seed' must be an integer or null"),
        ('{"header": {"sets": 5}}', "1:13: header 'sets' must be a list of KEY=VALUE strings"),
        ('{"header": {"sets": [1]}}', "1:13: header 'sets' must be a list of KEY=VALUE strings"),
        ('{"header": {"rig_arg": []}}', "1:13: header 'rig_arg' must be a path or null, got []"),
        ('{"header": {"rig_arg": "a\\u0000b"}}', "1:13: header 'rig_arg' must be a path"),
        ('{"header": {"mission": 7}}', "1:13: header 'mission' must be a path or null, got 7"),
        ('{"header": {"nodes": [[1]]}}', "1:13: header 'nodes' must be a list of [path"),
    ],
)
def test_a_malformed_resume_header_is_one_located_line(
    tmp_path, capsys, first_line, message
) -> None:
    prev = tmp_path / "prev"
    prev.mkdir()
    log = prev / "ticks.jsonl"
    log.write_text(first_line + '\n{"tick": 1, "t": 0.02, "status": "RUNNING"}\n')
    argv = ["run", SQUARE, "--resume", str(prev), "--out", str(tmp_path / "r"), "-q"]
    line = _one_problem(capsys, argv)
    assert line.startswith(f"{log}:{message}"), line
    assert not (tmp_path / "r").exists()


def test_a_tick_log_that_is_a_fifo_or_a_device_is_refused(fifo) -> None:
    for path, kind in ((fifo, "a named pipe (FIFO)"), ("/dev/zero", "a character device")):
        with pytest.raises(MissionError) as exc:
            read_log(path)
        assert str(exc.value) == (
            f"{path}:1:1: {path} is {kind}, not a regular file; tick logs are read from "
            "ordinary files"
        )


def test_a_good_tick_log_still_reads_with_a_torn_last_line(tmp_path) -> None:
    log = tmp_path / "ticks.jsonl"
    log.write_text('{"header": {"seed": 3, "sets": ["a=1"]}}\n{"tick": 1}\n{"tick": 2, "t')
    assert read_log(str(log)) == ({"seed": 3, "sets": ["a=1"]}, [{"tick": 1}])


# --- --resume: the inventory rows -----------------------------------------------------------


def _resume_folder(tmp_path, rows: object) -> str:
    prev = tmp_path / "prev"
    prev.mkdir(exist_ok=True)
    header = {"mission": INVENTORY, "rig_arg": AISLE, "seed": 0, "sets": []}
    (prev / "ticks.jsonl").write_text(json.dumps({"header": header}) + "\n")
    doc = {"format": "btrun-inventory-1", "planned": [], "rows": rows}
    (prev / "inventory.json").write_text(json.dumps(doc, indent=1))
    return str(prev)


GOOD_ROW = {"place": "A-01-1", "answer": "3A", "status": "identified", "mission_time_s": 12.5}


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"answer": ["3A"]}, "rows[1]: answer: expected text or null, got ['3A']"),
        ({"mission_time_s": "soon"}, "rows[1]: mission_time_s: expected a number or null"),
        ({"distance": float("nan")}, "rows[1]: distance: expected a number or null, got nan"),
        ({"blocks_seen": 2.5}, "rows[1]: blocks_seen: expected an integer or null, got 2.5"),
        ({"status": "done"}, "rows[1]: status: expected one of"),
        ({"place": ""}, "rows[1]: place: expected a place name"),
        ({"colour": "red"}, "rows[1]: unknown key 'colour'"),
    ],
)
def test_a_forged_inventory_row_is_refused_before_anything_flies(
    tmp_path, capsys, bad, message
) -> None:
    row = {**GOOD_ROW, "place": "A-01-2", **bad}
    prev = _resume_folder(tmp_path, [GOOD_ROW, row])
    out = tmp_path / "r"
    line = _one_problem(capsys, ["run", INVENTORY, "--resume", prev, "--out", str(out), "-q"])
    # the second row starts on line 11, column 3 of the file as json.dumps(indent=1) writes it
    assert line.startswith(f"{prev}/inventory.json:11:3: {message}"), line
    assert not out.exists()


def test_an_inventory_row_that_is_not_an_object_is_located(tmp_path) -> None:
    prev = _resume_folder(tmp_path, [GOOD_ROW, ["A-01-2"]])
    with pytest.raises(InventoryError, match=r"inventory.json:1:1: rows\[1\]: expected a row"):
        read_inventory(prev)


def test_too_many_inventory_rows_are_refused(tmp_path) -> None:
    rows = [{"place": f"p{i}"} for i in range(MAX_INVENTORY_ROWS + 1)]
    prev = _resume_folder(tmp_path, rows)
    with pytest.raises(InventoryError) as exc:
        read_inventory(prev)
    assert exc.value.problem().message == (
        f"{MAX_INVENTORY_ROWS + 1} rows; an inventory holds at most {MAX_INVENTORY_ROWS}"
    )
    assert str(exc.value.problem().loc) == f"{prev}/inventory.json:1:1"


def test_an_inventory_that_is_a_fifo_or_a_device_is_refused(make_fifo, tmp_path) -> None:
    prev = tmp_path / "prev"
    prev.mkdir()
    make_fifo(str(prev / "inventory.json"))
    with pytest.raises(InventoryError, match=r"is a named pipe \(FIFO\), not a regular file"):
        read_inventory(str(prev))
    os.remove(prev / "inventory.json")
    os.symlink("/dev/zero", prev / "inventory.json")
    with pytest.raises(InventoryError, match="is a character device, not a regular file"):
        read_inventory(str(prev))


def test_a_good_inventory_still_reads(tmp_path) -> None:
    row = {**GOOD_ROW, "best_id": None, "distance": 0.2, "blocks_seen": 3, "reason": None}
    assert read_inventory(_resume_folder(tmp_path, [row])) == [row]


# --- a damaged gallery's history ------------------------------------------------------------


@pytest.mark.parametrize("time_value, shown", [("'yesterday'", "'yesterday'"), ("1e300", "1e+300")])
def test_a_gallery_time_that_is_not_a_date_is_one_line(tmp_path, time_value, shown) -> None:
    path = str(tmp_path / "g.sqlite")
    with Gallery.create(path, model_version="test-v1", dim=8) as g:
        g.enrol("1A", np.ones((3, 8), np.float32))
    conn = sqlite3.connect(path)
    with conn:
        conn.execute(f"UPDATE history SET time = {time_value}")
        conn.execute(f"UPDATE entries SET created = {time_value}")
    conn.close()
    g = Gallery.open(path)
    with pytest.raises(GalleryError, match=re.escape(f"history event 1: time {shown} is not")):
        g.history()
    with pytest.raises(GalleryError, match=re.escape(f"entry '1A': time {shown} is not a")):
        g.entries()
    g.close()


@pytest.mark.slow
def test_gallery_history_on_a_damaged_gallery_is_one_line(tmp_path, capsys) -> None:
    """Through ``btrun gallery history`` (it loads the shipped embedder)."""
    from perception.embedder import BlockEmbedder

    emb = BlockEmbedder.load(threads=1)
    path = str(tmp_path / "g.sqlite")
    with Gallery.create(path, emb.model_version, emb.dim) as g:
        g.enrol("1A", np.ones((3, emb.dim), np.float32) / np.sqrt(emb.dim))
    conn = sqlite3.connect(path)
    with conn:
        conn.execute("UPDATE history SET time = 'soon'")
    conn.close()
    assert main(["gallery", "history", path]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"btrun gallery: {path}: history event 1: time 'soon' is not a date; the gallery file "
        "is damaged (restore a backup)\n"
    )
