"""A reader of btrun's output that goes away (``btrun ... | head -1``, a closed terminal)
stops the printing, not the flight: the progress line's BrokenPipeError ended the run as an
internal error."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from helpers import REPO


@pytest.mark.slow
def test_a_closed_stdout_does_not_end_the_flight(tmp_path):
    out = tmp_path / "run"
    args = ["missions/square.xml", "--realtime", "4", "--out", str(out), "--no-report"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "btrun_launcher", *args, "--store", "none"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout.readline().startswith(b"btrun: missions/square.xml")
    proc.stdout.close()  # the reader is gone; the next print hits a broken pipe
    _, err = proc.communicate(timeout=120)
    s = json.loads((out / "summary.json").read_text())
    assert (proc.returncode, s["status"]) == (0, "SUCCESS"), (s["reason"], err[-500:])
    assert b"BrokenPipeError" not in err
