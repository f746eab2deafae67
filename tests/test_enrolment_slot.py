"""Where the demo gallery enrols: a world's ``enrolment_slot`` (default: btrun's canonical
spot, 9.30, 0.0, facing -x). A site of another shape whose racks cover the canonical spot
enrolled its pallets in an open hall unlike its aisles and answered most places
``unknown``; its own spot, chosen to look like the aisles, enrols them where they are seen."""

from __future__ import annotations

import copy

import pytest
import yaml
from helpers import REPO

from drivers.settings import ConfigError
from drivers.sim.world import load_world
from nodes.gallery.demo import demo_gallery_path
from nodes.gallery.enrol_scan import (
    CANONICAL_SLOT,
    _canonical_scan,
    canonical_world_data,
    enrolment_line,
    look_overrides,
)


class Model:
    model_version = "m1"


def _site(tmp_path, name: str, **top) -> str:
    with open(f"{REPO}/worlds/site.yaml", encoding="utf-8") as f:
        site = yaml.safe_load(f)
    site = copy.deepcopy(site)
    site.update(top)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(site))
    return str(path)


def test_the_canonical_line_is_the_one_the_shipped_galleries_were_enrolled_on():
    # x 8.90, y -0.75 -> 0.65, camera yaw 0: the numbers the shipped cache keys stand for
    assert enrolment_line(CANONICAL_SLOT) == (8.9, -0.75, 8.9, 0.65, 0.0)
    # a face looking +y at (2, 3): the camera 0.40 m in front of it looking -y, moving to
    # its left (+x), from 0.75 m right of the face centre to 0.65 m left
    x0, y0, x1, y1, yaw = enrolment_line({"x_m": 2.0, "y_m": 3.0, "facing_deg": 90.0})
    assert yaw == 270.0 and y0 == y1 == pytest.approx(3.4)
    assert (x0, x1) == (pytest.approx(1.25), pytest.approx(2.65))


def test_a_world_enrols_at_its_own_slot_and_its_gallery_is_another(tmp_path):
    site = f"{REPO}/worlds/site.yaml"
    same = _site(tmp_path, "same.yaml", enrolment_slot=dict(CANONICAL_SLOT))
    own = _site(tmp_path, "own.yaml", enrolment_slot={"x_m": 4.0, "y_m": 9.6, "facing_deg": 270})
    # the default written out is the default: the shipped worlds keep their galleries
    assert demo_gallery_path(same, Model, Model, {}) == demo_gallery_path(site, Model, Model, {})
    assert demo_gallery_path(own, Model, Model, {}) != demo_gallery_path(site, Model, Model, {})
    # --set world.enrolment_slot.* is a gallery setting too (its own cache file)
    sets = {"enrolment_slot.y_m": "9.7"}
    assert look_overrides(sets) == sets
    assert demo_gallery_path(own, Model, Model, {}, sets) != demo_gallery_path(
        own, Model, Model, {}
    )
    data = load_world(own).data
    scene = canonical_world_data(data, "1001A")
    assert scene["scan_slot"]["x_m"] == 4.0 and scene["scan_slot"]["facing_deg"] == 270
    assert [r["name"] for r in scene["racks"]] == ["A", "B", "C", "D"]  # none on the spot
    _renderer, poses = _canonical_scan(data, own, "1001A", None, 0)
    # 0.40 m in front of the face (looking -y: y 9.2), 1.4 m along it, facing it (+y)
    assert {round(p.y_m, 9) for p in poses} == {9.2}
    assert poses[0].x_m == pytest.approx(4.75) and poses[-1].x_m == pytest.approx(3.35, abs=0.01)
    assert poses[0].yaw_rad == pytest.approx(1.5707963, abs=1e-6)


def test_a_bad_enrolment_slot_is_located(tmp_path):
    bad = _site(tmp_path, "bad.yaml", enrolment_slot={"x_m": "behind rack F", "y_m": 0.0})
    with pytest.raises(ConfigError) as exc:
        load_world(bad)
    text = str(exc.value)
    assert "bad.yaml:" in text and "enrolment_slot.x_m" in text and "behind rack F" in text


@pytest.mark.slow
def test_a_side_enrolled_at_a_world_slot_facing_along_the_aisle_gives_its_three_blocks(
    tmp_path,
):
    """A slot that faces +y (a direction the canonical line never took): the scan sees the
    side's three blocks, as at the canonical spot."""
    from drivers.rig.loader import load_rig
    from nodes.gallery.enrol_scan import scan_blocks, scan_frames
    from nodes.perception_session import PerceptionSession

    s = PerceptionSession(load_rig("rigs/site.yaml"), log=lambda m: None)
    det = s.detector()
    own = _site(tmp_path, "own.yaml", enrolment_slot={"x_m": 4.0, "y_m": -10.6, "facing_deg": 90})
    crops = scan_blocks(scan_frames(own, "1001A", s.camera, 5), det, s.factors)
    assert len(crops) == 3


def test_validate_says_when_a_rack_stands_on_the_enrolment_slot(tmp_path, capsys):
    """A third aisle's rack E covers the canonical spot: its demo gallery would enrol the
    pallets in an open hall (22 of 216 places right on a seed of such a site); btrun
    validate and the gallery build say so and what to set. With the world's own slot,
    clear of the racks, nothing is said (216 of 216 on the same seed)."""
    from bt_engine.cli import main

    with open(f"{REPO}/worlds/site.yaml", encoding="utf-8") as f:
        site = yaml.safe_load(f)
    third = dict(copy.deepcopy(site["racks"][2]), name="E", origin_m=[10.0, -8.4])
    more = {
        "racks": [*site["racks"], third],
        "floor": dict(site["floor"], size_m=[17.0, 23.0]),
        "stock": dict(site["stock"], empty_places=46),  # 180 places, a pool of 140
    }
    covered = _site(tmp_path, "covered.yaml", **more)
    slot = {"x_m": 14.3, "y_m": 0.0, "facing_deg": 180}
    own = _site(tmp_path, "own.yaml", enrolment_slot=slot, **more)
    assert main(["validate", covered, own]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "enrolment slot (9.30, 0.00) stands on rack E" in out[0]
    assert "set enrolment_slot to a free spot" in out[0]
    assert out[1].endswith("own.yaml: ok (world)")
