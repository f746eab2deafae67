"""The guard process: nothing that happens to btrun leaves the drone flying, and every run
leaves a summary.json.

The flights here are the issue's own command line: a software Crazyflie served by ``btrun sim
serve crazyflie --mocap`` in a process of its own, flown by ``btrun`` through the real cflib
driver (which the guard owns). Then the mission process is blocked holding the GIL, or is
``kill -9``-ed, in flight; afterwards the drone's state is read back through cflib by this
test, independently of btrun.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from helpers import REPO, bench_module, children, cmdline, leaf_plugin_env, wait_until

BTRUN = [sys.executable, "-c", "from bt_engine.cli import main; raise SystemExit(main())"]

PLUGIN_MODULE = '''
"""Guard test plug-in: a leaf blocked in native code that holds the GIL."""

import ctypes

from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import INT, input_port
from bt_engine.registry import register


@register
class HoldTheGil(SyncActionNode):
    """Calls libc sleep() through ctypes.PyDLL: the GIL stays held the whole time."""

    category = "test"
    ports = (input_port("seconds", INT, 1000, "how long to block"),)

    def tick_impl(self) -> NodeStatus:
        ctypes.PyDLL(None).sleep(int(self.get_input("seconds")))
        return SUCCESS
'''

MISSION = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff name="takeoff" height="1.0" speed="0.5"/>
      {middle}
      <Land name="land" speed="0.5"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


@pytest.fixture
def plugin_env(tmp_path):
    """An environment whose btrun loads the GIL-holding leaf."""
    return leaf_plugin_env(tmp_path, "btrun_guard_probe", PLUGIN_MODULE)


def _mission(tmp_path, middle: str) -> str:
    path = tmp_path / "m.xml"
    path.write_text(MISSION.format(middle=middle))
    return str(path)


def _summary(run_dir: str) -> dict | None:
    try:
        with open(os.path.join(run_dir, "summary.json")) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


@pytest.fixture
def emulator():
    """``btrun sim serve crazyflie --mocap`` on a free port, in a process of its own."""
    proc = subprocess.Popen(
        [*BTRUN, "sim", "serve", "crazyflie", "--mocap", "--port", "0"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert "udp://" in line, line
        uri = line.split()[3].rstrip(",")
        yield uri
    finally:
        proc.terminate()
        proc.wait(10)


def _fly_args(uri: str, mission: str, run_dir: str) -> list[str]:
    return [
        *BTRUN,
        mission,
        "--rig",
        os.path.join(REPO, "rigs", "sitl.yaml"),
        "--set",
        "crazyflie.sitl=false",
        "--set",
        f"crazyflie.uri={uri}",
        "--set",
        "crazyflie.pose_source=none",
        "--set",
        "control.pose_source=onboard",
        "--set",
        "aideck.enabled=false",
        "--out",
        run_dir,
        "--quiet",
        "--no-report",
    ]


def read_drone(uri: str) -> dict:
    """The drone's own state through a fresh cflib connection (as the fault campaign reads
    it): height, armed, flying."""
    with bench_module("fault_campaign") as campaign:
        return campaign.drone_state(uri)


def _airborne_in(run_dir: str) -> bool:
    try:
        with open(os.path.join(run_dir, "ticks.jsonl")) as f:
            return '/takeoff":"SUCCESS"' in f.read()
    except OSError:
        return False


def _airborne_btrun(tmp_path, env: dict, uri: str, run_dir: str) -> subprocess.Popen:
    """A btrun flying a long Sleep on the emulator at ``uri``, once it has taken off."""
    mission = _mission(tmp_path, '<Sleep msec="60000"/>')
    proc = subprocess.Popen(
        _fly_args(uri, mission, run_dir),
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_until(lambda: _airborne_in(run_dir), 60, "the take-off")
    except BaseException:
        proc.kill()
        proc.communicate(timeout=10)
        raise
    return proc


@pytest.mark.slow
@pytest.mark.sitl
def test_a_leaf_holding_the_gil_in_flight_ends_landed_exited_and_recorded(
    tmp_path, plugin_env, emulator
) -> None:
    run_dir = str(tmp_path / "run")
    mission = _mission(tmp_path, '<HoldTheGil seconds="1000"/>')
    t0 = time.monotonic()
    proc = subprocess.run(
        _fly_args(emulator, mission, run_dir),
        cwd=REPO,
        env=plugin_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert time.monotonic() - t0 < 90
    assert proc.returncode == -signal.SIGKILL, proc.stderr  # ended by the guard
    assert "taking over" in proc.stderr
    summary = wait_until(lambda: _summary(run_dir), 20, "summary.json")
    guard = summary["guard"]
    assert guard["took_over"] is True
    assert "silent" in guard["reason"]
    assert guard["landing"] == "landed"
    assert guard["mission_process"] == "killed by the guard"
    assert summary["status"] == "ABORTED"
    state = read_drone(emulator)
    assert state["z_m"] < 0.1 and not state["armed"] and not state["flying"], state


@pytest.mark.slow
@pytest.mark.sitl
def test_kill_9_of_btrun_in_flight_ends_landed_within_10_s_and_recorded(
    tmp_path, plugin_env, emulator
) -> None:
    run_dir = str(tmp_path / "run")
    proc = _airborne_btrun(tmp_path, plugin_env, emulator, run_dir)
    try:
        os.kill(proc.pid, signal.SIGKILL)
        killed = time.monotonic()
        proc.wait(10)
        summary = wait_until(lambda: _summary(run_dir), 15, "the guard's summary.json")
        landed_after = time.monotonic() - killed
    finally:
        if proc.poll() is None:
            proc.kill()
    assert landed_after < 10.0
    guard = summary["guard"]
    assert guard["took_over"] is True and "without a goodbye" in guard["reason"]
    assert guard["landing"] == "landed" and guard["from_z_m"] > 0.8
    assert summary["written_by"] == "guard" and summary["status"] == "ABORTED"
    state = read_drone(emulator)
    assert state["z_m"] < 0.1 and not state["armed"] and not state["flying"], state


@pytest.mark.slow
def test_lock_step_run_blocked_holding_the_gil_is_ended_with_a_summary(
    tmp_path, plugin_env
) -> None:
    """A simulated drone dies with its process; the run still ends and is recorded."""
    run_dir = str(tmp_path / "run")
    mission = _mission(tmp_path, '<HoldTheGil seconds="1000"/>')
    proc = subprocess.run(
        [*BTRUN, mission, "--set", "guard.rest_silence_s=1", "--out", run_dir, "--quiet"],
        cwd=REPO,
        env=plugin_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    summary = wait_until(lambda: _summary(run_dir), 10, "summary.json")
    assert summary["guard"]["took_over"] is True
    assert summary["guard"]["mode"] == "watch"
    assert "simulated in the mission process" in summary["guard"]["landing"]
    assert summary["ticks"] > 0 and summary["mission_time_s"] > 0
    # the tick log's last tick, as its reason says (it had given the last heartbeat's)
    with open(os.path.join(run_dir, "ticks.jsonl"), encoding="utf-8") as f:
        last = [json.loads(line) for line in f.read().splitlines()[1:] if line.endswith("}")][-1]
    assert summary["ticks"] == last["tick"] and summary["mission_time_s"] == last["t"]


def test_a_run_that_ends_normally_reports_its_guard_and_leaves_no_process(tmp_path) -> None:
    run_dir = str(tmp_path / "run")
    proc = subprocess.run(
        [*BTRUN, "missions/yaw_test.xml", "--out", run_dir, "--quiet", "--no-report"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    guard = _summary(run_dir)["guard"]
    assert guard["enabled"] is True and guard["took_over"] is False and guard["heartbeats"] > 0
    assert not _alive(guard["pid"]), "the guard process outlived its run"


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] not in ("Z", "X")
    except OSError:
        return False


def test_guard_can_be_turned_off(tmp_path) -> None:
    run_dir = str(tmp_path / "run")
    proc = subprocess.run(
        [*BTRUN, "missions/yaw_test.xml", "--set", "guard.enabled=false"]
        + ["--out", run_dir, "--quiet", "--no-report"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "guard" not in _summary(run_dir)


@pytest.mark.sitl
def test_a_link_the_guard_cannot_open_is_a_located_error(tmp_path) -> None:
    run_dir = str(tmp_path / "run")
    proc = subprocess.run(
        [*BTRUN, "missions/square.xml", "--rig", "rigs/sitl.yaml"]
        + ["--set", "crazyflie.sitl=false", "--set", "crazyflie.uri=udp://127.0.0.1:9"]
        + ["--set", "crazyflie.pose_source=none", "--set", "crazyflie.connect_timeout_s=1"]
        + ["--set", "aideck.enabled=false", "--out", run_dir, "--quiet"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "rigs/sitl.yaml:1:1:" in proc.stderr and "udp://127.0.0.1:9" in proc.stderr


def _watch_guard(rest_silence_s: float = 10.0):
    """A guard in watch mode (no link) on a socket pair, driven by hand: its loop's steps are
    called with explicit times, so the test decides when the machine was paused."""
    import socket as _socket

    from drivers.guard.server import Guard, GuardSettings

    ours, theirs = _socket.socketpair(_socket.AF_UNIX, _socket.SOCK_SEQPACKET)
    settings = GuardSettings(run_dir="/nonexistent", mission_pid=0, rest_silence_s=rest_silence_s)
    return Guard(theirs, settings), ours


def _turn(guard, now: float) -> str | None:
    """One turn of the guard's loop at ``now`` (what Guard.run does after its select)."""
    guard.note_resume(now)
    guard._read(now)
    return guard.why_take_over(now)


