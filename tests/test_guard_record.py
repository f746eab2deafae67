"""What the guard says must be true: its record never passes old telemetry off as the
drone's state, a stop of the guard itself is not blamed on btrun, a dead terminal never
stops it before it lands, and a link error is one line."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import time
from types import SimpleNamespace

from drivers.guard import server
from drivers.guard.server import STALE_TELEMETRY_S, Guard, GuardSettings
from drivers.guard.wire import socket_pair


def _tel(z: float = 1.0, armed: bool = True) -> SimpleNamespace:
    return SimpleNamespace(
        x_m=0.5, y_m=0.2, z_m=z, yaw_rad=0.0, armed=armed, motors_running=armed, battery_v=3.9
    )


def _guard(tmp_path, pid: int | None = None) -> Guard:
    _, theirs = socket_pair()
    settings = GuardSettings(run_dir=str(tmp_path), mission_pid=pid or os.getpid())
    return Guard(theirs, settings, None)


def test_the_final_state_says_how_old_its_telemetry_is(tmp_path):
    guard = _guard(tmp_path)
    guard._got_telemetry(_tel())
    final = guard._final()["final"]
    assert final["confirmed"] and final["telemetry_age_s"] <= STALE_TELEMETRY_S
    guard.last_tel_at = time.monotonic() - 34.0  # the guard was stopped; the drone fell
    final = guard._final()["final"]
    assert final["confirmed"] is False and final["telemetry_age_s"] >= 34.0
    assert final["z_m"] == 1.0  # what it last heard, said to be old


def test_a_landing_without_telemetry_says_the_state_is_unknown(tmp_path):
    class _SilentLink:
        connected = False

        def __init__(self):
            self.calls = []

        def poll(self, timeout):
            return []

        def send_position_setpoint(self, *a):
            self.calls.append(a)

        def send_stop_setpoint(self):
            self.calls.append("stop")

        def arm(self, on):
            self.calls.append(("arm", on))

    guard = _guard(tmp_path)
    guard.link, guard.link_closed = _SilentLink(), False
    guard.s.land_max_s = 0.2
    guard._got_telemetry(_tel(z=1.0))
    guard.last_tel_at = time.monotonic() - 10.0
    out = guard.land()
    assert out["landing"] == "no telemetry during the landing: the drone's state is unknown"
    assert out["final"]["confirmed"] is False
    assert ("arm", False) in guard.link.calls  # it still tried


def test_a_stop_of_the_guard_itself_is_said_not_blamed_on_btrun(tmp_path):
    guard = _guard(tmp_path)
    guard.last_loop = time.monotonic() - 34.0  # the guard was stopped for 34 s
    now = time.monotonic()
    guard.note_resume(now)
    guard.last_rx = now - 20.0  # and btrun was silent past its limit (10 s on the ground)
    why = guard.why_take_over(now)
    assert why is not None and "the guard itself had been stopped for 34" in why, why


def test_a_mission_process_that_ended_is_noticed_without_its_socket_closing(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    guard = _guard(tmp_path, pid=proc.pid)
    guard.link, guard.link_closed = object(), False
    guard._got_telemetry(_tel(z=1.0))  # flying, as far as it knows
    why = guard.why_take_over(time.monotonic())
    assert guard.mission_gone
    assert why is not None and why.startswith("the mission process ended without a goodbye")


def test_a_dead_terminal_does_not_stop_the_guard(monkeypatch):
    class _DeadTerminal:
        def write(self, text):
            raise OSError(errno.EIO, "Input/output error")

        def flush(self):
            raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(sys, "stderr", _DeadTerminal())
    server._say("btrun guard: taking over: test")  # no exception: the landing comes next


def test_a_link_error_is_one_line_without_cflibs_traceback():
    exc = Exception(
        "Error communicating with the Crazyflie\nException:[Errno 111] Connection refused\n\n"
        'Traceback (most recent call last):\n  File "udpdriver.py", line 285, in run\n'
        "ConnectionRefusedError: [Errno 111] Connection refused\n"
    )
    assert server._first_line(exc) == (
        "Error communicating with the Crazyflie; Exception:[Errno 111] Connection refused"
    )
    assert server._first_line(ValueError()) == "ValueError"
