"""Campaign files that are too big or not what they claim to be: refused with one located
line before anything runs (exit code 2), and rows that are never held in a list.

Row counts are checked arithmetically before a row exists (``max_rows``, default
:data:`~bt_engine.campaign.spec.MAX_ROWS`); the campaign file and every mission, rig and
world file it names are read bounded: regular files only, at most ``MAX_FILE_BYTES``,
UTF-8 text without NUL bytes. Nothing here flies.
"""

from __future__ import annotations

import io
import json
import os
import resource
import subprocess
import sys
import textwrap
import threading
import time
from typing import Any

import pytest
from helpers import REPO

from bt_engine import files
from bt_engine.campaign import execution, pool, spec
from bt_engine.campaign import rows as campaign_rows
from bt_engine.campaign.results import ResultStore
from bt_engine.campaign.rows import expand
from bt_engine.campaign.spec import load_campaign
from bt_engine.cli import main
from bt_engine.spec import MissionError

SQUARE = os.path.join(REPO, "missions", "square.xml")


def write(tmp_path, text: str, name: str = "c.yaml") -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


def refusal(path: str) -> list[str]:
    """The located problems of a campaign file that must not load."""
    with pytest.raises(MissionError) as exc:
        load_campaign(path)
    return [str(p) for p in exc.value.problems]


# --- the row count: checked first, arithmetically -------------------------------------------


def test_a_row_count_over_the_cap_is_one_located_line_before_any_row(tmp_path) -> None:
    path = write(
        tmp_path, f"missions: [{SQUARE}]\nseeds: {{start: 5, count: {spec.MAX_ROWS + 1}}}\n"
    )
    t0 = time.perf_counter()
    got = refusal(path)
    assert time.perf_counter() - t0 < 0.5
    assert got == [
        f"{path}:2:26: the campaign has {spec.MAX_ROWS + 1:,} rows (seeds {spec.MAX_ROWS + 1:,}); "
        f"the limit is {spec.MAX_ROWS:,} (max_rows: raises it, up to {spec.MAX_ROWS_CEILING:,})"
    ]


def test_a_twelve_key_grid_is_refused_at_once(tmp_path) -> None:
    grid = "".join(f"  k{i}: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n" for i in range(12))
    path = write(tmp_path, f"missions: [{SQUARE}]\nseeds: {{count: 3}}\ngrid:\n{grid}")
    t0 = time.perf_counter()
    (line,) = refusal(path)
    assert time.perf_counter() - t0 < 0.5
    assert line.startswith(f"{path}:4:3: the campaign has 3,000,000,000,000 rows (grid.k0 10 x ")
    assert f"seeds 3); the limit is {spec.MAX_ROWS:,}" in line


def test_the_dry_run_of_a_huge_campaign_answers_at_once(tmp_path, capsys) -> None:
    path = write(
        tmp_path,
        f"missions: [{SQUARE}]\nseeds: [1, 2]\nfaults:\n"
        + "".join(f"  - {{name: f{i}, set: {{probe: {i}}}}}\n" for i in range(1000))
        + "grid: {a: ["
        + ", ".join(map(str, range(1000)))
        + "]}\n",
    )
    assert len(refusal(path)) == 1  # first, without the command: nothing expanded
    t0 = time.perf_counter()
    assert main(["campaign", path, "--dry-run"]) == 2
    # expanding 2,000,000 rows would take minutes; counting them takes milliseconds (10 s of
    # slack: the machine may be busy with other work)
    assert time.perf_counter() - t0 < 10.0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"{path}:") and "2,000,000 rows (faults 1,000 x grid.a 1,000" in err[0]
    assert err[1:] == ["1 problem found; nothing was run."]