def _run(guard, start: float, end: float) -> tuple[float, str | None]:
    """The guard's loop every 5 ms from ``start`` to ``end``: (when, why) of a take-over, or
    (end, None)."""
    t = start
    while t < end:
        t = min(end, t + 0.005)
        why = _turn(guard, t)
        if why is not None:
            return t, why
    return end, None


def test_a_pause_of_the_whole_machine_is_not_the_mission_process_s_silence() -> None:
    """The site fleet was killed once by its own guard ('silent for 10.00 s (limit 10 s)')
    on a host that had stalled: the guard, woken before the mission process, counted the
    pause as the mission's silence. A gap in the guard's own loop is not held against the
    mission process; it gets RESUME_GRACE_S to speak, then silence counts as before."""
    from drivers.guard.server import RESUME_GRACE_S
    from drivers.guard.wire import encode

    guard, mission = _watch_guard(rest_silence_s=10.0)
    t0 = guard.started
    guard.last_loop = t0
    assert _turn(guard, t0 + 0.005) is None
    # the machine pauses for 30 s; the guard wakes first and finds nothing on the socket
    assert _turn(guard, t0 + 30.0) is None
    assert guard.stalls == 1 and guard.longest_stall_s == pytest.approx(29.995)
    # within the grace the mission process speaks: it is in charge again
    assert _turn(guard, t0 + 30.0 + RESUME_GRACE_S / 2) is None
    mission.send(encode(["hb", 7, None, None, 12.0]))
    now = t0 + 30.0 + RESUME_GRACE_S * 0.9
    assert _turn(guard, now) is None and guard.last_rx == now
    # silence while the guard runs (its loop every 5 ms) still ends the run at the limit
    t, why = _run(guard, now, now + 11.0)
    assert why is not None and "silent for 10.0" in why and t == pytest.approx(now + 10.0, abs=0.01)
    assert guard.stalls == 1


