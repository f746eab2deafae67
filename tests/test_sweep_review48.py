"""A rescan keeps clear of its neighbours, and a battery a Crazyflie cannot hover on is
refused before flight.

Seed 9005 of the site at the stock's placement limits had a rescan of a pallet standing
0.2 m deep flown at the stand-off from its face: 0.2 m from the rack's front line, into the
corner of a turned neighbour standing out of it. A 25 mAh battery passed the rig check and
landed dead in an aisle (its voltage sagged to the cut-off while it read half full)."""

from __future__ import annotations

import math

import pytest

from bt_engine.cli import main
from nodes.reactive_scan import MIN_MAP_CLEARANCE_M, behind_the_map
from perception.face import FaceEstimate


def _face(depth_m: float, facing_deg: float = 0.0, map_facing: float | None = 0.0):
    """A face whose row stands ``depth_m`` behind the mapped line x = 3 (facing +x)."""
    f = FaceEstimate(math.radians(facing_deg), 3.0 + depth_m, 0.25, -0.6, 0.6, 3, 10, 1, 0.0)
    f.prior = (3.0, 0.0, 0.25)
    f.map_facing_rad = map_facing
    return f


def _clearance(face, s: float, standoff: float) -> float:
    x, _, _ = face.point(s, standoff)
    return 3.0 - x


@pytest.mark.parametrize("depth", [0.0, 0.05, 0.15, 0.2])
def test_a_scan_point_keeps_its_clearance_from_the_mapped_face_line(depth):
    face = _face(depth)
    extra = behind_the_map(face, 0.0, 0.4 - depth)  # as near as a deep face would bring it
    assert _clearance(face, 0.0, 0.4 - depth + extra) >= MIN_MAP_CLEARANCE_M - 1e-9


def test_a_face_standing_out_or_at_the_line_keeps_its_stand_off():
    assert behind_the_map(_face(-0.1), 0.0, 0.4) == 0.0  # 0.5 m from the line already
    assert behind_the_map(_face(0.0), 0.0, 0.4) == 0.0
    assert behind_the_map(_face(0.2, map_facing=None), 0.0, 0.4) == 0.0  # no mapped line


def test_a_turned_face_is_pushed_back_along_its_own_normal_far_enough():
    face = _face(0.2, facing_deg=12.0)
    for s in (-0.8, 0.0, 0.8):
        extra = behind_the_map(face, s, 0.4)
        assert _clearance(face, s, 0.4 + extra) >= MIN_MAP_CLEARANCE_M - 1e-6


def test_the_clearance_covers_the_worst_neighbour_the_site_allows():
    """A neighbour stands out of the line by its depth error plus its corner's swing; the
    drone is a 0.06 m sphere."""
    from drivers.sim.crazyflie_params import crazyflie_params

    worst = 0.15 + 0.6 * math.sin(math.radians(16.2))  # the stock's documented limits
    assert MIN_MAP_CLEARANCE_M > worst + crazyflie_params["radius_m"]


