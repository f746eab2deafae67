"""bench/verification.py's plan, bounds and report (no rendering)."""

from __future__ import annotations

import math
from collections import Counter

import pytest
from helpers import bench_module

from perception.expected import ExpectedThresholds


@pytest.fixture(scope="module")
def bench():
    with bench_module("verification") as module:
        yield module


def test_default_plan_is_the_original_one(bench):
    names, looks, jobs = bench.plan("test", 20, 2, 40)
    assert names[0] == "xt0001A" and len(names) == 40
    assert Counter(j.what for j in jobs) == {"enrolled": 80, "look_alike": 80, "never": 40}
    # per round the enrolled sides then their look-alikes, then the never-enrolled sides;
    # the conditions in turn along that order, the seeds as they always were
    assert [j.what for j in jobs[:41]] == ["enrolled"] * 40 + ["look_alike"]
    assert all(j.condition == k % 10 for k, j in enumerate(jobs))
    la = [j for j in jobs if j.what == "look_alike"]
    assert [j.seed for j in la[:2]] == [100_000, 100_001] and la[40].seed == 100_100
    never = [j for j in jobs if j.what == "never"]
    assert never[0].name == "xt5000A" and never[0].seed == 90_000


def test_lookalikes_are_distinct_and_meet_every_condition(bench):
    names, _, jobs = bench.plan("test", 60, 1, 0, lookalikes=12)
    la = [j for j in jobs if j.what == "look_alike"]
    assert len(la) == 120 * 12 and len({(j.name, j.seed) for j in la}) == len(la)
    assert all(j.imitated == j.name[:-1] for j in la)
    for i in (0, 7, 119):
        assert {j.condition for j in la if j.index == i} == set(range(10))
    with pytest.raises(ValueError):
        bench.plan("test", 5000, 1, 0)


def test_interleaved_spreads_the_kinds(bench):
    _, _, jobs = bench.plan("test", 10, 1, 20, lookalikes=4)
    order = bench._interleaved(jobs)
    assert sorted(j.scan for j in order) == list(range(len(jobs)))
    half = Counter(j.what for j in order[: len(order) // 2])
    assert half == {"enrolled": 10, "look_alike": 40, "never": 10}


def test_upper_bound_is_clopper_pearson(bench):
    assert bench.upper_95(0, 3000) == pytest.approx(1 - 0.05 ** (1 / 3000))
    assert bench.upper_95(0, 3000) < 1e-3 < bench.upper_95(0, 2900)  # the rule of three
    assert bench.upper_95(1, 100) == pytest.approx(0.0466, abs=1e-4)
    assert bench.upper_95(5, 5) == 1.0 and bench.upper_95(0, 0) is None


def row(kind, scanned, expected, z, scan, agreement=2.5, rank=1):
    return {
        "kind": kind, "condition": "clean", "scanned": scanned, "expected": expected, "z": z,
        "agreement": agreement, "rank": rank, "distance": 0.3, "open_set": "unknown",
        "scan": scan, "seed": 90_000 + scan,
    }  # fmt: skip


def test_rates_count_scans_pallets_and_accepted(bench, capsys):
    th = ExpectedThresholds(verify_z=3.3, block_z=2.0, max_rank=3)
    rows = [
        row("genuine", "xt0001A", "xt0001", 6.0, 0),
        row("other_enrolled", "xt0001A", "xt0002", 0.1, 0),
        # one never-enrolled side scanned once, against two enrolled pallets: 2 trials, 1 scan
        row("never_enrolled", "xt5000A", "xt0001", 3.5, 1),
        row("never_enrolled", "xt5000A", "xt0002", 3.5, 1, rank=9),
        row("never_enrolled", "xt5000B", "xt0001", 0.2, 2),
        row("look_alike", "xt0001A", "xt0001", 1.0, 3),
        row("look_alike", "xt0001B", "xt0001", 0.5, 4),
    ]
    r = bench.rates(rows, th)
    never = r["never_enrolled"]
    assert (never["trials"], never["scans"], never["pallets"]) == (3, 2, 1)
    assert (never["accepted"], never["accepted_scans"]) == (1, 1)
    assert never["rate"] == pytest.approx(1 / 3) and never["max_z"] == 3.5
    assert never["upper_95_scans"] > never["upper_95"]
    look = r["look_alike"]
    assert (look["trials"], look["scans"], look["pallets"], look["accepted"]) == (2, 2, 1, 0)
    assert look["upper_95"] == pytest.approx(1 - math.sqrt(0.05))
    bench.report(rows, th, print)
    out = capsys.readouterr().out
    assert "ACCEPTED never_enrolled: xt5000A (seed 90001, clean) as xt0001: z 3.50" in out
    # rows of an older --json have no scan id: a side and a condition make a scan
    old = [{k: v for k, v in x.items() if k not in ("scan", "seed")} for x in rows]
    assert bench.rates(old, th)["look_alike"]["scans"] == 2


def test_workers_need_per_scan_generators(bench):
    with pytest.raises(SystemExit):
        bench.main(["--workers", "2"])
