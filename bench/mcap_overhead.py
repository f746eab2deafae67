"""What writing ``run.mcap`` (nodes/mcap_log.py) adds to a run's wall time.

Flies a mission through ``btrun`` in this process (``bt_engine.cli.main``, lock-step, no
report) alternately with and without the recorder (without: ``make_mcap_recorder`` returns
None), ``--rounds`` times each after one warm-up flight (models, gallery), and prints the
median wall time of both and their ratio, plus the recorder's own time per tick. It also
checks that both flights wrote the same ``ticks.jsonl``. It prints figures; it is not a test::

    .venv/bin/python bench/mcap_overhead.py                       # missions/pallet_scan.xml
    .venv/bin/python bench/mcap_overhead.py missions/square.xml --rounds 5
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import statistics
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from bt_engine.cli import main  # noqa: E402
from nodes import mcap_log  # noqa: E402


def fly(mission: str, out: str, record: bool) -> tuple[float, float, int]:
    """One flight: (wall seconds, seconds spent in the recorder, ticks)."""
    real = mcap_log.make_mcap_recorder
    spent = [0.0]

    def timed(*args, **kwargs):
        rec = real(*args, **kwargs)
        if rec is None:
            return None
        for name in ("after_tick", "shutdown"):
            fn = getattr(rec, name)

            def wrap(arg, fn=fn):
                t0 = time.perf_counter()
                try:
                    fn(arg)
                finally:
                    spent[0] += time.perf_counter() - t0

            setattr(rec, name, wrap)
        return rec

    mcap_log.make_mcap_recorder = timed if record else (lambda *a, **k: None)
    try:
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = main([mission, "--seed", "0", "--out", out, "-q", "--no-report"])
        wall = time.perf_counter() - t0
    finally:
        mcap_log.make_mcap_recorder = real
    if code != 0:
        raise SystemExit(f"{mission} ended with exit code {code}")
    with open(os.path.join(out, "ticks.jsonl"), encoding="utf-8") as f:
        ticks = sum(1 for _ in f) - 1
    return wall, spent[0], ticks


def _log(run_dir: str) -> tuple[dict, bytes]:
    """A run's tick log as (header without its wall-clock ``started``, the ticks' bytes)."""
    with open(os.path.join(run_dir, "ticks.jsonl"), "rb") as f:
        header = json.loads(f.readline())["header"]
        header.pop("started", None)
        return header, f.read()


def run(mission: str, rounds: int) -> dict:
    """Fly ``mission`` warm-up + ``rounds`` x (with, without); print and return the figures."""
    with tempfile.TemporaryDirectory() as tmp:
        fly(mission, os.path.join(tmp, "warmup"), True)
        walls: dict[bool, list[float]] = {True: [], False: []}
        spent: list[float] = []
        ticks = 0
        for i in range(rounds):
            for record in (True, False) if i % 2 == 0 else (False, True):
                out = os.path.join(tmp, f"{'with' if record else 'without'}-{i}")
                wall, rec_s, ticks = fly(mission, out, record)
                walls[record].append(wall)
                if record:
                    spent.append(rec_s)
        same = _log(os.path.join(tmp, "with-0")) == _log(os.path.join(tmp, "without-0"))
        size = os.path.getsize(os.path.join(tmp, "with-0", "run.mcap"))
    with_s, without_s = statistics.median(walls[True]), statistics.median(walls[False])
    rec_s = statistics.median(spent)
    print(f"{mission}: {ticks} ticks, {rounds} rounds, median wall time")
    print(f"  without run.mcap  {without_s:7.2f} s")
    print(f"  with run.mcap     {with_s:7.2f} s   ratio {with_s / without_s:.3f}")
    print(
        f"  in the recorder   {rec_s:7.3f} s   ({rec_s / ticks * 1e6:.0f} us per tick, "
        f"{rec_s / without_s:.1%} of the run); run.mcap {size / 1e6:.2f} MB"
    )
    print(f"  ticks.jsonl identical with and without: {same}")
    return {"with_s": with_s, "without_s": without_s, "recorder_s": rec_s, "same": same}


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mission", nargs="?", default=os.path.join(REPO, "missions", "pallet_scan.xml"))
    p.add_argument("--rounds", type=int, default=3, help="flights with and without (default 3)")
    args = p.parse_args(argv)
    run(args.mission, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(cli())
