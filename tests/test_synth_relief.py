"""The long faces' relief (issue 28): lit per pixel by the scene's lamps, cached, optional."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from perception.synth import relief
from perception.synth.appearance import EPAL, SideStyle, block_rect_px, face_texture
from perception.synth.scene import PalletSpec, Scene, SceneLight, _rect

FRONT = SceneLight(0.6, (((-1.5, 0.0, 4.0), 1.0),), 4000.0)
LEFT = SceneLight(0.6, (((-1.2, 2.5, 2.5), 1.0),), 4000.0)
NORMAL = np.array([-1.0, 0.0, 0.0])
CORNERS = _rect(np.zeros(3), NORMAL, EPAL.length_m, 0.338, 0.194)


def _band(img: np.ndarray, block: int = 1) -> np.ndarray:
    x0, y0, x1, y1 = block_rect_px(block)
    g = cv2.cvtColor(np.ascontiguousarray(img[y0:y1, x0:x1]), cv2.COLOR_BGR2GRAY)
    g = g.astype(np.float32)
    return (cv2.GaussianBlur(g, (0, 0), 2.0) - cv2.GaussianBlur(g, (0, 0), 8.0)).ravel()


def test_a_flat_face_is_shaded_as_before() -> None:
    flat = np.zeros((40, 60, 3), np.float16)
    flat[..., 2] = 1.0
    shade = relief.shade_map(flat, CORNERS, FRONT)
    assert shade.shape == (40, 60)
    centre = FRONT.shade(CORNERS.mean(0), NORMAL)
    assert abs(float(shade[20, 30]) - centre) < 0.01  # Lambert + fall-off as SceneLight.shade


def test_normals_are_a_function_of_the_seed_not_of_paint_or_grain() -> None:
    a = relief.face_normals("rl1", "A", SideStyle(texture_seed=5))
    b = relief.face_normals("rl1", "A", SideStyle(texture_seed=5, paint="blue", grain=0.2))
    c = relief.face_normals("rl1", "A", SideStyle(texture_seed=6))
    assert a is b  # one cached map per seed
    assert a.shape == (*face_texture("rl1", "A").shape[:2], 3)
    assert not np.array_equal(a, c)
    assert np.allclose(np.linalg.norm(a.astype(np.float32), axis=-1), 1.0, atol=0.01)


def test_the_same_face_looks_different_under_other_lamps() -> None:
    style = SideStyle(texture_seed=7, grain=0.2)  # faint grain: the relief is most of it
    a = relief.lit_face("rl2", "A", style, EPAL, CORNERS, FRONT)
    b = relief.lit_face("rl2", "A", style, EPAL, CORNERS, LEFT)
    again = relief.lit_face("rl2", "A", style, EPAL, CORNERS, FRONT)
    assert np.array_equal(a, again)  # deterministic
    assert np.corrcoef(_band(a), _band(b))[0, 1] < 0.97
    assert abs(float(a.mean()) - float(b.mean())) < 25  # about as bright overall


def test_faint_grain_lowers_the_colour_contrast_only() -> None:
    full = face_texture("rl3", "A", SideStyle(texture_seed=3, marking="none"))
    faint = face_texture("rl3", "A", SideStyle(texture_seed=3, marking="none", grain=0.2))
    assert _band(faint).std() < _band(full).std()
    with pytest.raises(ValueError):
        SideStyle(grain=3.0)


def test_flat_faces_switch_draws_the_old_scalar_shading(monkeypatch) -> None:
    p = PalletSpec("rl4", "A", 0.0, 0.0, 0.194, math.pi)
    monkeypatch.setattr(relief, "ENABLED", False)
    old = Scene.build([p], floor=None, light=FRONT).quads[0].levels[0]
    monkeypatch.setattr(relief, "ENABLED", True)
    new = Scene.build([p], floor=None, light=FRONT).quads[0].levels[0]
    tex = face_texture("rl4", "A")
    expected = cv2.convertScaleAbs(tex, alpha=FRONT.shade(CORNERS.mean(0), NORMAL))
    assert np.array_equal(old, expected)
    assert new.shape == old.shape and not np.array_equal(new, old)
