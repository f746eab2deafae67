"""A Ctrl-C or a kill while btrun builds a demo gallery before flight stops the build at
once and cleans up: ``btrun run`` used to hold a Ctrl-C until the build was done (the
whole build: half an hour for a pool of thousands of pallets) and then abort the run;
``btrun validate`` killed by SIGTERM left the build's temporary file in the cache."""

from __future__ import annotations

import glob
import os
import select
import signal
import subprocess
import sys

import pytest
from helpers import REPO

BTRUN = os.path.join(os.path.dirname(sys.executable), "btrun")
RIG = os.path.join(REPO, "rigs", "aisle.yaml")
MISSION = os.path.join(REPO, "missions", "inventory.xml")


def _interrupt_mid_build(argv: list[str], cache: str, sig: int) -> tuple[int, str]:
    """Start ``btrun argv`` with an empty cache; once the build has enrolled its first side
    (its progress line), send ``sig``; the exit code and all it printed (stdout and
    stderr)."""
    env = dict(os.environ, BTRUN_CACHE_DIR=cache)
    env.pop("BTRUN_PLUGINS", None)
    proc = subprocess.Popen(
        [BTRUN, *argv], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    err = b""
    try:
        while b"enrolled " not in err:  # the build is under way
            assert select.select([proc.stdout], [], [], 120)[0], err
            line = proc.stdout.readline()  # type: ignore[union-attr]
            assert line, f"btrun ended before its build: {err!r}"
            err += line
        proc.send_signal(sig)
        rest, _ = proc.communicate(timeout=60)  # not the rest of the build, nor a flight
        return proc.returncode, (err + rest).decode()
    finally:
        if proc.poll() is None:
            proc.kill()


def _galleries(cache: str) -> list[str]:
    return glob.glob(os.path.join(cache, "galleries", "*.sqlite"))


@pytest.mark.slow
def test_ctrl_c_in_a_runs_gallery_build_stops_it_and_flies_nothing(tmp_path):
    cache, out = str(tmp_path / "cache"), str(tmp_path / "run")
    argv = [MISSION, "--rig", RIG, "--out", out, "--no-report"]
    code, err = _interrupt_mid_build(argv, cache, signal.SIGINT)
    assert code == 1, err
    assert "interrupted: the demo gallery was not built" in err
    assert err.rstrip().endswith("interrupted"), err
    assert _galleries(cache) == []  # neither the gallery (the whole build) nor a part of it
    assert not os.path.exists(out)  # no run: nothing took off


@pytest.mark.slow
def test_a_killed_validate_cleans_up_its_gallery_build(tmp_path):
    cache = str(tmp_path / "cache")
    code, err = _interrupt_mid_build(["validate", "--rig", RIG, MISSION], cache, signal.SIGTERM)
    assert code == 1, err  # not killed by the signal (-15): it stopped as on a Ctrl-C
    assert err.rstrip().endswith("interrupted"), err
    assert _galleries(cache) == []  # the temporary file is gone
