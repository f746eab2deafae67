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