def test_after_a_pause_a_silent_mission_process_is_taken_over_once_the_grace_is_out() -> None:
    from drivers.guard.server import RESUME_GRACE_S

    guard, _mission = _watch_guard(rest_silence_s=10.0)
    t0 = guard.started
    guard.last_loop = t0
    assert _turn(guard, t0 + 30.0) is None  # paused: the grace starts
    t, why = _run(guard, t0 + 30.0, t0 + 40.0)
    assert why is not None and why.startswith("the mission process was silent")
    assert t == pytest.approx(t0 + 30.0 + RESUME_GRACE_S, abs=0.01)


def test_after_a_pause_a_tick_s_running_time_gets_the_grace_too() -> None:
    """A heartbeat said one tick had run 5 s of its 22 s; a 30 s pause is not 35 s of tick."""
    from drivers.guard.server import RESUME_GRACE_S
    from drivers.guard.wire import encode

    guard, mission = _watch_guard(rest_silence_s=1000.0)
    t0 = guard.started
    guard.last_loop = t0
    mission.send(encode(["hb", 3, 5.0, 22.0, 1.0]))
    assert _turn(guard, t0 + 0.005) is None
    assert _turn(guard, t0 + 30.0) is None
    t, why = _run(guard, t0 + 30.0, t0 + 40.0)
    assert why is not None and why.startswith("tick 3 has been running")
    assert t == pytest.approx(t0 + 30.0 + RESUME_GRACE_S, abs=0.01)
    # without a pause the same tick is taken over when its time is out, as before
    guard, mission = _watch_guard(rest_silence_s=1000.0)
    t0 = guard.started
    mission.send(encode(["hb", 3, 5.0, 22.0, 1.0]))
    guard.last_loop = t0
    t, why = _run(guard, t0, t0 + 20.0)
    assert why is not None and why.startswith("tick 3") and t == pytest.approx(t0 + 17.0, abs=0.01)
    assert guard.stalls == 0


