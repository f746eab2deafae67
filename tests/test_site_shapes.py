"""A site is whatever its world file draws: the sweep's plan and its routes around the racks
do not depend on which way the aisles run. The site turned by 90 deg (aisles along x, racks
facing +-y) gives the same passes and routes, turned (flown: 144/144, docs/performance.md)."""

from __future__ import annotations

import math

import pytest
import yaml
from helpers import REPO

from drivers.sim.world import load_world
from nodes.rack_geometry import footprints, route
from nodes.sweep_plan import pass_line, plan_passes


def _turn(p):
    """(x, y, ...) turned by +90 deg about the origin."""
    return [-p[1], p[0], *p[2:]]


@pytest.fixture(scope="module")
def worlds(tmp_path_factory):
    path = f"{REPO}/worlds/site.yaml"
    with open(path, encoding="utf-8") as f:
        w = yaml.safe_load(f)
    w["floor"].update(origin_m=[-11.5, -2.0], size_m=[23.0, 12.0])
    for lamp in w["lighting"]["lamps"]:
        lamp["position_m"] = _turn(lamp["position_m"])
    for rack in w["racks"]:
        rack["origin_m"] = _turn(rack["origin_m"])
        rack["facing_deg"] = (rack["facing_deg"] + 90) % 360
    for pad in w["pads"]:
        pad["position_m"] = _turn(pad["position_m"])
    slot = w["enrolment_slot"]
    slot["x_m"], slot["y_m"] = _turn([slot["x_m"], slot["y_m"]])
    slot["facing_deg"] = (slot["facing_deg"] + 90) % 360
    turned = tmp_path_factory.mktemp("turned") / "site_turned.yaml"
    turned.write_text(yaml.safe_dump(w))
    return load_world(path, seed=3), load_world(str(turned), seed=3)


def _close(a, b) -> bool:
    return all(math.isclose(x, y, abs_tol=1e-9) for x, y in zip(a, b, strict=True))


def test_the_turned_site_plans_the_same_passes_turned(worlds):
    site, turned = worlds
    assert sorted(site.places) == sorted(turned.places)
    places = sorted(site.places)
    start = (1.0, -10.0, 0.5)  # pad-1, and turned
    a, b = plan_passes(places, site, start), plan_passes(places, turned, tuple(_turn(start)))
    assert a.order == b.order and len(a.order) == 12
    for name in a.order:
        pa, pb = a.passes[name], b.passes[name]
        assert pa.places == pb.places  # the same places in the same flying order
        assert _close(_turn(pa.direction), pb.direction)
        assert math.isclose((pb.look_rad - pa.look_rad) % (2 * math.pi), math.pi / 2, abs_tol=1e-9)
        for p in pa.places:
            assert _close(_turn(pa.rows[p]), pb.rows[p])
        ends_a, ends_b = pass_line(pa, 0.45, 0.5), pass_line(pb, 0.45, 0.5)
        for ea, eb in zip(ends_a, ends_b, strict=True):
            assert _close(_turn(ea), eb)


def test_the_routes_around_the_racks_are_the_same_turned(worlds):
    """From the pads to the far aisle's passes, around rack B/C's end, never over it."""
    site, turned = worlds
    racks_a, racks_b = footprints(site), footprints(turned)
    for start, goal in (
        ((1.0, -10.0, 0.5), (5.45, 8.0, 1.2)),
        ((6.0, 10.0, 0.5), (2.55, -8.0, 0.4)),
    ):
        ra = route(start, goal, racks_a)
        rb = route(tuple(_turn(start)), tuple(_turn(goal)), racks_b)
        assert ra is not None and rb is not None and len(ra) == len(rb) > 1  # around a rack
        for wa, wb in zip(ra, rb, strict=True):
            assert _close(_turn(wa), wb)
