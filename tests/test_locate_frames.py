"""A place is said empty only when frames taken there reached the detector: a stalled camera
(or, in real time, a host too busy to detect) answered a place holding a pallet ``empty``."""

from __future__ import annotations

import os

import pytest
from helpers import REPO, sim_mission

MISSION = os.path.join(REPO, "missions", "inventory_per_place.xml")


def _answer_with_the_camera_stalled_from(leaf: str | None) -> dict:
    m, run, pf = sim_mission(
        MISSION, seed=0, rig="rigs/aisle.yaml", blackboard={"places": "A-01-1"}
    )

    def watch(mm):
        if leaf and any(
            p.endswith(f"/{leaf}") and st == "RUNNING" for p, st in mm.statuses().items()
        ):
            pf.camera.stalled = True
        return mm.status.value != "RUNNING"

    run.run_until(watch, 100_000)
    assert pf.vehicle.is_landed and not pf.vehicle.is_crashed
    return m.ctx.resources["inventory"].rows["A-01-1"]


@pytest.mark.slow
def test_a_place_looked_at_with_no_frame_is_not_empty():
    """Seed 0's A-01-1 holds 109B. With the camera stalled from the first look on, no frame
    reached the detector: before, LocatePallet's look points passed, "no block seen", and
    the row said empty. Now it looks on until its time-out and the place is not scanned."""
    row = _answer_with_the_camera_stalled_from("locate")
    assert (row["answer"], row["status"], row["blocks_seen"]) == ("", "not_scanned", -1), row
    assert _answer_with_the_camera_stalled_from(None)["answer"] == "109B"  # the camera alive
