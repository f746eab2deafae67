"""The flight report: a real simulated flight end to end, and the pure helpers on synthetic data."""

from __future__ import annotations

import math
import os
import re

import numpy as np
import pytest

import nodes  # noqa: F401  (registers the drone leaves)
from bt_engine import Mission, Runner, SimClock
from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from nodes.report import write_report
from nodes.report.metrics import (
    action_spans,
    motion_metrics,
    rms,
    settle_time,
    short_labels,
    telemetry_arrays,
    wrap_deg,
    wrap_rad,
)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def square_flight():
    clock = SimClock()
    platform = make_platform(load_rig(None), clock, seed=0)
    m = Mission.from_file(
        os.path.join(REPO, "missions", "square.xml"), clock=clock, vehicle=platform.vehicle
    )
    runner = Runner(m, hooks=[platform], telemetry=platform.telemetry_row)
    result = runner.run(max_time_s=120)
    summary = {
        "status": result.status,
        "reason": result.reason,
        "ticks": result.ticks,
        "mission_time_s": result.mission_time_s,
        "wall_time_s": result.wall_time_s,
        "mission": "missions/square.xml",
        "seed": 0,
        "rate_hz": 50.0,
        "sim": platform.summary(),
    }
    return m, runner, summary


def test_report_of_a_simulated_square(square_flight, tmp_path):
    m, runner, summary = square_flight
    assert summary["status"] == "SUCCESS"
    path = write_report(str(tmp_path), runner.trace, summary, m)
    assert path == os.path.join(str(tmp_path), "report.html")
    text = open(path, encoding="utf-8").read()
    pngs = sorted(f for f in os.listdir(tmp_path) if f.endswith(".png"))
    assert {"xy.png", "position.png", "yaw.png", "goto_errors.png", "timeline.png"} <= set(pngs)
    srcs = re.findall(r'<img src="([^"]+)"', text)
    assert sorted(srcs) == pngs  # every PNG is shown, by a relative link to a file that exists
    for f in pngs:
        assert os.path.getsize(tmp_path / f) > 5000
    for needle in (
        "square.xml",
        "SUCCESS",
        "the mission tree returned SUCCESS",
        "seed",
        "max_tracking_error_m",
    ):
        assert needle in text

    motions = m.ctx.resources["motions"]
    assert [r["kind"] for r in motions] == ["TakeOff", "GoTo", "GoTo", "GoTo", "GoTo", "Land"]
    assert text.count('<tr class="motion">') == len(motions)
    rows = motion_metrics(motions, telemetry_arrays(runner.trace))
    assert [r["label"] for r in rows[1:5]] == [f"corner_{i}/goto" for i in range(1, 5)]
    for r in rows:
        assert r["result"] == "SUCCESS"
        assert 0.0 < r["duration"] < 20.0
        assert 0.0 <= r["reach"] <= r["duration"] + 1e-9
        assert 0.0 <= r["track_rms"] <= r["track_max"] < 0.2  # metres, vs the reference
        assert r["final_dist"] <= r["pos_thr"] + 1e-9
        assert abs(r["final_yaw_deg"]) <= r["yaw_thr_deg"]
        assert r["settle"] is not None and 0.0 <= r["settle"] <= r["duration"]
    for r in rows[1:5]:
        assert r["pos_thr"] == pytest.approx(0.03) and r["yaw_thr_deg"] == pytest.approx(15.0)
        assert math.dist(r["goal"], (0, 0, 1)) in (
            pytest.approx(2.0),
            pytest.approx(2 * math.sqrt(2)),
            0.0,
        )


def test_no_vehicle_data_no_report(tmp_path):
    trace = [{"tick": 1, "t": 0.02, "status": "RUNNING", "changed": {"a": "RUNNING"}}]
    assert write_report(str(tmp_path), trace, {"status": "RUNNING"}, None) is None
    assert os.listdir(tmp_path) == []


