"""Ctrl-C during start-up and during a stuck tick, the lock-step tick budget, ticks that never
return, and a killed run's ``run.mcap``.

1. A SIGINT during ``import bt_engine`` could land in importlib's weakref callback, where
   CPython swallows the KeyboardInterrupt, and the mission flew to SUCCESS. The console
   script is now ``btrun_launcher:main``, which records the signal before anything of btrun is
   imported (``btrun_launcher.py``).
2. Ctrl-C while a lock-step tick is stuck waited for the whole tick budget; a second Ctrl-C
   ended with no summary.json. Now the interrupt shortens the budget to about a second.
3. The lock-step budget was 300 s; now 10 s (a slow first tick on the ground keeps the
   600 s rest budget). A tick that swallows the watchdog's stop or sleeps in C is given up:
   the run still ends, with summary.json.
4. A SIGKILLed run's ``run.mcap`` did not open with ``mcap.reader.make_reader``;
   ``btrun replay --repair`` (and ``btrun replay``, ``--resume``) rebuild it.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest
from helpers import REPO, leaf_plugin_env, sim_mission, wait_until
from mcap.reader import make_reader

import nodes  # noqa: F401  (the drone leaves, before the registry snapshot)
from bt_engine import Runner
from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.registry import REGISTRY

SQUARE = os.path.join(REPO, "missions", "square.xml")
PALLET_SCAN = os.path.join(REPO, "missions", "pallet_scan.xml")
BTRUN = os.path.join(os.path.dirname(sys.executable), "btrun")

# ------------------------------------------------------------------ helpers


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env.pop("BTRUN_PLUGINS", None)
    env.update(extra)
    return env


def _summary(run_dir: str) -> dict | None:
    path = os.path.join(run_dir, "summary.json")
    if not os.path.exists(path):
        return None
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def _wait(proc: subprocess.Popen, timeout_s: float) -> tuple[int | None, str, str]:
    """The exit code and output of ``proc`` if it ends within ``timeout_s``; else it is
    killed and the code is None."""
    try:
        out, err = proc.communicate(timeout=timeout_s)
        return proc.returncode, out, err
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=30)
        return None, out, err


#: the console script, run as setup's wrapper runs it, with SIGINT sent from inside a weakref
#: callback at the first import of MODULE: CPython swallows an exception raised there
WEAKREF_SIGINT = """
import os, signal, sys, weakref
from importlib.metadata import entry_points

module = sys.argv[1]
fired = []


class Probe:
    pass


def callback(_ref):
    os.kill(os.getpid(), signal.SIGINT)  # the Python handler runs here, in the callback


def hook(event, args):
    if event == "import" and args[0] == module and not fired:
        fired.append(1)
        probe = Probe()
        ref = weakref.ref(probe, callback)
        del probe


