"""The range of pallet looks and what ageing does: wood tones, paints, face generators,
markings, stains, dust, occluders, moisture, the AI-deck's Bayer JPEG path."""

from __future__ import annotations

import numpy as np
import pytest

from perception.synth import appearance as ap
from perception.synth import looks
from perception.synth.ageing import OCCLUDERS, Ageing, age_image, random_ageing
from perception.synth.views import (
    ViewConditions,
    bayer_jpeg,
    mosaic,
    random_conditions,
    resensor_crop,
)


def mean_hsv(img: np.ndarray) -> tuple[float, float, float]:
    return looks.bgr_to_hsv(tuple(float(v) for v in img.reshape(-1, 3).mean(0)))


def test_wood_tones_span_fresh_to_grey_and_wet():
    hsv = {
        t: mean_hsv(ap.block_texture("w1", "A", 0, ap.SideStyle(wood=t))) for t in looks.WOOD_TONES
    }
    assert hsv["grey"][1] < 0.15 and hsv["silver"][1] < 0.12  # weathered: nearly no colour
    assert hsv["fresh"][1] > 0.3 and hsv["yellowed"][1] > hsv["grey"][1] + 0.25
    assert hsv["wet"][2] < hsv["fresh"][2] - 0.2 and hsv["dark"][2] < 0.4
    assert hsv["pale"][2] > hsv["brown"][2] + 0.2
    sat = mean_hsv(ap.block_texture("w1", "A", 0, ap.SideStyle(saturation=0.2)))[1]
    assert sat < 0.35 * mean_hsv(ap.block_texture("w1", "A", 0))[1]


@pytest.mark.parametrize("paint", ["blue", "red", "green"])
def test_paint_covers_blocks_and_optionally_boards(paint):
    bgr = np.asarray(looks.PAINTS[paint])
    block = ap.block_texture("w2", "A", 1, ap.SideStyle(paint=paint)).reshape(-1, 3).mean(0)
    assert int(np.argmax(block)) == int(np.argmax(bgr))  # the paint's channel dominates
    only = ap.SideStyle(paint=paint, paint_parts="blocks")
    face_all = ap.face_texture("w2", "A", ap.SideStyle(paint=paint))
    face_blocks = ap.face_texture("w2", "A", only)
    board_all, board_blocks = (
        face_all[:30].reshape(-1, 3).mean(0),
        face_blocks[:30].reshape(-1, 3).mean(0),
    )
    assert int(np.argmax(board_all)) == int(np.argmax(bgr))
    assert np.abs(board_blocks - ap.face_texture("w2", "A")[:30].reshape(-1, 3).mean(0)).max() < 3


def test_random_looks_cover_the_range_and_never_the_held_out_generator():
    rng = np.random.default_rng(0)
    draws = [looks.random_look(rng) for _ in range(400)]
    sat = np.array([d["wood_hsv"][1] for d in draws])
    val = np.array([d["wood_hsv"][2] for d in draws])
    assert sat.min() < 0.05 and sat.max() > 0.6 and val.min() < 0.4 and val.max() > 0.85
    painted = [d for d in draws if "paint" in d]
    assert 0.15 < len(painted) / len(draws) < 0.35
    assert {d["paint_parts"] for d in painted} == {"all", "blocks"}
    gens = {d["generator"] for d in draws}
    assert gens == set(looks.TRAINING_GENERATORS) and "plank" not in gens
    assert {d["marking"] for d in draws} == set(looks.MARKINGS)


def test_generators_and_markings_draw_different_faces():
    faces = {
        g: ap.block_texture("w3", "B", 2, ap.SideStyle(generator=g)).astype(int)
        for g in looks.FACE_GENERATORS
    }
    for a in faces:
        for b in faces:
            if a < b:
                assert np.abs(faces[a] - faces[b]).mean() > 8, (a, b)
    marked = {
        m: ap.block_texture("w3", "B", 1, ap.SideStyle(marking=m)).astype(int)
        for m in looks.MARKINGS
    }
    assert np.abs(marked["label"] - marked["none"]).mean() > 5
    with pytest.raises(ValueError, match="unknown face generator"):
        ap.SideStyle(generator="photo")
    with pytest.raises(ValueError, match="unknown wood tone"):
        ap.SideStyle(wood="purple")


