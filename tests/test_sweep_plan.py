"""The sweep's plan and routes (nodes/sweep_plan.py) and the fleet's face split, on the site
world (worlds/site.yaml): pure geometry, no flight."""

from __future__ import annotations

import math
import os

import pytest

from drivers.sim.world import load_world
from nodes.fleet.plan import split_places
from nodes.sweep_plan import footprints, plan_passes, route

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def site():
    return load_world(os.path.join(REPO, "worlds", "site.yaml"), seed=0)


def test_the_site_has_144_places_on_four_faces_of_two_aisles(site):
    assert len(site.places) == 144
    racks = {p.rack for p in site.places.values()}
    assert racks == {"A", "B", "C", "D"}
    assert {p.level for p in site.places.values()} == {1, 2, 3}
    assert max(p.bay for p in site.places.values()) == 12
    truth = site.places_truth()
    assert sum(v is None for v in truth.values()) == 10
    not_enrolled = set(site.not_enrolled())
    assert sum(1 for v in truth.values() if v in not_enrolled) == 10


def _clear(path, start, racks, clearance):
    pts = [start[:2]] + [p[:2] for p in path]
    return all(
        not r.crosses(a, b, clearance - 1e-6)
        for a, b in zip(pts, pts[1:], strict=False)
        for r in racks
    )


def test_a_route_between_the_aisles_goes_around_the_racks(site):
    racks = footprints(site)
    start, goal = (1.0, -10.0, 1.0), (6.5, 7.0, 1.8)
    straight = any(r.crosses(start[:2], goal[:2], 0.0) for r in racks)
    assert straight  # the straight line would cross rack B/C
    path = route(start, goal, racks, lambda p: 0.1 <= p[0] <= 7.9 and -11 <= p[1] <= 9)
    assert path is not None and len(path) >= 2 and path[-1] == goal
    assert _clear(path, start, racks, 0.45)
    # within one aisle it is straight
    assert route((1.0, -10.0, 1.0), (0.6, 5.0, 0.3), racks) == [(0.6, 5.0, 0.3)]


def test_no_route_when_the_geofence_closes_every_way(site):
    racks = footprints(site)
    assert route((1.0, 0.0, 1.0), (6.5, 0.0, 1.0), racks, lambda p: False) is None


def test_passes_are_a_serpentine_over_each_face_nearest_first(site):
    plan = plan_passes(list(site.places), site, (1.0, -10.0, 1.0))
    assert len(plan.order) == 12
    assert sorted(p for s in plan.passes.values() for p in s.places) == sorted(site.places)
    first = plan.passes[plan.order[0]]
    assert first.rack == "A" and first.places[0] == "A-01-1"  # the face at pad-1's end
    for a, b in zip(plan.order, plan.order[1:], strict=False):
        pa, pb = plan.passes[a], plan.passes[b]
        end = site.places[pa.places[-1]].row_m
        begin = site.places[pb.places[0]].row_m
        # each pass starts at the end where the last one ended (the same face) or, for the
        # next face, the near end of it
        if pa.rack == pb.rack:
            assert abs(pa.level - pb.level) == 1
            assert math.dist(end[:2], begin[:2]) < 0.1
        else:
            assert math.dist(end[:2], begin[:2]) < 4.0
    for spec in plan.passes.values():  # each pass flies its places in bay order
        bays = [site.places[p].bay for p in spec.places]
        assert bays in (sorted(bays), sorted(bays, reverse=True))


def test_a_plan_of_some_places_keeps_only_them(site):
    places = ["C-03-2", "C-04-2", "A-01-1", "C-05-2"]
    plan = plan_passes(places, site, (1.0, -10.0, 1.0))
    assert plan.order == ["A/1", "C/2"]
    assert plan.passes["C/2"].places == ["C-03-2", "C-04-2", "C-05-2"]


def test_the_faces_split_gives_every_drone_whole_faces(site):
    starts = {
        "cf1": (1.0, -10.0, 0.0),
        "cf2": (2.0, -10.0, 0.0),
        "cf3": (6.0, -10.0, 0.0),
        "cf4": (7.0, -10.0, 0.0),
    }
    split = split_places(list(site.places), site, starts, "faces")
    faces = {d: {site.places[p].rack for p in ps} for d, ps in split.items()}
    assert all(len(f) == 1 for f in faces.values())
    assert {next(iter(f)) for f in faces.values()} == {"A", "B", "C", "D"}
    assert all(len(ps) == 36 for ps in split.values())
    # the drones of aisle 1's pads take aisle 1's faces
    assert faces["cf1"] | faces["cf2"] == {"A", "B"}


def test_three_drones_on_four_faces_get_faces_of_one_aisle_each(site):
    """Four faces for three drones: one drone takes two. They used to be dealt largest
    first, and the drone of pad-2 got faces A and D, one in each aisle, while pad-1's got B:
    the two crossed on their way out and held each other up for minutes. Now the drone with
    two faces has both faces of one aisle, and no drone crosses another's way."""
    pads = {"pad-1": (1.0, -10.0, 0.0), "pad-2": (2.0, -10.0, 0.0), "pad-3": (6.0, -10.0, 0.0)}
    aisle = {"A": 1, "B": 1, "C": 2, "D": 2}
    for names in (["pad-1", "pad-2", "pad-3"], ["pad-2", "pad-1", "pad-3"]):
        starts = {f"cf{i}": pads[p] for i, p in enumerate(names)}
        split = split_places(list(site.places), site, starts, "faces")
        faces = {d: {site.places[p].rack for p in ps} for d, ps in split.items()}
        assert sorted(len(ps) for ps in split.values()) == [36, 36, 72]
        assert all(len({aisle[f] for f in fs}) == 1 for fs in faces.values()), faces
        # the drone starting further left flies to the face further left: no crossing
        x = {d: sum(site.places[p].row_m[0] for p in ps) / len(ps) for d, ps in split.items()}
        by_start = sorted(starts, key=lambda d: starts[d][0])
        assert [x[d] for d in by_start] == sorted(x.values()), (faces, starts)


def test_fewer_faces_than_drones_split_by_levels(site):
    places = [p for p in site.places if p.startswith("A-")]
    starts = {"cf1": (1.0, -10.0, 0.0), "cf2": (2.0, -10.0, 0.0)}
    split = split_places(places, site, starts, "faces")
    levels = {d: {site.places[p].level for p in ps} for d, ps in split.items()}
    assert sorted(len(ps) for ps in split.values()) == [12, 24]
    assert not (levels["cf1"] & levels["cf2"])


def test_fewer_face_levels_than_drones_split_by_bays(site):
    places = ["A-02-1", "A-07-1"]
    starts = {"cf1": (1.0, -10.0, 0.0), "cf2": (2.0, -10.0, 0.0)}
    split = split_places(places, site, starts, "faces")
    assert sorted(len(ps) for ps in split.values()) == [1, 1]
