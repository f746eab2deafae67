"""`btrun sim serve crazyflie`: a software Crazyflie other tools (cflib, cfclient) connect to."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys

import pytest
from helpers import REPO

pytestmark = pytest.mark.sitl  # the CRTP emulator and cflib over UDP on 127.0.0.1


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_cflib_connects_to_btrun_sim_serve():
    port = _free_udp_port()
    btrun = os.path.join(os.path.dirname(sys.executable), "btrun")
    proc = subprocess.Popen(
        [btrun, "sim", "serve", "crazyflie", "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        cwd=REPO,
    )
    try:
        line = proc.stdout.readline().decode()
        assert f"udp://127.0.0.1:{port}" in line
        code = (
            "import cflib.crtp\n"
            "from cflib.crazyflie import Crazyflie\n"
            "from cflib.crazyflie.syncCrazyflie import SyncCrazyflie\n"
            "cflib.crtp.init_drivers()\n"
            f"with SyncCrazyflie('udp://127.0.0.1:{port}', cf=Crazyflie(rw_cache=None)) as scf:\n"
            "    print('est', scf.cf.param.get_value('stabilizer.estimator'))\n"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 0, out.stderr[-2000:]
        assert "est " in out.stdout
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
