"""bench/mission_speed.py's report: figures per variant and the answers check (no flights)."""

from __future__ import annotations

import pytest
from helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    with bench_module("mission_speed") as module:
        yield module


def row(seed: int, pallet_id: str, wall_s: float, rendered: int) -> dict:
    return {
        "seed": seed,
        "side": "1A" if seed == 100 else "1B",
        "code": 0,
        "wall_s": wall_s,
        "cpu_s": wall_s * 0.9,
        "mission_s": 66.0,
        "pallet_id": pallet_id,
        "blocks": [3],
        "rendered": rendered,
        "detected": rendered,
        "stages": {"render": 0.1, "detector": 0.5},
    }


def test_report_prints_the_figures_and_agrees_on_equal_answers(bench, capsys):
    results = {
        "every-frame": [row(100, "1A", 4.0, 356), row(101, "1B", 4.2, 356)],
        "new": [row(100, "1A", 2.0, 130), row(101, "1B", 2.1, 128)],
    }
    assert bench.report(results)
    out = capsys.readouterr().out
    assert "x real time" in out and "CPU s, detector" in out
    assert "2.00x" in out  # 4.1 s / 2.05 s
    assert "identical across variants" in out


def test_report_flags_a_changed_answer(bench, capsys):
    results = {
        "every-frame": [row(100, "1A", 4.0, 356)],
        "new": [row(100, "unknown", 2.0, 130)],
    }
    assert not bench.report(results)
    assert "DIFFERENT answer, seed 100" in capsys.readouterr().out