sys.addaudithook(hook)
(ep,) = entry_points(group="console_scripts", name="btrun")
sys.argv = ["btrun", *sys.argv[2:]]
code = ep.load()()
print("FIRED" if fired else "NOT FIRED", file=sys.stderr)
sys.exit(code)
"""


# ------------------------------------------------------------------ 1. Ctrl-C in start-up


@pytest.mark.parametrize("module", ["bt_engine", "bt_engine.runner", "bt_engine.cli"])
def test_a_ctrl_c_swallowed_by_an_import_callback_still_stops_the_run(tmp_path, module) -> None:
    out = str(tmp_path / "run")
    proc = subprocess.run(
        [sys.executable, "-c", WEAKREF_SIGINT, module, SQUARE, "--out", out, "-q", "--no-report"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=_env(),
    )
    assert "FIRED" in proc.stderr.splitlines()[-1], proc.stderr
    assert "SUCCESS" not in proc.stdout, proc.stdout
    assert proc.returncode == 1, proc.stdout + proc.stderr
    s = _summary(out)
    assert s is not None and s["status"] == "ABORTED", s
    assert s["reason"] == "operator interrupt (Ctrl-C)" and s["ticks"] == 0, s


def test_the_console_script_is_the_launcher_and_it_imports_nothing_of_btrun_first() -> None:
    from importlib.metadata import entry_points

    (ep,) = entry_points(group="console_scripts", name="btrun")
    assert ep.value == "btrun_launcher:main"
    with open(os.path.join(REPO, "btrun_launcher.py"), encoding="utf-8") as f:
        tree = ast.parse(f.read())
    top = set()
    for node in tree.body:  # module level: before main() installs the handler
        if isinstance(node, ast.Import):
            top |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            top.add(node.module or "")
    assert top <= {"__future__", "signal", "sys"}, top


def _launched(proc: subprocess.Popen) -> bool:
    """True once btrun's launcher routes the signals (Linux ``/proc``: the process catches
    SIGHUP, which Python's own start-up never does), or the process has ended.

    Before that the interpreter itself is starting (its site imports, the console script's
    ``import re``): a SIGINT there raises KeyboardInterrupt wherever Python happens to be,
    and one raised in importlib's module-lock weakref callback is swallowed by CPython
    (CI, 2026-11-28: "KeyboardInterrupt in <frozen importlib._bootstrap> cb", then the
    square flew to SUCCESS). No code of btrun runs in that window (docs/safety.md)."""
    if proc.poll() is not None:
        return True
    try:
        with open(f"/proc/{proc.pid}/status", encoding="ascii") as f:
            caught = next(ln for ln in f if ln.startswith("SigCgt:")).split()[1]
    except (OSError, StopIteration):  # not Linux, or already gone
        return True
    return bool(int(caught, 16) & (1 << (signal.SIGHUP - 1)))


@pytest.mark.slow  # 20 btrun processes, one after the other
def test_ctrl_c_at_any_point_of_start_up_never_flies_to_success(tmp_path) -> None:
    """SIGINT 0 to 0.95 s after start: start-up, or the first second of a flight paced at 10x
    real time (the square takes 2.3 s then), never after the mission could have ended."""
    outcomes = []
    for i in range(20):
        out = str(tmp_path / f"run{i}")
        proc = subprocess.Popen(
            [BTRUN, SQUARE, "--realtime", "10", "--out", out, "-q", "--no-report"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
            env=_env(),
        )
        # from the moment btrun's own code routes the signals (_launched): before that the
        # interpreter is starting, and a signal between fork and exec is even taken by the
        # handler the child inherited from this test and lost with it
        wait_until(lambda p=proc: _launched(p), 30, "btrun's launcher to start")
        time.sleep(0.05 * i)
        proc.send_signal(signal.SIGINT)
        code, stdout, stderr = _wait(proc, 60)
        s = _summary(out)
        outcomes.append((i, code, s and s["status"]))
        assert code not in (0, None), (i, code, stdout, stderr)
        assert "SUCCESS" not in stdout, (i, stdout)
        assert s is None or s["status"] == "ABORTED", (i, s)
        if s is not None:
            assert s["reason"].startswith("operator interrupt (Ctrl-C)"), (i, s["reason"])
    assert any(o[2] == "ABORTED" for o in outcomes), outcomes


# ------------------------------------------------------------------ 2. Ctrl-C in a stuck tick

SPIN = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <Repeat num_cycles="-1"><AlwaysSuccess/></Repeat>
    </Sequence>
  </BehaviorTree>
</root>
"""


