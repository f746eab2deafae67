"""The faster texture synthesis (issue 28: a 4,000-side demo gallery in under 10 minutes)
gives the same pixels, bit for bit, as the code it replaced (kept in
``bench/relief_reference.py``, which ``bench/gallery_build_speed.py`` times it against)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import bench_module

from perception.synth import appearance as ap
from perception.synth import relief, woodgen
from perception.synth.ageing import Ageing
from perception.synth.appearance import EPAL, PalletGeometry, SideStyle
from perception.synth.scene import PalletSpec, Scene, SceneLight, _rect, box_quads

AISLE = SceneLight(0.6, tuple(((1.5, y, 4.0), 1.0) for y in (3.5, 0.0, -3.5)), 4000.0)
LEFT = SceneLight(0.5, (((-1.2, 2.5, 2.5), 1.0), ((-1.0, -1.0, 1.0), 0.7)), 4000.0)
DARK = SceneLight(0.6, (), 4000.0)
CORNERS = _rect(np.array([9.3, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]), EPAL.length_m, 0.338, 0.194)

#: sides over the generator's branches: plain wood, a chipboard pallet (c0), the other
#: block-face generators, faint grain, paint, markings, ageing, another geometry
SIDES = [
    ("101", "A", SideStyle("EPAL", 0.31, 1011)),
    ("102", "B", SideStyle("EUR", 0.79, 1022)),
    ("7", "A", None),
    ("c0", "B", SideStyle(texture_seed=3)),
    ("g1", "A", SideStyle(generator="flake", marking="label")),
    ("g2", "B", SideStyle(generator="plank", marking="ink", wood="grey")),
    ("g3", "A", SideStyle(generator="noise", marking="stencil", paint="blue")),
    ("g4", "A", SideStyle(generator="pattern", marking="burnt", grain=0.2)),
    ("p5", "B", SideStyle(paint="red", paint_parts="blocks", ageing=Ageing.gradual(0.8, 3))),
    ("w6", "A", SideStyle(wood="wet", saturation=1.4, marking="none", wear=0.9)),
]


@pytest.fixture(scope="module")
def reference():
    with bench_module("relief_reference") as module:
        yield module


@pytest.mark.parametrize("pallet_id,side,style", SIDES)
def test_textures_are_the_same_as_before(reference, pallet_id, side, style) -> None:
    def made() -> list[np.ndarray]:
        out = [
            ap.face_texture(pallet_id, side, style),
            ap.short_face_texture(pallet_id, "L", style),
            ap.top_texture(pallet_id, style),
            relief.face_height(pallet_id, side, style),
            relief.face_normals(pallet_id, side, style),
        ]
        out += [relief.lit_face(pallet_id, side, style, EPAL, CORNERS, li) for li in (AISLE, LEFT)]
        return out

    new = made()
    with reference.reference():
        old = made()
    for a, b in zip(new, old, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a, b)


def test_faces_in_a_row_at_one_place_are_shaded_as_before(reference) -> None:
    # the lamp fields are kept once a second face in a row has the same corners and light
    # (a demo gallery build), and worked out afresh when they change
    def made() -> list[np.ndarray]:
        return [
            relief.lit_face(pallet_id, side, style, EPAL, CORNERS, light)
            for light in (AISLE, AISLE, LEFT, AISLE)
            for pallet_id, side, style in SIDES[:3]
        ]

    new = made()
    assert relief._LAST_FIELDS[1] is not None
    with reference.reference():
        old = made()
    assert all(np.array_equal(a, b) for a, b in zip(new, old, strict=True))


def test_another_geometry_and_no_lamps(reference) -> None:
    g = PalletGeometry(length_m=1.0, width_m=1.2, height_m=0.15, block_height_m=0.09)
    corners = _rect(np.zeros(3), np.array([0.0, 1.0, 0.0]), g.length_m, 0.4, 0.25)

    def made() -> list[np.ndarray]:
        return [relief.lit_face("x1", "A", None, g, corners, li) for li in (AISLE, DARK)]

    new = made()
    with reference.reference():
        old = made()
    assert all(np.array_equal(a, b) for a, b in zip(new, old, strict=True))


def test_woodgen_is_the_same_as_before(reference) -> None:
    for seed in range(40):
        h, w = ((44, 2400), (156, 290), (11, 400), (3, 5))[seed % 4]
        knots = [(-4.0, 1.0, 3.0, 2.5), (w * 0.5, h * 0.3, 9.0, 6.5), (w + 3.0, h, 4.0, 3.0)]
        kw = dict(period_px=6.0 + seed % 9, slope=0.04 * math.sin(seed), warp_px=3.0 + seed % 5)
        for impl in (woodgen, reference):
            rng = np.random.default_rng(seed)
            grain = impl.wood_grain(rng, h, w, knots=knots[: seed % 4], **kw)
            end = impl.end_grain(rng, h, w, period_px=5.0 + seed % 7)
            chips = impl.chipboard(rng, h, w)
            if impl is woodgen:
                new, new_state = (grain, end, chips), rng.random()
            else:
                assert new_state == rng.random()  # the same draws from the generator
                for a, b in zip(new, (grain, end, chips), strict=True):
                    assert a.dtype == b.dtype and np.array_equal(a, b)


def test_colourise_and_blend_are_the_same_as_before(reference) -> None:
    rng = np.random.default_rng(5)
    lum = rng.random((30, 40), dtype=np.float32) * 1.3
    base = np.array([118.0, 168.0, 206.0], np.float32)
    for b in (base, base.astype(np.float64)):
        a, r = woodgen.colourise(lum, b, 0.4 * b), reference.colourise(lum, b, 0.4 * b)
        assert a.dtype == r.dtype and np.array_equal(a, r)
    img = rng.random((30, 40, 3), dtype=np.float32) * 255
    for alpha, where in (
        (rng.random((30, 40), dtype=np.float32), np.s_[:, :]),
        (rng.random((10, 12), dtype=np.float32), np.s_[5:15, 20:32]),  # a view, as marks do
        (rng.random((30, 40)), np.s_[:, :]),  # float64 alpha: the general path
        (np.zeros((30, 40), np.float32), np.s_[:, :]),
    ):
        a, r = img.copy(), img.copy()
        woodgen.blend(a[where], alpha, (52, 60.5, 68))
        reference.blend(r[where], alpha, (52, 60.5, 68))
        assert np.array_equal(a, r)


def test_half_floats_round_as_numpy_does() -> None:
    x = np.random.default_rng(0).standard_normal((50, 70)).astype(np.float32)
    x[0, :6] = (0.0, -0.0, 1.0, 65504.0, 6e-8, 1e-9)
    assert np.array_equal(relief._half(x).view(np.uint16), x.astype(np.float16).view(np.uint16))
    h = x.astype(np.float16)
    assert np.array_equal(relief._single(h), h.astype(np.float32))
    assert np.array_equal(relief._single(np.dstack([h, h])[..., 1]), h.astype(np.float32))


def test_scenes_share_their_boxes_and_render_as_before(reference) -> None:
    box = ((1.0, 2.0, 0.5), (0.1, 0.4, 0.5), 0.3, "steel_blue")
    one = Scene.build([], boxes=[box], light=AISLE)
    two = Scene.build([], boxes=[box], light=AISLE)
    assert [id(q) for q in one.objects] == [id(q) for q in two.objects]
    assert box_quads(*box[:3], SceneLight(0.6, [((1.0, 0.0, 4.0), 1.0)]), box[3])  # unhashable
    pallet = PalletSpec("101", "A", 9.3, 0.0, 0.194, math.pi, EPAL, (("A", SIDES[0][2]),))
    new = Scene.build([pallet], boxes=[box], light=AISLE)
    with reference.reference():
        old = Scene.build([pallet], boxes=[box], light=AISLE)
        old_levels = [lv for q in old.quads for lv in q.levels]
    new_levels = [lv for q in new.quads for lv in q.levels]
    assert all(np.array_equal(a, b) for a, b in zip(new_levels, old_levels, strict=True))
    assert len(new_levels) == len(old_levels)


def test_enrolment_frames_are_chosen_as_before() -> None:
    from drivers.sim.world import load_world
    from nodes.gallery import enrol_scan

    data = load_world("worlds/warehouse.yaml").data
    enrol_scan._OFFSETS.clear()
    cached = [
        list(enrol_scan.enrolment_frames(data, "worlds/warehouse.yaml", i, None))
        for i in ("1A", "2B")
    ]
    enrol_scan.CACHE_OFFSETS = False
    try:
        fresh = [
            list(enrol_scan.enrolment_frames(data, "worlds/warehouse.yaml", i, None))
            for i in ("1A", "2B")
        ]
    finally:
        enrol_scan.CACHE_OFFSETS = True
    assert len(enrol_scan._OFFSETS) == 1  # every side of the world: one scan geometry
    for a, b in zip(cached, fresh, strict=True):
        assert [t for _, t in a] == [t for _, t in b]
        assert all(
            (x is None) == (y is None) and (x is None or np.array_equal(x, y))
            for (x, _), (y, _) in zip(a, b, strict=True)
        )
