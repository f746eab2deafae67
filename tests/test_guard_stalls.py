"""A guard that stops reading (SIGSTOP, a frozen process) must not stop the mission process:
a blocking send to it froze btrun, tick watchdog included, until the guard read again, and
the set-points queued meanwhile were then flown seconds late."""

from __future__ import annotations

import socket
import time

from drivers.guard.client import GuardClient
from drivers.guard.server import STALE_SETPOINT_S, Guard, GuardSettings
from drivers.guard.wire import decode, encode, socket_pair


def test_sending_to_a_guard_that_does_not_read_never_waits(tmp_path):
    ours, theirs = socket_pair()
    ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    client = GuardClient(str(tmp_path))
    client.sock = ours
    t0 = time.monotonic()
    sent = [client.send(["hb", k, None, 30.0, 0.0]) for k in range(5000)]
    assert time.monotonic() - t0 < 2.0  # a blocking send never came back here
    assert sent[0] and not sent[-1] and client.unsent == sent.count(False) > 0
    assert not client.gone  # stopped, not gone
    theirs.setblocking(False)
    while True:  # the guard reads again: so do the sends
        try:
            theirs.recv(65536)
        except BlockingIOError:
            break
    assert client.send(["hb", 1, None, 30.0, 0.0]) and client._unread_since is None
    assert client.longest_unread_s >= 0.0
    theirs.close()
    assert not client.send(["hb"]) and client.gone  # the guard ended


class _Radio:
    """What a cflib link is asked to send (the guard's own rule is under test)."""

    def __init__(self):
        self.sent = []

    def send_position_setpoint(self, *a):
        self.sent.append(a)

    def send_velocity_setpoint(self, *a):
        self.sent.append(a)


def test_a_set_point_queued_while_the_guard_was_stopped_is_not_flown(tmp_path):
    ours, theirs = socket_pair()
    radio = _Radio()
    guard = Guard(theirs, GuardSettings(run_dir=str(tmp_path), mission_pid=0), None)
    guard.link, guard.link_closed = radio, False
    now = time.monotonic()
    guard._handle(["p", 1.0, 0.0, 1.0, 0.0, now - STALE_SETPOINT_S - 3.0], now)  # queued
    guard._handle(["p", 2.0, 0.0, 1.0, 0.0, now - 0.01], now)  # fresh
    assert radio.sent == [(2.0, 0.0, 1.0, 0.0)]
    assert guard.counts["stale_setpoints"] == 1 and guard.stats()["stale_setpoints"] == 1
    # the guard's own sends never wait on a mission process that does not read
    theirs.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    t0 = time.monotonic()
    for _ in range(5000):
        guard._send(["T", [], True])
    assert time.monotonic() - t0 < 2.0 and guard.counts["unsent"] > 0
    assert decode(ours.recv(65536)) == ["T", [], True] and encode(["x"])


def test_a_link_gone_with_its_guard_is_not_waited_on(tmp_path):
    """The guard killed with the cflib link in it: btrun spent its whole recovery time (30 s)
    "landing" over a link that could never come back."""
    from helpers import sim_mission

    from drivers.guard.client import GuardLink
    from drivers.rig.loader import load_rig
    from drivers.safety.policies import SafetyConfig
    from drivers.safety.supervisor import SafetySupervisor

    client = GuardClient(str(tmp_path))
    link = GuardLink(
        client, type("Config", (), {"uri": "radio://0/80/2M", "link_timeout_s": 1.0})()
    )
    assert not link.gone_for_good
    client.gone = True  # the guard process ended (its socket closed) before the goodbye
    assert link.gone_for_good
    _, _, platform = sim_mission(
        "<root BTCPP_format='4'><BehaviorTree ID='M'><AlwaysSuccess/></BehaviorTree></root>"
    )
    sup = SafetySupervisor(
        SafetyConfig.from_dict(load_rig(None).data["safety"]), platform.vehicle, platform
    )
    platform.vehicle.link.gone_for_good = True
    t0 = sup._now()
    assert sup._wait(lambda: False, 30.0, t0 + 30.0) is False and sup._now() == t0