def _start_stuck(tmp_path, mission: str, *argv: str, env: dict | None = None):
    """A ``btrun`` process whose lock-step tick is stuck (the tick log stopped growing)."""
    path = tmp_path / "m.xml"
    path.write_text(mission)
    out = str(tmp_path / "run")
    proc = subprocess.Popen(
        [BTRUN, str(path), "--out", out, "--no-report", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=env or _env(),
    )
    log = os.path.join(out, "ticks.jsonl")
    sizes: list[int] = []

    def stuck() -> bool:
        sizes.append(os.path.getsize(log) if os.path.exists(log) else 0)
        return len(sizes) > 20 and sizes[-1] > 0 and sizes[-1] == sizes[-20]

    try:
        wait_until(stuck, 60, "the tick log to stop growing (the stuck tick)", step_s=0.02)
    except AssertionError:
        proc.kill()
        proc.communicate(timeout=30)
        raise
    return proc, out


def test_ctrl_c_ends_a_stuck_lock_step_tick_at_once_and_writes_the_summary(tmp_path) -> None:
    proc, out = _start_stuck(tmp_path, SPIN, "--tick-budget", "300")
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    code, stdout, stderr = _wait(proc, 20)
    took = time.monotonic() - t0
    assert code == 1, (code, stdout, stderr)
    assert took < 15, took
    s = _summary(out)
    assert s is not None and s["status"] == "ABORTED", (s, stderr)
    assert s["reason"].startswith("operator interrupt (Ctrl-C); watchdog: tick"), s["reason"]
    assert "in Repeat (" in s["reason"], s["reason"]
    assert s["safety"]["fault"] == "operator_interrupt"
    assert s["safety"]["final_state"] == "landed", s["safety"]


def test_a_second_ctrl_c_in_a_stuck_tick_still_writes_the_summary(tmp_path) -> None:
    proc, out = _start_stuck(tmp_path, SPIN, "--tick-budget", "300")
    proc.send_signal(signal.SIGINT)
    time.sleep(0.2)  # a real process between two keystrokes: no simulated clock to step
    proc.send_signal(signal.SIGINT)
    code, stdout, stderr = _wait(proc, 20)
    assert code == 1, (code, stdout, stderr)
    s = _summary(out)
    assert s is not None and s["status"] == "ABORTED", (s, stderr)
    assert s["reason"].startswith("operator interrupt (Ctrl-C)"), s["reason"]
    assert s["sim"]["landed"] or s["safety"]["motors_cut"], s


class _InterruptedSpinTestOnly(SyncActionNode):
    """Calls ``RUNNER.interrupt()`` (Ctrl-C arriving mid-tick) and spins forever."""

    bt_id = "InterruptedSpinTestOnly"
    runner: Runner | None = None

    def tick_impl(self) -> NodeStatus:
        assert self.runner is not None
        self.runner.interrupt()
        while True:
            pass


class _SwallowTestOnly(SyncActionNode):
    """Swallows every stop until ``release`` is set (a leaf with ``except BaseException``)."""

    bt_id = "SwallowTestOnly"
    release = threading.Event()
    swallowed = 0

    def tick_impl(self) -> NodeStatus:
        while not type(self).release.is_set():
            try:
                while not type(self).release.is_set():
                    pass
            except BaseException:  # noqa: BLE001 - the bug under test
                type(self).swallowed += 1
        return SUCCESS


@pytest.fixture
def test_leaves():
    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    REGISTRY.register(_InterruptedSpinTestOnly)
    REGISTRY.register(_SwallowTestOnly)
    try:
        yield
    finally:
        REGISTRY._models, REGISTRY._aliases = saved


def _wrap(body: str) -> str:
    return f"""<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
{body}
  </BehaviorTree>
</root>"""


def test_an_interrupt_shortens_the_budget_even_at_rest(test_leaves, monkeypatch) -> None:
    """Budget 15 s and the drone on the ground (rest budget 30 s here): the interrupt that
    arrives during the tick still ends it about a second later."""
    import bt_engine.runner as runner_mod

    monkeypatch.setattr(runner_mod, "REST_TICK_BUDGET_S", 30.0)
    m, _, platform = sim_mission(_wrap("    <InterruptedSpinTestOnly/>"))
    run = Runner(m, hooks=[platform], tick_budget_s=15, at_rest=lambda: True)
    _InterruptedSpinTestOnly.runner = run
    t0 = time.monotonic()
    result = run.run(max_time_s=5)
    assert time.monotonic() - t0 < 10
    assert result.status == "ABORTED"
    assert result.reason.startswith("operator interrupt (Ctrl-C); watchdog: tick 1 did not"), (
        result.reason
    )


# ------------------------------------------------------------------ 3. budgets, give-up


def test_the_lock_step_default_budget_is_seconds_not_minutes() -> None:
    from bt_engine import run_cmd
    from bt_engine.runner import REST_TICK_BUDGET_S

    assert run_cmd.LOCKSTEP_TICK_BUDGET_S <= 10
    assert REST_TICK_BUDGET_S >= 300  # a first tick on the ground may build a gallery


def test_a_tick_that_swallows_every_stop_is_given_up_and_the_drone_lands(test_leaves) -> None:
    """The tree runs on a helper thread (the test's main thread must come back); the
    runner's give-up concludes the run from the watchdog thread while the leaf still spins."""
    _SwallowTestOnly.release.clear()
    _SwallowTestOnly.swallowed = 0
    xml = _wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <SwallowTestOnly/>
    </Sequence>"""
    )
    m, _, platform = sim_mission(xml)
    gave_up: list = []

    def on_give_up(runner: Runner) -> None:
        gave_up.append((runner.result, platform.vehicle.is_flying))
        _SwallowTestOnly.release.set()  # what os._exit does for btrun: the leaf stops

    run = Runner(m, hooks=[platform], tick_budget_s=0.3, on_give_up=on_give_up)
    box: list = []
    t = threading.Thread(target=lambda: box.append(run.run(max_time_s=30)), daemon=True)
    t.start()
    t.join(timeout=30)
    _SwallowTestOnly.release.set()
    assert not t.is_alive()
    assert gave_up, "on_give_up was not called"
    result, flying = gave_up[0]
    assert result.status == "ABORTED" and "given up" in result.reason, result
    assert result.reason.startswith("watchdog: tick"), result.reason
    assert not flying  # the shutdown hooks landed it before the hand-over
    assert _SwallowTestOnly.swallowed >= 1
    assert box and box[0] is result  # the main thread, once back, finds the run ended


PLUGIN = '''
"""Test plug-in: a leaf that never returns (spin, swallow every stop, or sleep in C)."""

import time

from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import STRING, input_port
from bt_engine.registry import register


@register
class StuckTestOnly(SyncActionNode):
    """Never returns: spin, swallow (catches every stop) or sleep (time.sleep)."""

    category = "test"
    ports = (input_port("mode", STRING, "spin", "spin, swallow or sleep"),)

    def tick_impl(self) -> NodeStatus:
        mode = self.get_input("mode")
        if mode == "sleep":
            time.sleep(1000)
        while mode == "swallow":
            try:
                while True:
                    pass
            except BaseException:
                pass
        while mode == "spin":
            pass
        return SUCCESS
'''
STUCK = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff height="1.0" speed="0.5"/>
      <StuckTestOnly mode="{mode}"/>
      <Land speed="0.5"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def _plugin_env(tmp_path) -> dict[str, str]:
    return leaf_plugin_env(tmp_path, "btrun_test_stuck", textwrap.dedent(PLUGIN))


@pytest.mark.parametrize("mode", ["swallow", "sleep"])
def test_a_tick_that_never_returns_still_ends_the_run_with_its_summary(tmp_path, mode) -> None:
    """Budget 1 s: stopped at 1 s, given up at 2 s; the process ends by itself with btrun's
    own summary.json (exit 1)."""
    proc, out = _start_stuck(
        tmp_path, STUCK, "--set", f"mode={mode}", "--tick-budget", "1", env=_plugin_env(tmp_path)
    )
    code, stdout, stderr = _wait(proc, 30)
    assert code == 1, (code, stdout, stderr)
    s = _summary(out)
    assert s is not None and s["status"] == "ABORTED", (s, stderr)
    assert "written_by" not in s, s  # btrun's own summary, not an outside guard's
    assert s["reason"].startswith("watchdog: tick") and s["reason"].endswith("given up"), s
    assert s["sim"]["landed"], s["sim"]


@pytest.mark.slow  # waits out the default lock-step budget (10 s)
def test_a_lock_step_spin_ends_within_the_default_budget(tmp_path) -> None:
    proc, out = _start_stuck(tmp_path, SPIN)
    code, stdout, stderr = _wait(proc, 60)
    assert code == 1, (code, stdout, stderr)
    s = _summary(out)
    assert s is not None and s["reason"].startswith("watchdog: tick"), s
    # a busy host stretches the budget, and the reason then says how long it waited
    assert "within 10 s" in s["reason"] or "(the 10 s budget x" in s["reason"], s["reason"]


@pytest.mark.slow  # builds the demo gallery from scratch (about 20 s) and flies the scan
def test_the_pallet_scan_builds_its_gallery_on_the_ground_within_the_new_default(
    tmp_path,
) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    out = str(tmp_path / "run")
    proc = subprocess.run(
        [BTRUN, PALLET_SCAN, "--out", out, "-q", "--no-report"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
        env=_env(BTRUN_CACHE_DIR=str(cache)),
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    s = _summary(out)
    assert s is not None and s["status"] == "SUCCESS", s
    assert s["blackboard"]["pallet_id"] == "3A"


# ------------------------------------------------------------------ 4. a killed run's MCAP


def _read_all(path: str) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def test_a_sigkilled_runs_mcap_is_repaired_for_the_indexed_reader(tmp_path) -> None:
    from bt_engine.replay import mcap_complete

    out = str(tmp_path / "run")
    proc = subprocess.Popen(
        [BTRUN, SQUARE, "--realtime", "3", "--out", out, "-q", "--no-report"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
        env=_env(),
    )
    mcap = os.path.join(out, "run.mcap")
    try:  # at least one 128 KiB chunk on disk: the run is well under way
        wait_until(lambda: os.path.exists(mcap) and os.path.getsize(mcap) > 140_000, 60, "run.mcap")
    finally:
        proc.kill()
        proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    torn = str(tmp_path / "torn.mcap")
    shutil.copy(mcap, torn)
    with pytest.raises(Exception):  # noqa: B017 - whatever the reader trips on
        _read_all(mcap)
    assert not mcap_complete(mcap)

    repair = subprocess.run(
        [BTRUN, "replay", "--repair", out], capture_output=True, text=True, timeout=120
    )
    assert repair.returncode == 0, repair.stderr
    assert "repaired:" in repair.stdout, repair.stdout
    n = _read_all(mcap)
    assert n > 100
    with open(mcap, "rb") as f:
        reader = make_reader(f)
        topics = {c.topic for c in reader.get_summary().channels.values()}
        assert {"/tree/status", "/vehicle/pose", "/tf"} <= topics
        assert any(m.name == "btrun.header" for m in reader.iter_metadata())

    again = subprocess.run(
        [BTRUN, "replay", "--repair", out], capture_output=True, text=True, timeout=120
    )
    assert again.returncode == 0 and "nothing to repair" in again.stdout
    assert _read_all(mcap) == n

    # btrun replay repairs by itself, and reads the same ticks back
    shutil.copy(torn, mcap)
    shown = subprocess.run(
        [BTRUN, "replay", mcap, "--tick", "3"], capture_output=True, text=True, timeout=120
    )
    assert shown.returncode == 0, shown.stderr
    assert "repaired:" in shown.stderr and "tick 3" in shown.stdout
    assert _read_all(mcap) == n


def test_a_file_being_written_is_not_repaired(tmp_path) -> None:
    from bt_engine.replay import mcap_complete, repair_mcap
    from nodes.mcap_log import _lock

    path = str(tmp_path / "run.mcap")
    with open(path, "wb") as f:
        f.write(b"\x89MCAP0\r\n" + b"\x01" * 40)  # torn
        f.flush()
        _lock(f)
        done = repair_mcap(path)
        assert done.in_use and not done.repaired
    assert os.path.getsize(path) == 48  # untouched
    done = repair_mcap(path)  # the writer is gone: nothing in it to recover, left as it is
    assert done.unreadable and not done.repaired and os.path.getsize(path) == 48
    assert not mcap_complete(path)


def test_resuming_a_killed_run_repairs_its_mcap(tmp_path) -> None:
    from bt_engine.cli import main
    from bt_engine.replay import mcap_complete

    first = str(tmp_path / "first")
    assert main([SQUARE, "--out", first, "-q", "--no-report"]) == 0
    mcap = os.path.join(first, "run.mcap")
    with open(mcap, "rb") as f:
        data = f.read()
    with open(mcap, "wb") as f:  # what a kill leaves: no summary, no footer
        f.write(data[: len(data) // 2])
    assert not mcap_complete(mcap)
    second = str(tmp_path / "second")
    assert main([SQUARE, "--resume", first, "--out", second, "-q", "--no-report"]) == 0
    assert mcap_complete(mcap)
    _read_all(mcap)


def test_ctrl_c_stops_a_command_other_than_run_through_the_console_script() -> None:
    """The launcher's recorder must not outlive start-up: `btrun sim serve` (and gallery,
    fleet, campaign) stop on Ctrl-C instead of recording it and running on."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys, btrun_launcher; sys.exit(btrun_launcher.main())"]
        + ["sim", "serve", "crazyflie", "--port", "0"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert "CRTP emulator serving" in proc.stdout.readline()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
