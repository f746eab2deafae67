"""One drone, one mission: a second link to an address another process holds is refused
before anything is sent to the drone, and the lock never outlives its holder."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from helpers import REPO

from drivers.crazyflie.cflib_link import CrazyflieLink, CrazyflieLinkConfig
from drivers.crazyflie.link_lock import LinkInUse, LinkLock, lock_path

URI = "udp://127.0.0.1:1/btrun-lock-test"

HOLD = textwrap.dedent(
    """
    import sys, time
    from drivers.crazyflie.link_lock import LinkLock
    LinkLock(sys.argv[1]).acquire()
    print("held", flush=True)
    time.sleep(60)
    """
)


def _holder(uri: str) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, uri], cwd=REPO, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_holder_is_refused_with_who_holds_it_and_the_lock_dies_with_its_holder():
    proc = _holder(URI)
    try:
        with pytest.raises(LinkInUse) as info:
            LinkLock(URI).acquire()
        msg = str(info.value)
        assert msg.startswith(f"{URI}: in use by another btrun (pid {proc.pid}, since ")
        assert "one drone flies one mission at a time" in msg
    finally:
        proc.kill()  # however the holder ends, the kernel lets the lock go
        proc.wait()
    LinkLock(URI).acquire().release()


def test_the_lock_is_per_address():
    first = LinkLock(URI).acquire()
    try:
        LinkLock(URI + "2").acquire().release()
        assert lock_path(URI) != lock_path(URI + "2")
    finally:
        first.release()
    LinkLock(URI).acquire().release()  # released: free again


def test_a_link_to_a_held_address_fails_before_any_radio_traffic():
    proc = _holder(URI)
    try:
        link = CrazyflieLink(CrazyflieLinkConfig(uri=URI, connect_timeout_s=0.5))
        with pytest.raises(ConnectionError, match="in use by another btrun"):
            link.open()
        assert link.cf is None  # nothing was created, nothing sent
    finally:
        proc.kill()
        proc.wait()
