"""The pallet-scan mission end to end on the simulator: detection beside the scan, re-scan,
identification of every demo pallet side, enrolment, and every perception failure ending
with the drone on the ground."""

from __future__ import annotations

import os

import numpy as np
import pytest
from helpers import REPO, sim_mission

from drivers.sim.renderers import register_renderer

PALLET_SCAN = os.path.join(REPO, "missions", "pallet_scan.xml")
ENROLL = os.path.join(REPO, "missions", "enroll_pallet.xml")


def fly(path=PALLET_SCAN, side="3A", seed=0, blackboard=None, watch=None, overrides=None):
    """Fly a mission file (or XML text) with ``side`` at the scan slot: (mission, platform,
    result or None when ``watch(mission, platform)`` is called every tick instead)."""
    over = {"world.scan_pallet": side, **(overrides or {})}
    m, run, pf = sim_mission(path, seed=seed, overrides=over, blackboard=blackboard or {})
    m.run = run  # for messages() and took_off()
    if watch is None:
        result = run.run(max_time_s=400)
    else:
        run.run_until(lambda mm: watch(mm, pf) or mm.status.value != "RUNNING", 40_000)
        result = None
    return m, pf, result


def messages(m) -> str:
    """Everything the leaves logged during the run."""
    return " | ".join(msg for rec in m.run.trace for msg in rec.get("messages", ()))


def running(m, name: str) -> bool:
    """True if a node called ``name`` (the scan's or the re-scan's) is RUNNING."""
    return any(p.endswith("/" + name) and st == "RUNNING" for p, st in m.statuses().items())


def is_running(paths, name: str) -> bool:
    """``running`` on recorded paths of the RUNNING nodes (a shared flight's ticks)."""
    return any(p.endswith("/" + name) for p in paths)


def took_off(m) -> bool:
    """True if the take-off leaf ever ran."""
    return any(p.endswith("/takeoff") for rec in m.run.trace for p in rec.get("changed", {}))


@pytest.mark.slow
@pytest.mark.parametrize("side", [f"{n}{s}" for n in "12345" for s in "AB"])
def test_every_demo_pallet_side_is_identified(side):
    m, pf, result = fly(side=side, seed=1)
    assert result.status == "SUCCESS", result.reason
    bb = m.blackboard
    assert bb["pallet_id"] == side
    assert bb["block_count"] == 3
    th = m.ctx.resources["perception"].identifications[-1]["thresholds"]
    assert bb["match_distance"] <= th[0] and bb["match_margin"] >= th[1]
    ranking = bb["match_ranking"]
    assert ranking[0][0] == side and len(ranking) == 5
    assert [d for _, d in ranking] == sorted(d for _, d in ranking)
    assert pf.vehicle.is_landed and not pf.vehicle.is_crashed


@pytest.mark.slow
def test_detection_runs_beside_the_scan_and_stops_it_when_three_blocks_are_in(
    pallet_scan_flight,
):
    # the shared flight (conftest.py) is fly() with its defaults: side 3A (the world's),
    # seed 0, empty blackboard
    both = [
        tick.t
        for tick in pallet_scan_flight.ticks
        if is_running(tick.running, "detect_blocks") and is_running(tick.running, "scan_face")
    ]
    m = pallet_scan_flight.mission
    assert m.status.value == "SUCCESS"
    assert len(both) > 100  # many ticks with both branches running
    session = m.ctx.resources["perception"]
    assert [s.count for s in session.scans] == [3]
    assert session.frames > 60  # frames consumed as they arrived (15 fps), not one snapshot
    scan = session.scans[0]
    assert scan.frames == sorted(scan.frames) and len(set(scan.frames)) == 3
    assert all(c.ndim == 3 and c.shape[2] == 3 and c.shape[1] >= 8 for c in scan.crops)


@pytest.mark.slow
def test_same_seed_same_answer():
    a, _, _ = fly(side="2B", seed=5)
    b, _, _ = fly(side="2B", seed=5)
    assert a.blackboard["match_distance"] == b.blackboard["match_distance"]
    assert a.ctx.resources["perception"].frames == b.ctx.resources["perception"].frames


