"""Smoke test of bench/tick_overhead.py: the benchmark code runs on tiny trees (no timings)."""

from __future__ import annotations

import pytest
from helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    with bench_module("tick_overhead") as module:
        yield module


def test_shapes_have_the_requested_size(bench):
    for n in (100, 1000):
        assert abs(bench.mission_tree(n).count() - n) <= 0.05 * n
        assert abs(bench.worst_tree(n).count() - n) <= 0.05 * n


def test_engines_agree_on_tiny_trees(bench):
    # two whole missions (3 legs of 3-tick actions) and the all-visited shape
    mission = bench.mission_tree(29, action_ticks=3)
    rates = bench.check_equivalent(mission, 40)
    assert "btrun" in rates and "py_trees" in rates
    worst = bench.worst_tree(14)
    rates = bench.check_equivalent(worst, 5)
    # every condition of the worst case is ticked on every tick, plus the action
    assert rates["btrun"] == sum(1 for _ in _leaves(worst))
    assert len(set(rates.values())) == 1


def _leaves(spec):
    if not spec.children:
        yield spec
    for c in spec.children:
        yield from _leaves(c)


@pytest.mark.slow
def test_measure_and_report_run(bench, capsys):
    shapes = [("mission-20", bench.mission_tree(20, 3)), ("worst-20", bench.worst_tree(20))]
    rows = bench.measure(shapes, bench.ENGINES, budget_s=0.001, rounds=1, min_ticks=5, max_ticks=10)
    labels = {r.engine for r in rows}
    assert {bench.BTRUN, bench.RUN_TRACE, bench.RUN_NOTRACE, bench.RUN_LOG, bench.PYTREES} <= labels
    assert all(len(r.samples) >= 5 and r.cpu_ns >= 0 for r in rows)
    figures = bench.report(rows, {}, 100.0)
    assert ("worst-20", "py_trees") in figures["ratios"]
    assert "ratios of median tick time" in capsys.readouterr().out


def test_jitter_runs_on_a_wall_clock(bench):
    j = bench.jitter(0.1, rate_hz=50.0, nodes=20)
    assert j["ticks"] >= 3
    assert j["p99_ms"] >= 0


@pytest.mark.slow
def test_main_quick(bench, capsys):
    argv = ["--quick", "--sizes", "20", "--budget", "0.001", "--jitter-seconds", "0.1", "--no-fifo"]
    assert bench.main(argv) == 0
    out = capsys.readouterr().out
    assert "checked: same root status" in out
    assert "wall-clock jitter" in out