def test_wrap_and_rms():
    assert wrap_deg(190.0) == pytest.approx(-170.0)
    assert wrap_deg(-190.0) == pytest.approx(170.0)
    assert wrap_deg(180.0) == pytest.approx(-180.0)
    assert np.allclose(wrap_deg([0.0, 359.0, 720.5]), [0.0, -1.0, 0.5])
    assert wrap_rad(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert rms([3.0, 4.0]) == pytest.approx(math.sqrt(12.5))
    assert rms([2.0, math.nan, -2.0]) == pytest.approx(2.0)  # NaN (no reference yet) skipped
    assert math.isnan(rms([]))


def test_settle_time():
    t = np.arange(8) * 0.5
    assert settle_time(t, [0, 0, 1, 1, 0, 1, 1, 1]) == pytest.approx(
        1.5
    )  # entered 1.0, stays from 2.5
    assert settle_time(t, [0, 0, 0, 0, 0, 0, 0, 1]) == pytest.approx(0.0)
    assert settle_time(t, [1] * 8) == pytest.approx(0.0)
    assert settle_time(t, [0, 1, 1, 1, 1, 1, 1, 0]) is None  # left at the end: never settled
    assert settle_time(t, [0] * 8) is None
    assert settle_time([], []) is None


def _synthetic_trace():
    """A 1-D approach to x = 1 with a 4 cm overshoot, yaw near +-180, reference 1 cm ahead."""
    trace = []
    for i in range(1, 201):
        t = i * 0.02
        x = 1.0 - math.exp(-3 * t) + 0.04 * math.exp(-((t - 2.0) ** 2) / 0.05)
        yaw = math.radians(-179.0 if i % 2 else 179.5)
        veh = {
            "x": x,
            "y": 0.0,
            "z": 1.0,
            "yaw": yaw,
            "ref_x": x + 0.01,
            "ref_y": 0.0,
            "ref_z": 1.0,
            "ref_yaw": yaw,
        }
        trace.append({"tick": i, "t": round(t, 6), "status": "RUNNING", "vehicle": veh})
    return trace


def test_motion_metrics_on_synthetic_data():
    tel = telemetry_arrays(_synthetic_trace())
    motion = {
        "node": "T/seq/go",
        "name": "go",
        "kind": "GoTo",
        "goal": [1.0, 0.0, 1.0],
        "goal_yaw_rad": math.pi,
        "pos_threshold_m": 0.03,
        "yaw_threshold_rad": math.radians(15),
        "t_start": 0.02,
        "t_reached": 3.5,
        "t_end": 4.0,
        "result": "SUCCESS",
        "reason": "",
    }
    (row,) = motion_metrics([motion], tel)
    assert row["track_max"] == pytest.approx(0.01) and row["track_rms"] == pytest.approx(0.01)
    assert row["duration"] == pytest.approx(3.98) and row["reach"] == pytest.approx(3.48)
    assert abs(row["final_yaw_deg"]) < 1.5  # 180 - (+-179.x) wraps to a small error
    x = tel["x"]
    first = tel["t"][np.argmax(np.abs(x - 1.0) <= 0.03)]
    outside = np.flatnonzero(np.abs(x - 1.0) > 0.03)
    assert 1.1 < first < 1.3  # entered on the way in (e^-3t = 0.03), then the overshoot left
    assert row["settle"] == pytest.approx(tel["t"][outside[-1] + 1] - first)
    assert 0.8 < row["settle"] < 1.3  # back inside for good shortly after the bump at t = 2 s
    assert row["final_dist"] == pytest.approx(abs(x[-1] - 1.0))


def test_action_spans_from_status_changes():
    trace = [
        {"t": 0.02, "changed": {"S": "RUNNING", "S/a": "RUNNING"}},
        {"t": 0.04},
        {
            "t": 0.06,
            "changed": {"S/a": "IDLE", "S/b": "SUCCESS", "S/c": "RUNNING"},
            "done": {"S/a": "SUCCESS"},
        },
        {"t": 0.08, "changed": {"S/c": "IDLE", "S/d": "RUNNING"}},
        {"t": 0.10, "changed": {"S/d": "FAILURE"}},
        {"t": 0.12, "changed": {"S/d": "RUNNING"}},
        {"t": 0.14},
    ]
    spans = action_spans(trace, ["S/a", "S/b", "S/c", "S/d"])
    assert spans == [
        ("S/a", 0.02, 0.06, "SUCCESS"),
        ("S/b", 0.06, 0.06, "SUCCESS"),  # synchronous: one tick
        ("S/c", 0.06, 0.08, "halted"),
        ("S/d", 0.08, 0.10, "FAILURE"),
        ("S/d", 0.12, 0.14, "running"),  # still running when the trace ends
    ]
    assert short_labels(["T/c1/goto", "T/c2/goto", "T/land"]) == ["c1/goto", "c2/goto", "land"]


def test_numbers_summary_json_keeps_as_text_are_shown_not_multiplied():
    """A one-side gallery's margin is infinite, kept in summary.json as "inf": the report
    multiplied the text and was left empty (0 bytes, TypeError)."""
    from nodes.report.html import _fmt

    assert _fmt("inf") == _fmt(float("inf")) == "\u2014"
    assert _fmt("0.25", ".2f", 100) == "25.00" and _fmt("n/a") == "n/a"