def test_a_billion_seeds_on_the_command_line_is_exit_2_in_bounded_memory(tmp_path) -> None:
    """The real command, in a process that may not use more than 4 GB (the fix never does;
    without it the seeds became a list of a billion integers: MemoryError, a traceback)."""
    path = write(tmp_path, f"missions: [{SQUARE}]\nseeds: {{count: 1000000000}}\n")

    def limit_memory() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    proc = subprocess.run(
        [sys.executable, "-m", "bt_engine.cli", "campaign", path, "--dry-run"],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=limit_memory,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.splitlines() == [
        f"{path}:2:16: the campaign has 1,000,000,000 rows (seeds 1,000,000,000); the limit is "
        f"{spec.MAX_ROWS:,} (max_rows: raises it, up to {spec.MAX_ROWS_CEILING:,})",
        "1 problem found; nothing was run.",
    ]
    assert proc.stdout == ""


def test_max_rows_raises_the_cap_up_to_its_ceiling(tmp_path) -> None:
    n = spec.MAX_ROWS_CEILING
    c = load_campaign(
        write(tmp_path, f"missions: [{SQUARE}]\nseeds: {{count: {n}}}\nmax_rows: {n}\n")
    )
    assert c.max_rows == n and len(c.seeds) == n
    path = write(tmp_path, f"missions: [{SQUARE}]\nmax_rows: {n + 1}\n", "over.yaml")
    assert refusal(path) == [f"{path}:2:11: max_rows: expected 1 to {n:,}, got {n + 1:,}"]
    path = write(
        tmp_path, f"missions: [{SQUARE}]\nseeds: {{count: {n + 1}}}\nmax_rows: {n}\n", "big.yaml"
    )
    assert refusal(path) == [
        f"{path}:2:16: the campaign has {n + 1:,} rows (seeds {n + 1:,}); the limit is {n:,} "
        "(the most a campaign may have)"
    ]


def test_rows_are_generated_one_at_a_time(tmp_path) -> None:
    """A million rows: counted, indexed, sliced and compared without a list of them."""
    n = spec.MAX_ROWS_CEILING
    c = load_campaign(
        write(
            tmp_path,
            f"""\
            missions: [{SQUARE}]
            seeds: {{start: 7, count: {n // 4}}}
            grid: {{wind.gust_std_mps: [0.0, 0.1], speed: [1, 2]}}
            cycle: {{pallet: [A, B, C]}}
            random: {{noise: {{uniform: [0, 1]}}}}
            max_rows: {n}
            """,
        )
    )
    t0 = time.perf_counter()
    rows = expand(c)
    assert isinstance(rows, campaign_rows.CampaignRows) and len(rows) == n
    last, tail = rows[-1], rows[n - 3 :]
    assert time.perf_counter() - t0 < 0.5  # not a million rows made
    assert (last.name, last.seed, last.params["speed"]) == (f"r{n - 1:05d}", 7 + n // 4 - 1, 2)
    assert last.params["pallet"] == "ABC"[(n // 4 - 1) % 3]
    assert [r.index for r in tail] == [n - 3, n - 2, n - 1] and tail[-1] == last
    assert len(rows[::1000]) == n // 1000 and rows[::1000][1] == rows[1000]
    assert list(rows[:5]) == [rows[i] for i in range(5)]
    # a row is a function of its index alone: the same, however it was reached
    again = expand(load_campaign(c.path))
    assert again[123_457] == rows[123_457] and again[:50] == rows[:50]
    assert rows[:50] == list(rows[:50]) and rows[:50] != rows[1:51]


# --- the files: regular, bounded, text ------------------------------------------------------


@pytest.mark.parametrize(
    "content, message",
    [
        (b"missions: [x.xml]\nname: a\x00b\n", "2:8: the file holds a NUL byte"),
        (b"missions: [x.xml]\nname: caf\xe9\n", "2:10: not UTF-8 text (byte 27)"),
        (b"missions: [x.xml]\nname: a\x07b\n", "2:8: character #x0007 is not allowed in YAML"),
    ],
)
def test_a_campaign_file_that_is_not_text_is_one_located_line(tmp_path, capsys, content, message):
    path = tmp_path / "c.yaml"
    path.write_bytes(content)
    assert main(["campaign", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith(f"{path}:{message}"), err


def test_a_fifo_or_a_device_as_the_campaign_file_is_refused_unopened(tmp_path, capsys) -> None:
    fifo = tmp_path / "c.yaml"
    os.mkfifo(fifo)  # opened, it would block the command for ever
    assert main(["campaign", str(fifo), "--dry-run"]) == 2
    assert main(["campaign", "/dev/zero", "--dry-run"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"{fifo}:1:1: {fifo} is a named pipe (FIFO), not a regular file; "
        "campaign files are read from ordinary files",
        "1 problem found; nothing was run.",
        "/dev/zero:1:1: /dev/zero is a character device, not a regular file; "
        "campaign files are read from ordinary files",
        "1 problem found; nothing was run.",
    ]


@pytest.fixture
def odd_files(tmp_path):
    """Files a campaign may name that are not mission, rig or world files."""
    os.mkfifo(tmp_path / "fifo.yaml")
    (tmp_path / "nul.yaml").write_bytes(b"vehicle:\n  mass_kg: 0.03\x00\n")
    (tmp_path / "latin1.xml").write_bytes(b"<root>\xe9</root>\n")
    with open(tmp_path / "huge.yaml", "wb") as f:
        f.truncate(files.MAX_FILE_BYTES + 1)  # sparse: nothing written
    (tmp_path / "folder.yaml").mkdir()
    os.symlink("/dev/zero", tmp_path / "zero.yaml")
    return tmp_path


@pytest.mark.parametrize(
    "entry, message",
    [
        ("rigs: [/proc/self/environ]", "rigs: '/proc/self/environ' holds a NUL byte (byte "),
        ("rigs: [/dev/zero]", "rigs: '/dev/zero' is a character device, not a regular file"),
        ("rigs: [zero.yaml]", "rigs: 'zero.yaml' is a character device, not a regular file"),
        ("rigs: [fifo.yaml]", "rigs: 'fifo.yaml' is a named pipe (FIFO), not a regular file"),
        ("rigs: [folder.yaml]", "rigs: 'folder.yaml' is a directory, not a regular file"),
        ("rigs: [nul.yaml]", "rigs: 'nul.yaml' holds a NUL byte (byte 24); rigs are text files"),
        (
            "rigs: [huge.yaml]",
            f"rigs: 'huge.yaml': file is {files.MAX_FILE_BYTES + 1} bytes; "
            f"the limit is {files.MAX_FILE_BYTES}",
        ),
        ("worlds: [/dev/zero]", "worlds: '/dev/zero' is a character device"),
        ("worlds: [nul.yaml]", "worlds: 'nul.yaml' holds a NUL byte"),
        ("missions: [/dev/zero]", "missions: '/dev/zero' is a character device"),
        ("missions: [latin1.xml]", "missions: 'latin1.xml' is not UTF-8 text (byte 6)"),
    ],
)
def test_a_listed_file_that_is_not_a_bounded_text_file_is_refused(
    odd_files, capsys, entry, message
) -> None:
    text = entry if entry.startswith("missions") else f"missions: [{SQUARE}]\n{entry}"
    path = write(odd_files, text + "\n")
    line = 1 if entry.startswith("missions") else 2
    column = entry.index("[") + 2
    assert main(["campaign", path, "--dry-run"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith(f"{path}:{line}:{column}: {message}"), err
    assert err[1] == "1 problem found; nothing was run."


def test_listed_files_are_read_once_for_the_row_keys(tmp_path) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text("# the default rig\n")
    c = load_campaign(write(tmp_path, f"missions: [{SQUARE}]\nrigs: [rig.yaml, null]\n"))
    assert set(c.digests) == {SQUARE, str(rig)}
    before = expand(c)[0].key
    rig.write_text("# another rig\n")  # the key follows the contents read when checked
    assert expand(c)[0].key == before != expand(load_campaign(c.path))[0].key


# --- the consumers of the rows: pool, execution, resume -------------------------------------


class FakeWorker:
    """A :class:`~bt_engine.campaign.pool.WorkerProcess` that runs nothing: a run ends when
    the test hands it a credit (one per result the test has taken, three to start)."""

    credits = threading.Semaphore(0)

    def __init__(self, log_path: str | None = None) -> None:
        self.proc = None

    def run(self, payload: dict[str, Any]) -> dict[str, Any]:
        assert FakeWorker.credits.acquire(timeout=30)
        return {"key": payload["key"], "status": "SUCCESS", "reason": "", "metrics": {}}

    def close(self) -> None:
        pass

    def kill(self) -> str:
        return "not running"


def test_the_local_pool_pulls_payloads_as_its_workers_free_up(monkeypatch) -> None:
    monkeypatch.setattr(pool, "WorkerProcess", FakeWorker)
    FakeWorker.credits = threading.Semaphore(3)
    pulled: list[int] = []
    taken = 0
    ahead: list[int] = []

    def payloads():
        for i in range(300):
            pulled.append(i)
            ahead.append(len(pulled) - taken)
            yield {"key": f"k{i}"}

    got = []
    for rec in pool.LocalPool(3).results(payloads()):
        taken += 1
        got.append(rec["key"])
        FakeWorker.credits.release()
    assert sorted(got) == sorted(f"k{i}" for i in range(300))
    # one payload in each worker, three runs ended but not yet taken: never the whole list
    assert max(ahead) <= 3 + 3


class FakePool:
    """A pool that records how it was fed and answers every payload at once."""

    fed: list[Any] = []

    def __init__(self, *args: Any) -> None:
        pass

    def results(self, payloads: Any):
        FakePool.fed.append(payloads)
        for p in payloads:
            yield {
                "key": p["key"],
                "status": "SUCCESS",
                "reason": "",
                "metrics": {"t": 1.0},
                "wall_s": 0.1,
                "run_dir": "",
            }

    def close(self) -> None:
        pass

    def stop(self) -> None:
        pass


def test_a_campaign_runs_and_resumes_from_lazy_rows(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(execution, "LocalPool", FakePool)
    FakePool.fed = []
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        seeds: {{count: 5}}
        grid: {{wind.gust_std_mps: [0.0, 0.1]}}
        metrics: {{t: mission_time_s}}
        """,
    )
    out = str(tmp_path / "out")
    first = execution.run_campaign(path, out, limit=4, report=False, progress=io.StringIO())
    assert not isinstance(FakePool.fed[0], (list, tuple))  # a generator: made as asked
    assert first.ran == [f"r{i:05d}" for i in range(4)] and first.complete
    assert isinstance(first.rows, campaign_rows.CampaignRows) and len(first.rows) == 10
    rest = execution.run_campaign(path, out, report=False, progress=io.StringIO())
    assert rest.ran == [f"r{i:05d}" for i in range(4, 10)]
    assert [r["row"] for r in rest.table] == [f"r{i:05d}" for i in range(10)]
    assert len(rest.records) == 10 and rest.complete
    saved = {
        json.loads((tmp_path / "out" / "rows" / n).read_text())["row"]
        for n in os.listdir(tmp_path / "out" / "rows")
    }
    assert saved == {f"r{i:05d}" for i in range(10)}


def test_a_resume_skips_saved_rows_that_are_not_regular_files(tmp_path) -> None:
    store = ResultStore(str(tmp_path))
    store.save({"key": "a", "status": "SUCCESS"})
    fifo = tmp_path / "rows" / "b.json"
    os.mkfifo(fifo)  # opened, it would block the resume for ever
    got: dict[str, Any] = {}
    reader = threading.Thread(target=lambda: got.update(store.finished()), daemon=True)
    reader.start()
    reader.join(timeout=10)
    if reader.is_alive():  # free the blocked reader before failing
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
    assert not reader.is_alive() and set(got) == {"a"}


def test_a_saved_row_with_no_status_a_run_gives_runs_again(tmp_path) -> None:
    """A hand-edited (or cut) row record whose status is none a run gives had been counted
    as finished: the resume skipped it and the tables showed a status no run had."""
    store = ResultStore(str(tmp_path))
    for key, status in [("a", "SUCCESS"), ("b", "CRASHED"), ("c", "DONE"), ("d", None)]:
        store.save({"key": key, "status": status})
    store.save({"key": "e"})
    assert set(store.finished()) == {"a", "b"}
