"""Procedural pallet appearance: deterministic per identity, subtly different between them."""

from __future__ import annotations

import numpy as np
import pytest

from perception.synth import appearance as ap


def test_same_identity_side_block_gives_identical_pixels():
    a = ap.block_texture("3", "A", 1).copy()
    ap.block_texture.cache_clear()
    ap._look.cache_clear()
    b = ap.block_texture("3", "A", 1)
    assert a.shape == (156, 290, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert ap.part_seed("3", "A", 1) == ap.part_seed("3", "A", 1) != ap.part_seed("3", "B", 1)


def test_textures_are_cached_and_read_only():
    t = ap.face_texture("2", "B")
    assert ap.face_texture("2", "B") is t
    assert t.shape == (288, 2400, 3) and not t.flags.writeable


def test_identities_differ_in_texture_not_in_colour():
    """20 identities, block 0. Statistic: per-channel std of the identities' mean colours is
    below 8 % of the mean colour, while the median pairwise mean absolute difference of the
    zero-mean luminance (grain, knots, stamps, nails, dirt) is larger than the median pairwise
    mean-colour difference."""
    means, lums = [], []
    for i in range(1, 21):
        tex = ap.block_texture(f"p{i:04d}", "A", 0).astype(np.float32)
        means.append(tex.reshape(-1, 3).mean(axis=0))
        lum = tex.mean(axis=2)
        lums.append(lum - lum.mean())
    means = np.array(means)
    assert (means.std(axis=0) / means.mean(axis=0) < 0.08).all()
    pairs = [(i, j) for i in range(20) for j in range(i + 1, 20)]
    texture = np.median([np.abs(lums[i] - lums[j]).mean() for i, j in pairs])
    colour = np.median([np.abs(means[i] - means[j]).max() for i, j in pairs])
    assert texture > 10.0
    assert texture > colour


def test_blocks_of_one_side_differ_and_sides_differ():
    b0, b1 = ap.block_texture("1", "A", 0), ap.block_texture("1", "A", 2)
    assert np.abs(b0.astype(int) - b1.astype(int)).mean() > 5
    a, b = ap.block_texture("1", "A", 0), ap.block_texture("1", "B", 0)
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 5


def test_style_changes_the_look_deterministically():
    plain = ap.block_texture("4", "A", 0)
    worn = ap.block_texture("4", "A", 0, ap.SideStyle("EUR", 0.9, 41))
    assert not np.array_equal(plain, worn)
    assert np.array_equal(worn, ap.block_texture("4", "A", 0, ap.SideStyle("EUR", 0.9, 41)))


def test_face_layout_blocks_are_wood_and_gaps_are_dark():
    face = ap.face_texture("5", "A").astype(np.float32).mean(axis=2)
    x0, y0, x1, y1 = ap.block_rect_px(0)
    gap = face[y0:y1, x1 + 20 : x1 + 200]
    assert face[y0:y1, x0:x1].mean() > 2.5 * gap.mean()
    assert [ap.block_rect_px(k)[0] for k in range(3)] == sorted(
        ap.block_rect_px(k)[0] for k in range(3)
    )


def test_split_identity():
    assert ap.split_identity("3A") == ("3", "A")
    assert ap.split_identity("p0001b") == ("p0001", "B")
    assert ap.split_identity("7", "B") == ("7", "B")
    with pytest.raises(ValueError):
        ap.split_identity("7")


def test_styles_from_world_data():
    data = {
        "pallets": [
            {
                "id": "1",
                "sides": {"A": {"stamp": "EUR", "wear": 0.2, "texture_seed": 11}, "B": None},
            }
        ]
    }
    assert ap.styles_from_world(data) == {
        "1A": ap.SideStyle("EUR", 0.2, 11),
        "1B": ap.SideStyle(None, None, 0),
    }