def _guard_pid(parent: int) -> int | None:
    """The pid of ``parent``'s guard process (``python -m drivers.guard``), once started."""
    return next((p for p in children(parent) if "drivers.guard" in cmdline(p)), None)


@pytest.mark.slow  # a real btrun and its guard, both stopped for 2 s of wall time
def test_a_run_whose_machine_pauses_longer_than_the_silence_limit_goes_on(tmp_path) -> None:
    """Both processes stopped (as a paused virtual machine is) for twice the silence limit,
    the guard continued first: the run goes on and ends as it would have, the pause in the
    guard's figures. Before, the guard took over at once and killed the run."""
    run_dir = str(tmp_path / "run")
    proc = subprocess.Popen(
        [*BTRUN, "missions/pallet_scan.xml", "--set", "guard.rest_silence_s=1"]
        + ["--out", run_dir, "--quiet", "--no-report"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_until(lambda: _airborne_in(run_dir), 120, "the take-off", 0.02)
        guard = wait_until(lambda: _guard_pid(proc.pid), 10, "the guard process")
        os.kill(guard, signal.SIGSTOP)
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(2.0)  # the pause itself: wall time is what is being tested
        os.kill(guard, signal.SIGCONT)
        time.sleep(0.05)  # the guard first, as after a machine's pause: it wakes first
        os.kill(proc.pid, signal.SIGCONT)
        _out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
            proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    summary = _summary(run_dir)
    assert summary["status"] == "SUCCESS"
    assert summary["guard"]["took_over"] is False
    assert summary["guard"]["stalls"] >= 1 and summary["guard"]["longest_stall_s"] > 1.9


@pytest.mark.slow
@pytest.mark.sitl
def test_kill_9_of_the_guard_in_flight_btrun_reaches_the_drone_itself_and_lands_it(
    tmp_path, plugin_env, emulator
) -> None:
    """The guard holds the radio: killed in flight, it took the link with it and the drone
    fell 2 s later (the firmware's watchdog). btrun now opens its own link to the drone
    (the guard's end released the address) within that time, and its safety supervisor
    lands the drone."""
    run_dir = str(tmp_path / "run")
    proc = _airborne_btrun(tmp_path, plugin_env, emulator, run_dir)
    try:
        guard = wait_until(lambda: _guard_pid(proc.pid), 10, "the guard process")
        os.kill(guard, signal.SIGKILL)
        _out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    assert proc.returncode == 1, err
    summary = _summary(run_dir)
    assert summary is not None and summary["status"] == "ABORTED", err
    assert summary["guard"]["guard_gone"] is True
    safety = summary["safety"]
    assert safety["final_state"] == "landed" and safety["disarmed"], safety
    state = read_drone(emulator)
    assert state["z_m"] < 0.1 and not state["armed"] and not state["flying"], state