@pytest.mark.slow
def test_missed_block_triggers_one_rescan():
    """The camera stalls while block 2 passes (shorter than DetectBlocks' stall time-out,
    made longer for this test): the first scan commits two blocks, the re-scan (locate
    again, align, scan) all three."""
    text = (
        open(PALLET_SCAN)
        .read()
        .replace(
            '<DetectBlocks name="detect_blocks"',
            '<DetectBlocks name="detect_blocks" stall_timeout="6"',
        )
    )

    def watch(m, pf):
        # blind while block 2 (y = -0.05) crosses the image during the first scan only
        session = m.ctx.resources.get("perception")
        first_scan = session is not None and len(session.scans) == 1
        y = pf.vehicle.position[1]
        pf.camera.stalled = first_scan and running(m, "detect_blocks") and -0.25 < y < 0.12

    m, pf, _ = fly(text, side="4B", seed=2, watch=watch)
    assert m.status.value == "SUCCESS"
    counts = [s.count for s in m.ctx.resources["perception"].scans]
    assert counts[0] < 3 and counts[-1] == 3 and len(counts) == 2
    assert m.blackboard["pallet_id"] == "4B"
    assert pf.vehicle.is_landed


def test_camera_stall_during_the_scan_lands_without_an_answer():
    state = {}

    def watch(m, pf):
        if running(m, "detect_blocks"):
            state.setdefault("t0", m.clock.now())
        if "t0" in state and m.clock.now() - state["t0"] > 3.0:
            pf.camera.stalled = True

    m, pf, _ = fly(watch=watch)
    assert m.status.value == "FAILURE"
    assert "camera stalled" in messages(m) and "detect_blocks" in m.last_failure
    assert "pallet_id" not in m.blackboard or m.blackboard["pallet_id"] is None
    assert pf.vehicle.is_landed and not pf.vehicle.is_crashed
    # it came back to the take-off point before landing
    x, y, _ = pf.vehicle.position
    assert abs(x) < 0.1 and abs(y) < 0.1


def _wrong_size_renderer(**_):
    return lambda pose, t_s, previous=None: np.zeros((240, 320), np.uint8)


register_renderer("test_wrong_size", _wrong_size_renderer)


@pytest.mark.slow
def test_frames_of_the_wrong_size_fail_the_scan_and_land():
    m, pf, result = fly(overrides={"sensors.camera.renderer": "test_wrong_size"})
    assert result.status == "FAILURE"
    assert "(240, 320)" in messages(m) and "324x244" in messages(m)
    assert pf.vehicle.is_landed and not pf.vehicle.is_crashed


def test_missing_weights_stop_the_mission_on_the_ground(tmp_path):
    text = (
        open(PALLET_SCAN)
        .read()
        .replace(
            '<PerceptionReady name="perception_ready"',
            f'<PerceptionReady name="perception_ready" detector="{tmp_path}/none.pt"',
        )
    )
    m, pf, result = fly(text)
    assert result.status == "FAILURE"
    assert "none.pt" in messages(m) and "perception_ready" in m.last_failure
    assert not took_off(m) and pf.vehicle.is_landed


@pytest.mark.slow
def test_enrol_then_identify_with_your_own_gallery(tmp_path):
    gallery = str(tmp_path / "pallets.sqlite")
    m, pf, result = fly(
        ENROLL, side="5A", seed=3, blackboard={"pallet": "P-005A", "gallery": gallery}
    )
    assert result.status == "SUCCESS", result.reason
    assert m.blackboard["gallery_size"] == 1
    assert m.ctx.resources["perception"].result_lines()[-1] == f"enrolled: P-005A in {gallery}"
    m, pf, result = fly(
        ENROLL, side="1B", seed=4, blackboard={"pallet": "P-001B", "gallery": gallery}
    )
    assert result.status == "SUCCESS", result.reason
    m, pf, result = fly(side="5A", seed=5, blackboard={"gallery": gallery})
    assert result.status == "SUCCESS", result.reason
    assert m.blackboard["pallet_id"] == "P-005A"


def test_empty_or_missing_gallery_is_refused_before_take_off(tmp_path):
    m, pf, result = fly(blackboard={"gallery": str(tmp_path / "nothing.sqlite")})
    assert result.status == "FAILURE"
    assert "does not exist" in messages(m)
    assert not took_off(m)


def test_a_rig_without_a_camera_is_refused_before_take_off():
    m, pf, result = fly(overrides={"sensors.camera.renderer": "none"})
    assert result.status == "FAILURE" and not took_off(m)
    # the reason names the leaf, its place in the file and what to change
    assert "perception_ready" in result.reason and "pallet_scan.xml:" in result.reason
    assert "sensors.camera.renderer=pallet" in result.reason
