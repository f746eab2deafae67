"""Shared fixtures."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import pytest
from helpers import REPO


@pytest.fixture
def repo() -> str:
    return REPO


@pytest.fixture(autouse=True, scope="session")
def _btrun_cache(tmp_path_factory):
    """Generated files (the demo gallery) go to a temporary cache, built once per session:
    with pytest-xdist, one cache for all the session's workers (the demo gallery's build
    holds a lock, so the second worker waits for the first's and reads it)."""
    old = os.environ.get("BTRUN_CACHE_DIR")
    if os.environ.get("PYTEST_XDIST_WORKER"):  # gw0, gw1, ...: the session's folder is shared
        cache = tmp_path_factory.getbasetemp().parent / "btrun-cache"
        cache.mkdir(exist_ok=True)
    else:
        cache = tmp_path_factory.mktemp("btrun-cache")
    os.environ["BTRUN_CACHE_DIR"] = str(cache)
    yield
    if old is None:
        os.environ.pop("BTRUN_CACHE_DIR", None)
    else:
        os.environ["BTRUN_CACHE_DIR"] = old


@pytest.fixture(autouse=True)
def _idle_host_for_watchdogs(monkeypatch):
    """In-process watchdogs see an idle host: in lock-step a loaded host stretches the tick
    budget (bt_engine.watchdog.busy_factor), and the tests that time a budget must not
    depend on what else the machine runs. tests/test_watchdog_busy.py sets its own load."""
    from bt_engine import watchdog

    monkeypatch.setattr(watchdog.os, "getloadavg", lambda: (0.0, 0.0, 0.0))


@dataclass(frozen=True)
class FlightTick:
    """What a shared flight looked like after one tick."""

    t: float  # mission time (s)
    position: tuple[float, float, float]  # the vehicle's (x, y, z)
    running: frozenset[str]  # paths of the nodes RUNNING after the tick


@dataclass(frozen=True)
class SharedFlight:
    """A flight flown once for several tests that only read it: never fly or change it."""

    mission: Any
    runner: Any
    platform: Any
    result: Any  # the RunResult of ``runner.run``
    ticks: list[FlightTick]


@pytest.fixture(scope="session")
def pallet_scan_flight(_btrun_cache) -> SharedFlight:
    """``missions/pallet_scan.xml`` flown once per session on the default simulated rig
    (seed 0, the world's scan pallet 3A, empty blackboard) by ``helpers.sim_mission``,
    with every tick's time, position and RUNNING nodes recorded: the tests that fly exactly
    this mission with these settings just to read what happened share it."""
    from helpers import sim_mission

    m, run, pf = sim_mission(os.path.join(REPO, "missions", "pallet_scan.xml"), blackboard={})
    ticks: list[FlightTick] = []

    def record(_runner) -> None:
        running = frozenset(n.path for n in m.running_nodes())
        ticks.append(FlightTick(m.clock.now(), tuple(pf.vehicle.position), running))

    run.on_tick = record
    result = run.run(max_time_s=300)
    return SharedFlight(m, run, pf, result, ticks)


@pytest.fixture(scope="session")
def postgresql_server():
    """A PostgreSQL server of its own for this session (tests/pg_server.py): initdb into a
    temporary folder, started on a free port, stopped at the end. Skipped, saying why, on a
    machine without PostgreSQL's binaries (``.ci/run`` installs Debian's package)."""
    from pg_server import pg_bin, start_server

    if pg_bin() is None:
        pytest.skip("no PostgreSQL binaries (apt-get install postgresql; .ci/run does)")
    server = start_server()
    yield server
    server.stop()