def test_a_battery_a_crazyflie_cannot_hover_on_is_refused(capsys):
    args = ["validate", "--rig", "rigs/site.yaml", "--set", "battery.capacity_mah=25"]
    code = main([*args, "missions/inventory.xml"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "capacity_mah" in err and "25" in err and "50" in err, err


@pytest.mark.slow  # the site's pre-flight checks
def test_an_aisle_too_narrow_to_fly_home_through_is_refused_before_flight(tmp_path, capsys):
    """Rack B 0.9 m from rack A: both drones flew every pass, then found no way home
    (a route keeps 0.45 m from each rack) and landed at the far end of the aisle."""
    import os
    import shutil

    from helpers import REPO

    world = open(os.path.join(REPO, "worlds", "site.yaml"), encoding="utf-8").read()
    narrow = world.replace("{name: B, origin_m: [3.0, 8.4]", "{name: B, origin_m: [0.9, 8.4]")
    assert narrow != world
    (tmp_path / "worlds").mkdir()
    (tmp_path / "worlds" / "site.yaml").write_text(narrow, encoding="utf-8")
    (tmp_path / "rigs").mkdir()
    shutil.copy(os.path.join(REPO, "rigs", "site.yaml"), tmp_path / "rigs" / "site.yaml")
    mission = os.path.join(REPO, "missions", "inventory.xml")
    assert main(["validate", "--rig", str(tmp_path / "rigs" / "site.yaml"), mission]) == 2
    err = capsys.readouterr().err
    assert "inventory.xml:56:19: SweepPass 'pass': no way around the racks" in err, err
    assert "an aisle narrower than 0.9 m" in err
    # the site as it is passes (its checks but the demo gallery's build: a minute here)
    from bt_engine.loading import check_mission
    from bt_engine.preflight import check_before_flight
    from bt_engine.registry import REGISTRY

    spec, problems = check_mission(mission, REGISTRY)
    assert problems == []
    site = os.path.join(REPO, "rigs", "site.yaml")
    assert check_before_flight(spec, site, [], loads=False) == []


@pytest.mark.slow  # a short site sweep (two places)
def test_a_pallet_standing_above_its_beam_is_never_answered_empty(tmp_path):
    """Seed 9006 with pallets up to 0.1 m above their beams: A-03-3 and A-06-1 stand about
    0.1 m high, their blocks above the row the map gives. The pass had answered both
    ``empty`` ("no support block on the place's face"), a pallet gone to the WMS. Blocks
    seen on the face off the row now make the place a rescan, never ``empty``."""
    import csv
    import json

    from drivers.rig.loader import load_rig
    from nodes.gallery.demo import build_gallery
    from nodes.perception_session import PerceptionSession

    # a gallery of the two sides alone, not the site's demo (a 45 s build for this test)
    rig = load_rig("rigs/site.yaml", {"world.stock.placement_error.height_m": "0.1"})
    truth = rig.load_world(9006).places_truth()
    sides = sorted({truth["A-03-3"], truth["A-06-1"]} - {None})
    s = PerceptionSession(rig, log=lambda m: None)
    gallery = str(tmp_path / "two.sqlite")
    build_gallery(gallery, s.world_path(), sides, s.detector(), s.embedder(), s.camera, log=str)
    out = tmp_path / "run"
    code = main(
        ["missions/inventory.xml", "--rig", "rigs/site.yaml", "--seed", "9006", "--quiet"]
        + ["--set", "world.stock.placement_error.height_m=0.1", "--set", "places=A-03-3;A-06-1"]
        + ["--set", f"gallery={gallery}", "--out", str(out), "--no-report", "--no-mcap"]
    )
    assert code == 0
    truth = {p["slot"] for p in json.loads((out / "summary.json").read_text())["sim"]["pallets"]}
    assert {"A-03-3", "A-06-1"} <= truth  # both places hold a pallet
    rows = list(csv.DictReader((out / "inventory.csv").open(encoding="utf-8")))
    assert {r["place"] for r in rows} == {"A-03-3", "A-06-1"}
    for r in rows:
        assert r["answer"] != "empty", r


def test_off_row_sightings_count_only_when_they_stand_on_the_face_plane():
    """Seed 209 with a light gust: an empty place got two sightings 9 cm above its row of
    something behind it, and a rescan it did not need (a battery change, 1,730 -> 1,254
    places per hour). Off-row sightings must stand on the face plane, as strays must."""
    import numpy as np

    from perception.sweep import PlaceWatch, SweepParams

    p = SweepParams()
    w = PlaceWatch("C-08-2", 0.0, np.zeros((3, 3)), np.array([1.0, 0.0, 0.0]))
    w.off_row = [(0.00, 1.00, 0.09), (0.05, 1.03, 0.09), (0.10, 1.06, 0.10)]  # slides
    assert w.off_row_blocks(p.parallax_max_slope, p.parallax_baseline_m) == 0
    w.off_row = [(0.00, 1.00, 0.10), (0.05, 1.005, 0.10), (0.10, 1.01, 0.10)]  # stands
    assert w.off_row_blocks(p.parallax_max_slope, p.parallax_baseline_m) == 1


def test_inventory_csv_lists_every_planned_place_even_when_the_run_ended_early(tmp_path):
    """After an abort the CSV held only the answered places (72 of 144): a WMS import could
    not tell which places were planned and never reached. inventory.json is unchanged (its
    rows are what --resume carries)."""
    import csv
    import json

    from nodes.inventory_log import write_inventory

    row = {"place": "A-01-1", "answer": "103A", "status": "identified"}
    write_inventory(str(tmp_path), [row], ["A-01-1", "A-01-2", "A-01-3"])
    lines = list(csv.DictReader((tmp_path / "inventory.csv").open(encoding="utf-8")))
    assert [(r["place"], r["answer"], r["status"]) for r in lines] == [
        ("A-01-1", "103A", "identified"),
        ("A-01-2", "", "not_scanned"),
        ("A-01-3", "", "not_scanned"),
    ]
    doc = json.loads((tmp_path / "inventory.json").read_text())
    assert [r["place"] for r in doc["rows"]] == ["A-01-1"]


@pytest.mark.slow  # a short aisle sweep (two places and their rescans)
def test_a_pallet_a_fifth_of_a_metre_above_its_beam_is_found_by_the_rescan(tmp_path):
    """The aisle's seed 304 with pallets up to 0.25 m above their beams: A-01-1 and A-04-1
    stand 0.22 m high. The pass sends them to the rescan (blocks off the row), whose
    LocatePallet took sightings within 0.15 m of the mapped row only and answered
    ``empty`` (validation probe: 16 such places of the site, false ``missing``). It now
    takes a row up to its ``rise`` (0.4 m) above the mapped one."""
    import csv

    out = tmp_path / "run"
    code = main(
        ["missions/inventory.xml", "--rig", "rigs/aisle.yaml", "--seed", "304", "--quiet"]
        + ["--set", "world.stock.placement_error.height_m=0.25", "--set", "places=A-01-1;A-04-1"]
        + ["--out", str(out), "--no-report", "--no-mcap"]
    )
    assert code == 0
    rows = {r["place"]: r for r in csv.DictReader((out / "inventory.csv").open(encoding="utf-8"))}
    assert (rows["A-01-1"]["answer"], rows["A-04-1"]["answer"]) == ("106B", "103A"), rows
