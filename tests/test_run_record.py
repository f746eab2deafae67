"""The run's record on a bad day. A disk that fills in flight: the flight goes on and lands,
the tick log stops where it must, and summary.json is still written (the run folder keeps
room for it in reserve; both processes printed a traceback and the run left no summary). A
real-time host that ran late: summary.json says how late."""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import sys

import pytest
from helpers import REPO

from bt_engine import summary as summary_mod


def _small_files(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past it fails, EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


@pytest.mark.slow
def test_a_tick_log_that_cannot_grow_stops_and_the_run_ends_recorded(tmp_path):
    out = tmp_path / "run"
    args = ["missions/square.xml", "--out", str(out), "--no-report", "--no-mcap", "-q"]
    proc = subprocess.run(
        [sys.executable, "-m", "btrun_launcher", *args, "--store", "none"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=_small_files(100_000),
    )
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "SUCCESS" and s["sim"]["landed"], s["reason"]
    assert any(e.startswith("ticks.jsonl: File too large (the tick log stops") for e in s["errors"])
    assert "Traceback" not in proc.stderr and proc.returncode == 0, proc.stderr[-800:]
    assert os.path.getsize(out / "ticks.jsonl") <= 100_000
    assert not (out / summary_mod.SPACE_RESERVE).exists()  # given back


def test_the_reserve_makes_room_for_summary_json(tmp_path, monkeypatch):
    """A full disk refuses summary.json: the reserve is given back and it is written."""
    summary_mod.reserve_space(str(tmp_path), 4096)
    assert os.path.getsize(tmp_path / summary_mod.SPACE_RESERVE) == 4096
    real = summary_mod.atomic_write_text

    def full_until_freed(path, text):
        if os.path.exists(tmp_path / summary_mod.SPACE_RESERVE):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, text)

    monkeypatch.setattr(summary_mod, "atomic_write_text", full_until_freed)
    summary_mod.write_summary(str(tmp_path), {"status": "SUCCESS"})
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "SUCCESS" and "No space left on device" in s["errors"][0]
    with pytest.raises(OSError):  # no reserve left: the error stands
        monkeypatch.setattr(
            summary_mod,
            "atomic_write_text",
            lambda p, t: (_ for _ in ()).throw(OSError(errno.ENOSPC, "full")),
        )
        summary_mod.write_summary(str(tmp_path), {"status": "SUCCESS"})


def test_late_ticks_and_skipped_slots_are_in_the_summary():
    """Real time on a busy or paused host: the tick log alone showed a 7 s tick period and
    the slots skipped after it; summary.json and the console say it."""
    from bt_engine.runner import RunResult

    periods = [0.01] * 98 + [0.011, 3.0]
    result = RunResult("SUCCESS", "done", 100, 26.0, 13.0, periods, 303, 2.0)
    timing = summary_mod.tick_timing(result, 50.0)
    assert timing == {
        "tick_period_ms": {"nominal": 10.0, "p50": 10.0, "p99": 11.0, "max": 3000.0},
        "late_ticks": 1,
        "slots_skipped": 303,
    }
    line = summary_mod.timing_line({"timing": timing})
    assert line.startswith("timing: the tick period reached 3000 ms") and "303 tick slots" in line
    assert summary_mod.tick_timing(RunResult("SUCCESS", "", 1, 1.0, 1.0), 50.0) is None
    assert (
        summary_mod.timing_line({"timing": {**timing, "late_ticks": 0, "slots_skipped": 0}}) is None
    )
