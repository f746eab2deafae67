"""What ``btrun campaign`` hands a data engineer and a terminal: results tables with plain
column names (and their data dictionary, ``columns.csv``), an unambiguous mission column, a
readable CSV beside a full-precision Parquet file, a summary table at the end, a
``rich.progress`` bar on a terminal and plain lines in a log; a Dask scheduler that does not
answer fails fast with a hint, the dashboard link is printed, and the resume line keeps
``--scheduler``.

Nothing here flies: the pools are replaced by fakes that answer every row at once (the Dask
tests connect to a real in-process ``LocalCluster`` and fake only the run itself).
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import signal
import socket
import sys
import textwrap
import time
from typing import Any

import pyarrow.parquet as pq
import pytest
from helpers import REPO

from bt_engine.campaign import execution, pool
from bt_engine.campaign.execution import Progress, run_campaign
from bt_engine.campaign.spec import load_campaign
from bt_engine.cli import main
from bt_engine.spec import MissionError

SQUARE = os.path.join(REPO, "missions", "square.xml")
PLAIN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: what every fake run measures (by metric name)
METRICS: dict[str, Any] = {
    "sim.final_pose.x_m": 0.0046296533653606125,
    "settle_s": [0.1234567891, None, 2.0],
    "labels": ["up", "corner 1"],
    "pose": {"x": 1.23456789, "y": [0.5]},
    "landed": True,
    "worst": 0.0123456789,
}


def fake_result(p: dict[str, Any]) -> dict[str, Any]:
    """A run's result without a run: FAILURE where the row sets ``bb.probe=fail`` (an entry
    the mission does not read: ``bb.`` passes it unchecked)."""
    failed = "bb.probe=fail" in p["sets"]
    return {
        "key": p["key"],
        "status": "FAILURE" if failed else "SUCCESS",
        "reason": "probe said fail" if failed else "the mission tree returned SUCCESS",
        "metrics": {name: METRICS.get(name) for name, _ in p["metrics"]},
        "wall_s": 0.123456789,
        "run_dir": "",
    }


class FakePool:
    """A local pool (or, with an address, a Dask pool) answering every payload at once; with
    ``interrupt_after`` set, a SIGINT comes after that many results."""

    interrupt_after: int | None = None

    def __init__(self, *args: Any) -> None:
        pass

    def describe(self) -> str:
        return "a fake cluster"

    def check_workers(self, node_ids: Any) -> None:
        pass

    def results(self, payloads: Any):
        for n, p in enumerate(payloads):
            if n == FakePool.interrupt_after:  # Ctrl-C, handled as the command handles it
                signal.raise_signal(signal.SIGINT)
            yield fake_result(p)

    def close(self) -> None:
        pass

    def stop(self) -> None:
        pass


@pytest.fixture
def fake_pools(monkeypatch):
    monkeypatch.setattr(execution, "LocalPool", FakePool)
    monkeypatch.setattr(execution, "DaskPool", FakePool)
    FakePool.interrupt_after = None


def write(folder, text: str, name: str = "c.yaml") -> str:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))
    return str(path)


def campaign(folder, mission: str = SQUARE, extra: str = "") -> str:
    return write(
        folder,
        f"""\
        missions: [{mission}]
        seeds: [0, 1]
        grid: {{wind.gust_std_mps: [0.0, 0.1]}}
        metrics:
          sim.final_pose.x_m: sim.final_pose.x_m
          settle_s: "motions[kind=GoTo].settle_s"
          labels: "motions[kind=GoTo].label"
          pose: sim.final_pose
          landed: sim.landed
        {extra}""",
    )


def read_csv(path: str) -> list[dict[str, str]]:
    with open(path, encoding="utf-8", newline="") as f:
        return list(csv.DictReader(f))


# --- column names: plain identifiers, mapped back ------------------------------------------


def test_the_tables_have_plain_column_names_mapped_back_to_the_campaign(
    tmp_path, fake_pools
) -> None:
    path = campaign(tmp_path)
    out = str(tmp_path / "out")
    first = run_campaign(path, out, limit=1, report=False, progress=io.StringIO())
    rest = run_campaign(path, out, report=False, progress=io.StringIO())  # resumes
    assert first.ran == ["r00000"] and rest.ran == ["r00001", "r00002", "r00003"]
    table = pq.read_table(os.path.join(out, "results.parquet"))
    names = table.column_names
    assert all(PLAIN.fullmatch(n) for n in names), names  # no quoting in SQL
    assert "wind_gust_std_mps" in names and "sim_final_pose_x_m" in names
    assert table.num_rows == 4
    with open(os.path.join(out, "results.csv"), encoding="utf-8") as f:
        assert next(csv.reader(f)) == names
    # the data dictionary: each column, its kind and the campaign's name for it
    dictionary = {r["column"]: r for r in read_csv(os.path.join(out, "columns.csv"))}
    assert list(dictionary) == names
    assert dictionary["wind_gust_std_mps"]["kind"] == "setting"
    assert dictionary["wind_gust_std_mps"]["source"] == "wind.gust_std_mps"
    assert dictionary["sim_final_pose_x_m"]["source"] == "sim.final_pose.x_m"
    assert dictionary["sim_final_pose_x_m"]["description"] == "summary.json: sim.final_pose.x_m"
    assert dictionary["wall_s"]["wall_clock"] == "true"
    meta = json.loads(table.schema.metadata[b"btrun.columns"])
    assert {m["name"]: m["key"] for m in meta}["sim_final_pose_x_m"] == "sim.final_pose.x_m"
    # the Python table keeps the campaign's own keys (what the bench scripts read)
    assert rest.table[0]["wind.gust_std_mps"] == 0.0
    assert rest.table[0]["sim.final_pose.x_m"] == METRICS["sim.final_pose.x_m"]


def test_column_name() -> None:
    from bt_engine.campaign.spec import column_name

    assert column_name("sim.final_pose.x_m") == "sim_final_pose_x_m"
    assert column_name("faults.gust.speed_mps") == "faults_gust_speed_mps"
    assert column_name("scan_speed") == "scan_speed"
    assert column_name("p95-latency [ms]") == "p95_latency__ms_"
    assert column_name("3d") == "_3d"


def test_names_that_would_be_the_same_column_are_a_located_problem(tmp_path) -> None:
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        grid: {{wind.gust_std_mps: [0.0, 0.1]}}
        metrics:
          wind_gust_std_mps: mission_time_s
          Status: status
        """,
    )
    with pytest.raises(MissionError) as exc:
        load_campaign(path)
    got = [str(p) for p in exc.value.problems]
    assert (
        f"{path}:4:3: metrics: 'wind_gust_std_mps' and the setting 'wind.gust_std_mps' would "
        "both be the results column 'wind_gust_std_mps'; rename one"
    ) in got
    assert any(p.startswith(f"{path}:5:3: metrics: 'Status' and the column 'status'") for p in got)


