"""The lock-step tick budget on a busy host: a tick slowed by other processes sharing the
cores is not a hang (the simulated drone waits for the tree), so the budget stretches with
the host's load; real time keeps its budget (a drone is waiting)."""

from __future__ import annotations

import os
import time

import pytest

from bt_engine import watchdog as wd


def test_busy_factor_is_the_load_per_cpu_between_1_and_the_cap(monkeypatch):
    cpus = os.cpu_count() or 1
    monkeypatch.setattr(wd.os, "getloadavg", lambda: (0.1, 0.1, 0.1))
    assert wd.busy_factor() == 1.0
    monkeypatch.setattr(wd.os, "getloadavg", lambda: (3.0 * cpus, 0.0, 0.0))
    assert wd.busy_factor() == pytest.approx(3.0)
    monkeypatch.setattr(wd.os, "getloadavg", lambda: (1000.0 * cpus, 0.0, 0.0))
    assert wd.busy_factor() == wd.MAX_BUSY_FACTOR


@pytest.mark.parametrize("real_time, fires", [(False, False), (True, True)])
def test_a_slow_tick_on_a_busy_host(monkeypatch, real_time, fires):
    cpus = os.cpu_count() or 1
    monkeypatch.setattr(wd.os, "getloadavg", lambda: (8.0 * cpus, 0.0, 0.0))
    stops: list[str] = []
    w = wd.TickWatchdog(0.1, real_time=real_time, request_stop=stops.append)
    try:
        w.start_tick(1)
        try:
            deadline = time.monotonic() + 0.5  # 5 budgets; 8 x 0.1 s in lock-step
            while time.monotonic() < deadline:
                time.sleep(0.01)
        except wd.TickOverrun:
            pass
        w.end_tick()
    finally:
        w.close()
    assert bool(stops) == fires
    if fires:
        assert "within 0.1 s" in stops[0]


def _tick_with_progress(real_time: bool, progress_for_s: float, tick_s: float) -> list[str]:
    """One tick of ``tick_s`` that does bounded work (a face textured) every 20 ms for
    its first ``progress_for_s``; budget 0.1 s. The reasons the watchdog stopped it for."""
    last: list[float | None] = [None]
    stops: list[str] = []
    w = wd.TickWatchdog(
        0.1, real_time=real_time, request_stop=stops.append, progress=lambda: last[0]
    )
    try:
        w.start_tick(1)
        start = time.monotonic()
        try:
            while (now := time.monotonic()) < start + tick_s:
                if now < start + progress_for_s:
                    last[0] = now  # a face textured
                time.sleep(0.02)
        except wd.TickOverrun:
            pass
        w.end_tick()
    finally:
        w.close()
    return stops


def test_a_lock_step_tick_that_makes_progress_is_not_a_hang():
    """The first frame facing a larger site's racks textured over 10 s of pallet faces in
    one lock-step tick, and the watchdog stopped a healthy run: the budget now counts from
    the tick's last progress (bounded work: each face once)."""
    assert _tick_with_progress(False, progress_for_s=0.6, tick_s=0.65) == []  # 6 budgets
    # progress that stops: a hang from then on, stopped a budget later
    stops = _tick_with_progress(False, progress_for_s=0.3, tick_s=1.0)
    assert len(stops) == 1 and "within 0.1 s" in stops[0]
    # real time keeps its budget: a drone is waiting
    assert len(_tick_with_progress(True, progress_for_s=0.6, tick_s=0.65)) == 1


def test_the_guard_counts_a_lock_step_tick_from_its_last_progress(monkeypatch):
    """The guard process gets the tick's running time in each heartbeat: with progress,
    from its last progress (the guard's own limit is two budgets and a grace)."""
    from drivers.guard.client import GuardClient

    last: list[float | None] = [None]
    client = GuardClient("/nonexistent", progress=lambda: last[0])
    sent: list[list] = []
    monkeypatch.setattr(client, "send", lambda msg: sent.append(msg) or True)
    clock = [100.0]
    monkeypatch.setattr("drivers.guard.client.time.monotonic", lambda: clock[0])
    client.before_tick(1.0)  # the tick starts at 100 s
    clock[0] = last[0] = 130.0  # 30 s in, a texture made: running counts from here
    client._send_beat()
    clock[0] = 131.5
    client._send_beat()
    clock[0] = 140.0  # no progress since 130 s
    client._send_beat()
    running = [m[2] for m in sent if m[0] == "hb"]
    assert running[-3:] == [0.0, 1.5, 10.0]
    plain = GuardClient("/nonexistent")
    monkeypatch.setattr(plain, "send", lambda msg: sent.append(msg) or True)
    clock[0] = 200.0
    plain.before_tick(1.0)
    clock[0] = 230.0
    plain._send_beat()
    assert sent[-1][2] == 30.0  # without progress: from the tick's start, as before


def test_the_watchdog_names_the_leaf_that_does_not_return():
    """A leaf finished in one tick is never RUNNING: the watchdog named its parent (the
    Sequence) as where the tick hung. A leaf found on the stack in every look is named; a
    loop of children ticked within the tick (Repeat over AlwaysSuccess) still is not."""
    import threading

    from bt_engine.watchdog import stuck_leaf

    class Node:
        children = ()

        def __init__(self, name):
            self.name, self.loc, self.stop = name, f"m.xml:{len(name)}:1", False
            self.tick_count = 0

        def describe(self):
            return self.name

        def spin(self):
            while not self.stop:
                pass

        def tick(self):  # as BTNode.execute_tick: each call counted
            self.tick_count += 1
            return 1

    class Loop(Node):
        children = (Node("AlwaysSuccess"),)

        def spin(self):
            while not self.stop:
                self.children[0].tick()

    for node, expected in (
        (Node("ProbeSpinner"), " in ProbeSpinner (m.xml:12:1)"),
        (Loop("Repeat"), ""),
    ):
        t = threading.Thread(target=node.spin)
        t.start()
        try:
            time.sleep(0.05)
            assert stuck_leaf(t.ident) == expected
        finally:
            node.stop = True
            t.join()