@pytest.mark.parametrize("fraction", [0.07, 0.12, 0.3])
def test_stains_and_dust_cover_the_asked_fraction(fraction):
    for kind in ("stains", "dust"):
        img = np.full((78, 145, 3), 150.0, np.float32)
        hidden = age_image(img, np.random.default_rng(1), Ageing(**{kind: fraction}))
        covered = float((hidden > 0.3).mean())
        assert abs(covered - fraction) < 0.35 * fraction + 0.01, (kind, covered)
        changed = img.mean(axis=2)[hidden > 0.5]
        assert (changed < 130).all() if kind == "stains" else (changed > 150).mean() > 0.8


@pytest.mark.parametrize("occluder", OCCLUDERS)
def test_occluders_hide_the_asked_fraction(occluder):
    img = np.full((64, 112, 3), 128.0, np.float32)
    hidden = age_image(img, np.random.default_rng(2), Ageing(occlusion=0.3, occluder=occluder))
    assert 0.18 < float(hidden.mean()) < 0.42


def test_ageing_is_deterministic_and_leaves_the_rest_of_the_face():
    plain = ap.SideStyle(texture_seed=4)
    aged = ap.SideStyle(texture_seed=4, ageing=Ageing(stains=0.12, seed=3))
    a, b = ap.block_texture("w4", "A", 0, plain), ap.block_texture("w4", "A", 0, aged)
    diff = np.abs(a.astype(int) - b.astype(int)).max(axis=2) > 12
    assert 0.05 < diff.mean() < 0.25  # the stains, not the whole face
    ap.block_texture.cache_clear()
    assert np.array_equal(b, ap.block_texture("w4", "A", 0, aged))
    assert aged.unaged() == plain
    other = ap.block_texture(
        "w4", "A", 0, ap.SideStyle(texture_seed=4, ageing=Ageing(stains=0.12, seed=4))
    )
    assert not np.array_equal(b, other)  # another ageing seed: stains elsewhere


def test_faded_stamps_and_moisture():
    base = ap.block_texture("w5", "A", 1).astype(float)
    faded = ap.block_texture("w5", "A", 1, ap.SideStyle(ageing=Ageing(fade_stamps=1.0))).astype(
        float
    )
    dark_before = (base.mean(axis=2) < 70).mean()
    assert (faded.mean(axis=2) < 70).mean() < dark_before  # the brand's ink is gone
    wet = ap.block_texture("w5", "A", 1, ap.SideStyle(ageing=Ageing(moisture=1.0))).astype(float)
    assert wet[-20:].mean() < base[-20:].mean() - 20  # soaked from the bottom


def test_ageing_values_are_checked_and_gradual_grows():
    with pytest.raises(ValueError, match="stains"):
        Ageing(stains=1.5)
    with pytest.raises(ValueError, match="occluder"):
        Ageing(occluder="tarp")
    weak, strong = Ageing.gradual(0.2), Ageing.gradual(1.0)
    assert weak.stains < strong.stains and weak.dust < strong.dust and not Ageing().changes_texture
    rng = np.random.default_rng(0)
    draws = [random_ageing(rng) for _ in range(200)]
    assert max(d.occlusion for d in draws) > 0.35 and max(d.stains for d in draws) > 0.2


def test_bayer_jpeg_damages_more_at_lower_quality():
    rng = np.random.default_rng(0)
    raw = (np.indices((244, 324)).sum(0) % 2 * 60 + rng.integers(60, 120, (244, 324))).astype(
        np.uint8
    )
    err = {q: np.abs(bayer_jpeg(raw, q).astype(int) - raw).mean() for q in (90, 50, 20, 10)}
    assert err[90] < err[50] < err[20] < err[10]
    crop = rng.integers(0, 255, (30, 57, 3), dtype=np.uint8)
    assert mosaic(crop).shape == (30, 57)
    out = resensor_crop(crop, rng, 10.0, 20)
    assert out.shape == crop.shape and out.dtype == np.uint8


def test_view_conditions_are_checked_and_random_ones_are_broad():
    with pytest.raises(ValueError):
        ViewConditions(jpeg_quality=101)
    with pytest.raises(ValueError):
        ViewConditions(downscale=0.5)
    rng = np.random.default_rng(1)
    cs = [random_conditions(rng) for _ in range(300)]
    assert 0.3 < np.mean([c.jpeg_quality > 0 for c in cs]) < 0.5
    assert max(c.noise_dn for c in cs) > 20 and min(c.colour_temperature_k for c in cs) < 3000