# --- the mission column ----------------------------------------------------------------------


def test_the_mission_is_named_as_written_and_by_its_absolute_path(
    tmp_path, fake_pools, monkeypatch
) -> None:
    folder = tmp_path / "campaigns"
    written = os.path.relpath(SQUARE, folder)  # relative to the campaign file
    path = campaign(folder, mission=written)
    monkeypatch.chdir(tmp_path)  # elsewhere: the written path alone would not find it
    run = run_campaign(path, "out", report=False, progress=io.StringIO())
    table = pq.read_table(os.path.join("out", "results.parquet")).to_pylist()
    assert {r["mission"] for r in table} == {written}
    assert {r["mission_path"] for r in table} == {SQUARE}
    assert {r["rig_path"] for r in table} == {""}  # the default rig
    assert {r["mission_path"] for r in read_csv(run.csv)} == {SQUARE}
    assert pq.read_schema(run.parquet).metadata[b"btrun.campaign_file"].decode() == path


# --- a readable CSV, a full-precision Parquet file ------------------------------------------


def test_the_csv_rounds_floats_and_joins_lists_the_parquet_keeps_everything(
    tmp_path, fake_pools
) -> None:
    run = run_campaign(campaign(tmp_path), str(tmp_path / "out"), progress=io.StringIO())
    row = read_csv(run.csv)[0]
    assert row["sim_final_pose_x_m"] == "0.00462965"  # 6 significant digits
    assert row["settle_s"] == "0.123457;;2.0"  # a list: items joined by ';', None empty
    assert row["labels"] == "up;corner 1"
    assert json.loads(row["pose"]) == {"x": 1.23457, "y": [0.5]}  # a mapping: JSON
    assert row["landed"] == "true"
    assert row["wind_gust_std_mps"] == "0.0" and row["seed"] == "0"
    assert row["wall_s"] == "0.123457"
    full = pq.read_table(run.parquet).to_pylist()[0]
    assert full["sim_final_pose_x_m"] == METRICS["sim.final_pose.x_m"]
    assert full["settle_s"] == METRICS["settle_s"]  # a typed list column
    assert full["landed"] is True and full["wall_s"] == 0.123456789


# --- the terminal: summary table, progress ---------------------------------------------------


