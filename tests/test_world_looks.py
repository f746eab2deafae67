"""Worlds ask for pallet looks: wood tone, paint and ageing per side or for every side
(``pallet_look``), validated with located errors, through the renderer into the frames."""

from __future__ import annotations

import os

import numpy as np
import pytest

from drivers.rig.loader import REPO_ROOT, ConfigError, load_rig
from drivers.sim import world as world_mod
from drivers.sim.renderers.pallet import scene_from_world
from drivers.sim.world import load_world
from nodes.gallery.demo import appearance_key
from nodes.gallery.enrol_scan import canonical_world_data
from perception.synth import looks
from perception.synth.appearance import styles_from_world

WORLD = os.path.join(REPO_ROOT, "worlds", "warehouse.yaml")
WEATHERED = os.path.join(REPO_ROOT, "worlds", "warehouse_weathered.yaml")


def test_world_choices_are_the_generator_names():
    assert set(world_mod.WOODS) == {"auto", *looks.WOOD_TONES}
    assert set(world_mod.PAINTS) == {"auto", "none", *looks.PAINTS}


def test_a_bad_look_is_located(tmp_path):
    text = (
        open(WORLD)
        .read()
        .replace(
            "A: {stamp: EPAL, wear: 0.2, texture_seed: 11}",
            "A: {stamp: EPAL, wear: 0.2, texture_seed: 11, wood: purple, age: 1.5}",
        )
    )
    path = tmp_path / "w.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_world(str(path))
    line = next(i for i, s in enumerate(text.splitlines()) if "purple" in s) + 1
    problems = [str(p) for p in exc.value.problems]
    assert any(
        p.startswith(f"{path}:{line}:") and "'purple' is not one of" in p and "grey" in p
        for p in problems
    )
    assert any("age: 1.5 is above the maximum 1.0" in p for p in problems)
    with pytest.raises(ConfigError, match="world.pallet_look.paint.*'pink' is not one of"):
        load_rig(None, {"world.pallet_look.paint": "pink"}).load_world()


def test_side_keys_win_over_pallet_look_and_reach_the_style():
    data = load_world(WORLD, {"pallet_look.wood": "grey", "pallet_look.age": "0.5"}).data
    styles = styles_from_world(data)
    assert styles["1A"].wood == "grey" and styles["1A"].ageing.stains == pytest.approx(0.05)
    assert styles["1A"].ageing.seed != styles["1B"].ageing.seed
    weathered = load_world(WEATHERED).data
    styles = styles_from_world(weathered)
    assert {s.wood for s in styles.values()} <= {"grey", "silver", "dark", "wet", None}
    assert any(s.paint == "blue" for s in styles.values())


def block_saturation(world) -> float:
    """Mean saturation of the scan pallet's middle block texture as the renderer draws it."""
    scene = scene_from_world(world)
    quad = next(q for q in scene.objects if q.blocks and q.blocks[0][1] == "3A")
    tex = quad.levels[0]
    h, w = tex.shape[:2]
    block = tex[int(h * 0.35) : int(h * 0.8), int(w * 0.45) : int(w * 0.55)]
    return looks.bgr_to_hsv(tuple(float(v) for v in block.reshape(-1, 3).mean(0)))[1]


def test_pallet_look_flows_into_the_rendered_scene():
    fresh = block_saturation(load_rig(None).load_world())
    grey = block_saturation(load_rig(None, {"world.pallet_look.wood": "grey"}).load_world())
    assert fresh > 0.3 and grey < 0.15


def test_demo_gallery_enrols_the_look_but_not_the_ageing():
    data = load_world(WORLD).data
    aged = load_world(WORLD, {"pallet_look.age": "0.8"}).data
    grey = load_world(WORLD, {"pallet_look.wood": "grey"}).data
    assert appearance_key(aged) == appearance_key(data) != appearance_key(grey)
    canon = canonical_world_data(aged, "2B")
    assert canon["pallet_look"]["age"] == 0.0
    assert all(s["age"] == 0.0 for p in canon["pallets"] for s in p["sides"].values())
    assert np.isclose(aged["pallet_look"]["age"], 0.8)
