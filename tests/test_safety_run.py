"""Safety through ``btrun run``: summary.json content, complete logs, SIGINT and SIGTERM.

The signal tests start a real ``btrun`` process (paced at 20x real time) and signal it; they
are the only tests here that take wall time (a few seconds each).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest
from helpers import REPO, wait_until

from bt_engine.cli import main
from bt_engine.ticklog import read_log

MISSION = os.path.join(REPO, "missions", "pallet_scan.xml")


def _logged(run_dir: str) -> tuple[dict, list[dict]]:
    with open(os.path.join(run_dir, "summary.json")) as f:
        summary = json.load(f)
    _, records = read_log(os.path.join(run_dir, "ticks.jsonl"))
    return summary, records


def test_summary_records_the_fault_and_what_was_done(tmp_path, capsys) -> None:
    out = str(tmp_path / "run")
    rc = main(
        [
            "run",
            MISSION,
            "--quiet",
            "--no-report",
            "--out",
            out,
            "--set",
            "faults.link_drop.at_s=12",
            "--set",
            "faults.link_drop.duration_s=0.5",
        ]
    )
    assert rc == 1
    summary, records = _logged(out)
    s = summary["safety"]
    assert summary["status"] == "ABORTED" and summary["reason"].startswith("safety: link_lost")
    assert s["fault"] == "link_lost" and s["t_s"] == pytest.approx(12.0, abs=0.05)
    assert [a["action"] for a in s["actions"]][-2:] == ["land", "disarm"]
    assert s["final_state"] == "landed" and s["disarmed"] is True
    assert summary["sim"]["landed"] and not summary["sim"]["armed"]
    assert records[-1]["tick"] == summary["ticks"]  # complete to the last tick
    assert records[-1]["bb"]["safety_state"] == "recovering"
    assert "Traceback" not in capsys.readouterr().out


def test_safety_settings_are_validated(tmp_path, capsys) -> None:
    args = ["run", MISSION, "--quiet", "--out", str(tmp_path / "r"), "--set"]
    assert main(args + ["safety.policies.link_lot.hold_s=1"]) != 0
    assert "did you mean 'safety.policies.link_lost'" in capsys.readouterr().err
    assert main(args + ["safety.policies.link_lost.action=pray"]) != 0
    assert "is not one of" in capsys.readouterr().err


def _signalled(tmp_path, sig: int) -> tuple[subprocess.CompletedProcess, dict, list[dict]]:
    out = str(tmp_path / "run")
    exe = os.path.join(os.path.dirname(sys.executable), "btrun")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "bt_engine.cli"]
    proc = subprocess.Popen(
        cmd + ["run", MISSION, "--quiet", "--no-report", "--realtime", "20", "--out", out],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    log = os.path.join(out, "ticks.jsonl")

    def flying() -> bool:  # mission time > 8 s in the tick log
        if not os.path.exists(log):
            return False
        _, recs = read_log(log)
        return bool(recs) and recs[-1]["t"] > 8.0

    try:
        wait_until(flying, 60.0, "btrun to log 8 s of mission time", 0.05)
    except AssertionError:
        proc.kill()
        proc.communicate(timeout=10)
        raise
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    summary, records = _logged(out)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), summary, records


@pytest.mark.slow  # a real btrun process flying paced at 20x real time
@pytest.mark.parametrize(
    ("sig", "reason"),
    [
        (signal.SIGINT, "operator interrupt (Ctrl-C)"),
        (signal.SIGTERM, "operator interrupt (SIGTERM)"),
        (signal.SIGHUP, "operator interrupt (SIGHUP)"),  # the terminal closed
    ],
)
def test_signal_halts_lands_and_writes_the_summary(tmp_path, sig, reason) -> None:
    proc, summary, records = _signalled(tmp_path, sig)
    assert proc.returncode == 1, proc.stderr
    assert summary["status"] == "ABORTED" and summary["reason"] == reason
    s = summary["safety"]
    assert s["fault"] == "operator_interrupt"
    assert s["final_state"] == "landed" and s["disarmed"]
    assert records[-1]["tick"] == summary["ticks"]
    assert "Traceback" not in proc.stderr


@pytest.mark.slow  # a real btrun process in a pseudo-terminal, paced at 20x real time
def test_a_closed_terminal_lands_the_drone_and_btrun_writes_its_summary(tmp_path) -> None:
    """btrun in its own terminal (the session leader, as a login shell's job is) whose
    terminal goes away in flight: SIGHUP stops the run as SIGTERM does, the writes to the
    dead terminal (EIO) stop the display, not the run, and btrun itself writes the record."""
    import fcntl
    import termios

    out = str(tmp_path / "run")
    exe = os.path.join(os.path.dirname(sys.executable), "btrun")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "bt_engine.cli"]
    master, slave = os.openpty()

    def own_terminal() -> None:  # in the child: a new session whose terminal is the pty
        os.setsid()
        fcntl.ioctl(slave, termios.TIOCSCTTY, 0)

    proc = subprocess.Popen(
        cmd + ["run", MISSION, "--no-report", "--realtime", "20", "--out", out],
        cwd=REPO,
        stdin=slave,
        stdout=slave,
        stderr=slave,
        preexec_fn=own_terminal,  # noqa: PLW1509 - nothing threaded runs in this process yet
    )
    os.close(slave)
    log = os.path.join(out, "ticks.jsonl")

    def drain() -> None:  # the live view fills the pty's buffer: read it as a terminal would
        import select

        while select.select([master], [], [], 0)[0]:
            try:
                os.read(master, 65536)
            except OSError:
                return

    def flying() -> bool:
        drain()
        if not os.path.exists(log):
            return False
        _, recs = read_log(log)
        return bool(recs) and recs[-1]["t"] > 8.0

    try:
        wait_until(flying, 60.0, "btrun to log 8 s of mission time", 0.05)
    finally:
        os.close(master)  # the terminal goes away: the kernel hangs up its session
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    summary, records = _logged(out)
    assert proc.returncode == 1
    assert summary["status"] == "ABORTED", summary["reason"]
    assert summary["reason"] == "operator interrupt (SIGHUP)"
    assert summary.get("written_by") != "guard"  # btrun's own record, blackboard and all
    assert summary["safety"]["final_state"] == "landed" and summary["safety"]["disarmed"]
    assert records[-1]["tick"] == summary["ticks"]