def test_the_command_ends_with_a_summary_table(tmp_path, fake_pools, capsys) -> None:
    path = campaign(
        tmp_path,
        extra="""faults:
          - name: none
            set: {bb.probe: ok}
          - name: broken
            set: {bb.probe: fail}
        """,
    )
    assert main(["campaign", path, "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out

    def cells(line: str, bar: str) -> list[str]:
        return [cell.strip() for cell in line.strip().strip(bar).split(bar)]

    heads = [cells(line, "┃") for line in out.splitlines() if line.startswith("┃")]
    assert [" ".join(filter(None, h)) for h in zip(*heads, strict=True)] == [
        "fault",
        "runs",
        "SUCCESS",
        "FAILURE",
        "success",
        "sim.final_pose.x_m median",  # the numeric metrics' medians
        "landed true",  # the true/false metrics' counts (lists, mappings: the report's)
        "wall_s median",
    ]
    body = {c[0]: c[1:] for c in (cells(ln, "│") for ln in out.splitlines() if ln[:1] == "│")}
    assert body == {
        "none": ["4", "4", "", "100 %", "0.00463", "4/4", "0.12"],
        "broken": ["4", "", "4", "0 %", "0.00463", "4/4", "0.12"],
        "total": ["8", "4", "4", "50 %", "0.00463", "8/8", "0.12"],
    }
    assert out.index("campaign c: 8 runs") < out.index("8/8 rows finished")


class Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_progress_is_a_rich_bar_on_a_terminal_and_lines_in_a_log() -> None:
    tty = Terminal()
    bar = Progress(total=5, done=2, todo=3, stream=tty)
    bar.update(force=True)
    for status in ("SUCCESS", "FAILURE", "SUCCESS"):
        bar.update(status)
    bar.close()
    text = tty.getvalue()
    assert "━" in text and "5/5" in text and "1 failed" in text  # rich.progress's bar
    assert "\x1b[K" not in text  # not the hand-written line
    log = io.StringIO()
    plain = Progress(total=5, done=2, todo=3, stream=log, interval_s=0.0)
    plain.update(force=True)
    for status in ("SUCCESS", "FAILURE", "SUCCESS"):
        plain.update(status)
    plain.close()
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("campaign: 2/5 done, 0 failed")
    assert [line.split(",")[0] for line in lines[1:4]] == [
        f"campaign: {n}/5 done" for n in (3, 4, 5)
    ]
    assert "\x1b" not in log.getvalue() and "\r" not in log.getvalue()


# --- Dask: a wrong address, the dashboard, the resume line ----------------------------------


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_that_does_not_answer_fails_fast_with_a_hint(tmp_path, capsys) -> None:
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    out = tmp_path / "out"
    cmd = ["campaign", campaign(tmp_path), "--out", str(out), "--scheduler", address]
    t0 = time.monotonic()
    assert main([*cmd, "--connect-timeout", "0.5"]) == 2  # bad input: nothing ran
    assert time.monotonic() - t0 < 10  # the campaign's own checks included
    err = capsys.readouterr().err
    assert f"no Dask scheduler answered at {address} within 0.5 s" in err
    assert "`dask scheduler`" in err and "--connect-timeout" in err
    assert not out.exists()  # nothing was written
    assert pool.CONNECT_TIMEOUT_S <= 5  # the default: not Dask's 30 s
    assert main(["campaign", cmd[1], "--out", str(out), "--scheduler", "nowhere"]) == 2
    assert "'nowhere' is not a Dask scheduler address" in capsys.readouterr().err
    for bad in ("0", "inf", "1e11"):  # inf and 1e11 reached Dask and threading: tracebacks
        with pytest.raises(SystemExit) as exc:
            main([*cmd, "--connect-timeout", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "argument --connect-timeout: expected a time in s > 0 and at most 3600" in err
        assert "Traceback" not in err and not out.exists()


def test_a_dask_campaign_prints_the_dashboard_link(tmp_path, monkeypatch, capsys) -> None:
    from dask.distributed import Client, LocalCluster

    monkeypatch.setattr(pool, "run_on_dask_worker", fake_result)  # in-process workers
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0"
    ) as cluster:
        with Client(cluster.scheduler_address, set_as_default=False) as client:
            link = client.dashboard_link
        path = campaign(tmp_path)
        cmd = ["campaign", path, "--out", str(tmp_path / "out")]
        assert main([*cmd, "--scheduler", cluster.scheduler_address]) == 0
    err = capsys.readouterr().err
    assert link and f"dashboard: {link}" in err
    assert f"Dask scheduler {cluster.scheduler_address}, 1 worker thread;" in err


def test_the_resume_line_of_a_dask_campaign_keeps_the_scheduler(
    tmp_path, fake_pools, capsys, monkeypatch
) -> None:
    import btrun_launcher

    FakePool.interrupt_after = 1
    path = campaign(tmp_path)
    out = str(tmp_path / "my out")
    cmd = ["campaign", path, "--out", out, "--scheduler", "tcp://head:8786"]
    cmd += ["--connect-timeout", "20", "--keep-runs", "all", "--include-path", str(tmp_path)]
    # through the console script: its Ctrl-C recorder must not swallow the campaign's Ctrl-C
    monkeypatch.setattr(sys, "argv", ["btrun", *cmd])
    assert btrun_launcher.main() == 1
    err = capsys.readouterr().err
    resume = err.split("resume with: ", 1)[1].strip()
    assert resume == (
        f"btrun campaign {path} --out '{out}' --scheduler tcp://head:8786 "
        f"--connect-timeout 20 --keep-runs all --include-path {tmp_path}"
    )
    assert len(os.listdir(os.path.join(out, "rows"))) == 1
