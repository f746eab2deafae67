"""``btrun`` exits with its code even when a plug-in leaves a thread running that is no
daemon: Python waits for such threads at exit, so btrun had hung after its summary (Ctrl-C
ignored), and the exit code a campaign or CI waits for never came."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from helpers import leaf_plugin_env

from btrun_launcher import EXIT_WAIT_S

BTRUN = os.path.join(os.path.dirname(sys.executable), "btrun")

LEAVES = '''
import threading

from bt_engine.node import SUCCESS, SyncActionNode
from bt_engine.registry import register


@register
class StartsAThread(SyncActionNode):
    """Starts a thread that never ends and is no daemon."""

    def tick_impl(self):
        threading.Thread(target=threading.Event().wait, name="forever", daemon=False).start()
        return SUCCESS


@register
class UsesAPool(SyncActionNode):
    """Runs a job on a thread pool it keeps (its idle workers are no daemons)."""

    def tick_impl(self):
        from concurrent.futures import ThreadPoolExecutor

        type(self).pool = ThreadPoolExecutor(1, thread_name_prefix="pooled")
        self.pool.submit(sum, [1, 2]).result()
        return SUCCESS
'''


def _mission(tmp_path, module: str, leaf: str = "StartsAThread"):
    """The plug-in's environment and a mission of one of its leaves."""
    env = leaf_plugin_env(tmp_path, module, LEAVES)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">'
        f"<{leaf}/></BehaviorTree></root>"
    )
    return env, mission


def test_a_stray_thread_does_not_keep_btrun_from_exiting(tmp_path) -> None:
    env, mission = _mission(tmp_path, "btrun_stray_thread")
    out = tmp_path / "run"
    started = time.monotonic()
    done = subprocess.run(
        [BTRUN, str(mission), "--out", str(out), "-q", "--no-report"],
        env=env,
        capture_output=True,
        text=True,
        timeout=EXIT_WAIT_S + 60,
    )
    assert done.returncode == 0, done.stderr
    assert "exiting with 1 thread(s) still running (forever)" in done.stderr
    assert time.monotonic() - started < EXIT_WAIT_S + 45
    assert json.loads((out / "summary.json").read_text())["status"] == "SUCCESS"


def test_a_ctrl_c_after_the_run_ended_keeps_its_exit_code(tmp_path) -> None:
    """A second Ctrl-C just after a run ended came while Python tore itself down, its
    signal handlers back to the default: the process died of SIGINT (exit code 130, -2 for
    Python) though the run had ended and said so. Here the signal comes while btrun waits
    for the stray thread at its exit: it leaves at once, with the run's code."""
    import signal

    env, mission = _mission(tmp_path, "btrun_stray_thread_2")
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [BTRUN, str(mission), "--out", str(out), "-q", "--no-report"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()  # the result line: the run is over
        assert line.startswith("SUCCESS"), line
        deadline = time.monotonic() + 30
        while not (out / "summary.json").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # btrun is now waiting for the thread (EXIT_WAIT_S)
        started = time.monotonic()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
        assert time.monotonic() - started < EXIT_WAIT_S - 2  # it did not wait on
    finally:
        if proc.poll() is None:
            proc.kill()


def test_an_idle_thread_pool_is_no_stray_thread(tmp_path) -> None:
    """The idle workers of a thread pool (btrun's own verify_0 in every pallet scan) were
    waited for 5 s at exit and called a stray thread: Python's exit wakes them first."""
    env, mission = _mission(tmp_path, "btrun_pool_thread", "UsesAPool")
    out = tmp_path / "run"
    done = subprocess.run(
        [BTRUN, str(mission), "--out", str(out), "-q", "--no-report"],
        env=env,
        capture_output=True,
        text=True,
        timeout=EXIT_WAIT_S + 60,
    )
    assert done.returncode == 0, done.stderr
    assert "still running" not in done.stderr, done.stderr
    assert json.loads((out / "summary.json").read_text())["status"] == "SUCCESS"
