"""Shared helpers of the CRTP emulator / cflib link tests (real sockets on 127.0.0.1 only)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from helpers import wait_until

from drivers.rig.loader import load_rig
from drivers.sim.emulators.sitl import SitlSession


@contextmanager
def sitl_session(seed: int = 0, **rig_over: str) -> Iterator[SitlSession]:
    """A started emulator (default sim rig data, no world), stopped afterwards."""
    s = SitlSession(load_rig(None, rig_over or None).data, seed).start()
    try:
        yield s
    finally:
        s.stop()


@contextmanager
def sync_cf(uri: str, timeout_s: float = 5.0) -> Iterator[Any]:
    """cflib ``SyncCrazyflie`` connected and with parameters read (every wait bounded)."""
    from cflib.crazyflie import Crazyflie
    from cflib.crazyflie.syncCrazyflie import SyncCrazyflie

    from drivers.crazyflie.cflib_link import init_drivers

    init_drivers()
    scf = SyncCrazyflie(uri, cf=Crazyflie())
    th = threading.Thread(target=scf.open_link, daemon=True)
    th.start()
    th.join(timeout_s)
    assert not th.is_alive() and scf.is_link_open(), "SyncCrazyflie.open_link did not finish"
    try:
        wait_until(scf.is_params_updated, timeout_s, "cflib to read the parameter values")
        yield scf
    finally:
        scf.close_link()
