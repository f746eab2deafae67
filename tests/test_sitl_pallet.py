"""The flagship mission through the software-in-the-loop rig: real cflib to the CRTP emulator,
the real CPX stream client to the AI-deck emulator, detection and identification on the
streamed frames, in real time. Shortened (take-off spot near the pallet, faster scan) to
about 25 s of flight."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from helpers import REPO

pytestmark = [pytest.mark.sitl, pytest.mark.slow]  # a real-time flight through the SITL rig


#: real-time flights on a shared host: a flight whose frames a starved host could not keep
#: up with is flown once more; two misses in a row fail
ATTEMPTS = 2


def test_pallet_scan_flies_through_sitl_and_identifies_the_pallet(tmp_path) -> None:
    for attempt in range(1, ATTEMPTS + 1):
        try:
            _fly_and_check(tmp_path / f"try{attempt}")
            return
        except AssertionError:
            if attempt == ATTEMPTS:
                raise


def _fly_and_check(tmp_path) -> None:
    tmp_path.mkdir()
    out = tmp_path / "run"
    btrun = os.path.join(os.path.dirname(sys.executable), "btrun")
    cmd = [btrun, os.path.join(REPO, "missions", "pallet_scan.xml"),
           "--rig", os.path.join(REPO, "rigs", "sitl.yaml"),
           "--set", "sim.start_m=[7.9,-0.8,0]", "--set", "world.scan_pallet=4A",
           "--set", "scan_speed=0.15", "--set", "takeoff_height=0.5",
           "--out", str(out), "--no-report", "--max-time", "90"]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "pallet: 4A (distance " in res.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["blackboard"]["pallet_id"] == "4A"
    p, v = summary["perception"], summary["vehicle"]
    # in real time a first identification may see two blocks when the host is loaded (the
    # frames vary): the answer comes from one that saw all three
    assert p["blocks"] and p["blocks"][-1] == 3 and p["frames_processed"] > 40
    cam = v["camera"]  # every frame came over TCP from the emulated deck
    assert cam["dropped"] == 0 and cam["corrupt"] == 0 and cam["frames_at_vehicle"] > 200
    assert v["sitl"]["landed"] and not v["sitl"]["crashed"]
