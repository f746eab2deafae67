"""Perception off the tick thread: the worker takes the newest frame, drops what it cannot
get to (counted), and publishes observations; lock-step detects in the step (the same
tick log as before the worker existed, see tests/test_sim_determinism.py); a real-time run
identifies the pallet with its perception on the worker and models loaded before flight."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import REPO, leaf_plugin_env, wait_until, wrap, xml_mission

from nodes.perception_feed import PerceptionWorker

BTRUN = [sys.executable, "-c", "from bt_engine.cli import main; raise SystemExit(main())"]


class Camera:
    """Frames whose index the test moves on; the worker always sees the newest."""

    def __init__(self) -> None:
        self.index = 0

    def frame(self) -> SimpleNamespace | None:
        if self.index == 0:
            return None
        return SimpleNamespace(index=self.index, t_s=0.1 * self.index, image=None, meta={})


def test_the_worker_takes_the_newest_frame_and_counts_what_it_dropped() -> None:
    cam = Camera()
    busy = threading.Event()
    release = threading.Event()
    seen: list[int] = []

    def detect(frame):
        seen.append(frame.index)
        busy.set()
        release.wait(10)  # a slow model: frames pile up meanwhile
        release.clear()
        return np.zeros((2, 2, 3), np.uint8), [frame.index]

    w = PerceptionWorker(cam.frame, detect, poll_s=0.001)
    try:
        cam.index = 1
        wait_until(busy.is_set, 10, "the first detection")
        busy.clear()
        cam.index = 5  # frames 2, 3, 4 came and went while the model was busy
        release.set()
        wait_until(busy.is_set, 10, "the second detection")
        release.set()
        wait_until(lambda: w.processed == 2, 10, "two observations")
        assert seen == [1, 5]
        assert w.dropped == 3
        obs = w.since(0)
        assert [o.frame.index for o in obs] == [1, 5] and [o.seq for o in obs] == [1, 2]
        assert w.since(1)[0].dets == [5] and w.since(2) == []
    finally:
        release.set()
        w.close()


def test_a_frame_the_models_cannot_take_is_counted_and_the_worker_goes_on() -> None:
    cam = Camera()
    errors: list[str] = []

    def detect(frame):
        if frame.index == 1:
            raise ValueError("camera frame has shape (10, 10); expected 324x244")
        return np.zeros((2, 2, 3), np.uint8), []

    w = PerceptionWorker(cam.frame, detect, on_error=errors.append, poll_s=0.001)
    try:
        cam.index = 1
        wait_until(lambda: w.errors == 1, 10, "the bad frame")
        cam.index = 2
        wait_until(lambda: w.processed == 1, 10, "the next frame")
        assert "expected 324x244" in w.last_error and errors == [w.last_error]
    finally:
        w.close()


@pytest.mark.slow
def test_real_time_pallet_scan_identifies_with_perception_on_the_worker(tmp_path) -> None:
    """At 4x real time (17 s of wall clock), models and gallery loaded before the first
    tick: the first tick comes at once, no tick waits for a model."""
    out = tmp_path / "run"
    proc = subprocess.run(
        [*BTRUN, "missions/pallet_scan.xml", "--realtime", "4", "--out", str(out)]
        + ["--quiet", "--no-report", "--no-mcap"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    p = summary["perception"]
    assert p["mode"] == "worker thread"
    assert p["identifications"][-1]["pallet_id"] == "3A"
    assert p["frames_processed"] > 50 and p["frames_dropped"] >= 0
    assert p["capture_to_decision_ms"]["p95"] > 0
    ticks = [json.loads(line) for line in open(os.path.join(out, "ticks.jsonl"))]
    t = [r["t"] for r in ticks if "tick" in r]
    assert t[0] < 3.0  # one time base: loading before the first tick is not mission time
    gaps = [b - a for a, b in zip(t, t[1:], strict=False)]
    assert max(gaps) < 2.5  # no tick loaded a model or a gallery (4x: 0.6 s of wall time)


def test_lock_step_detects_in_the_tick(tmp_path) -> None:
    out = tmp_path / "run"
    proc = subprocess.run(
        [*BTRUN, "missions/pallet_scan.xml", "--out", str(out), "--no-report", "--no-mcap"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    p = json.loads((out / "summary.json").read_text())["perception"]
    assert p["mode"] == "in the tick" and p["frames_dropped"] == 0
    header = json.loads((out / "ticks.jsonl").read_text().split("\n", 1)[0])["header"]
    assert "before_flight" in header


class SlowOnce:
    """A runner hook whose fifth tick takes 0.3 s of wall time (a slow leaf's stand-in)."""

    def __init__(self) -> None:
        self.n = 0

    def before_tick(self, t_s: float) -> None:
        self.n += 1
        if self.n == 5:
            time.sleep(0.3)  # wall time is the subject here: a real-time tick that overran


def test_real_time_ticks_skip_missed_slots_instead_of_bursting() -> None:
    """After a slow tick the runner resumes its rate: no burst of ticks microseconds apart
    to catch up (the tick log showed ~1,800 ticks in 0.6 s after a 37 s first tick)."""
    from bt_engine.clock import WallClock
    from bt_engine.runner import Runner

    m = xml_mission(wrap('<Sleep msec="600"/>'), clock=WallClock())
    run = Runner(m, rate_hz=50, hooks=[SlowOnce()])
    result = run.run(5.0)
    assert result.status == "SUCCESS"
    after = run.tick_periods_s[5:]
    assert after and min(after) > 0.01, after  # 20 ms period: nothing back to back
    assert result.ticks < 30  # 0.6 s at 50 Hz, less the slots the slow tick took


PREFLIGHT_PLUGIN = '''
from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.registry import register


@register
class LoadsBeforeFlight(SyncActionNode):
    """Logs from its preflight, as PerceptionReady does while it builds a gallery."""

    category = "test"
    ports = ()

    def preflight(self):
        self.ctx.log("loading the test model")
        return []

    def tick_impl(self) -> NodeStatus:
        return SUCCESS
'''


def test_preflight_messages_are_shown_at_once_with_wall_time(tmp_path) -> None:
    env = leaf_plugin_env(tmp_path, "btrun_preflight_probe", PREFLIGHT_PLUGIN)
    mission = tmp_path / "m.xml"
    mission.write_text(wrap("<LoadsBeforeFlight/>"))
    proc = subprocess.run(
        [*BTRUN, str(mission), "--out", str(tmp_path / "run"), "--no-report", "--no-mcap"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    shown = [i for i, line in enumerate(lines) if "loading the test model" in line]
    assert len(shown) == 1, lines  # once, not again at the first tick
    assert lines[shown[0]].startswith("[wall ")
    assert shown[0] < next(i for i, line in enumerate(lines) if "run folder" in line)
