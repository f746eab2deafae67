"""Training-data helpers of the synthetic camera."""

from __future__ import annotations

import numpy as np

from perception.synth.dataset import block_crops, crop_to, identity_names, render_detection_sample


def test_identity_names():
    assert identity_names(5) == ["p0001A", "p0001B", "p0002A", "p0002B", "p0003A"]
    names = identity_names(600)
    assert len(set(names)) == 600 and names[-1] == "p0300B"


def test_detection_samples_are_frames_with_boxes_inside_the_image():
    rng = np.random.default_rng(0)
    n_boxes = 0
    for _ in range(6):
        raw, boxes = render_detection_sample(rng, identities=["p0001A", "p0002B"])
        assert raw.shape == (244, 324) and raw.dtype == np.uint8
        for b in boxes:
            assert 0 <= b.x1 < b.x2 <= 324 and 0 <= b.y1 < b.y2 <= 244
            assert 0 < b.visible <= 1 and b.block in (0, 1, 2)
            assert b.identity in ("p0001A", "p0002B")
        n_boxes += len(boxes)
    assert n_boxes >= 4


def test_detection_samples_are_deterministic():
    a = render_detection_sample(np.random.default_rng(4), identities=["p0003A"])
    b = render_detection_sample(np.random.default_rng(4), identities=["p0003A"])
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]


def test_aimed_samples_centre_one_block_at_every_distance_and_yaw():
    """``aim_probability`` 1: every frame is aimed at a block as the scan's views are (its
    box centred within a few pixels, end blocks included, out to 1.3 m and 30 deg); 0: the
    random stream is untouched, so older training configurations render the same frames."""
    rng = np.random.default_rng(7)
    aimed_blocks = set()
    for _ in range(12):
        _, boxes = render_detection_sample(
            rng, ["p0001A"], aim_probability=1.0, distance_m=(0.9, 1.3), yaw_deg=30.0
        )
        centred = [b for b in boxes if abs((b.x1 + b.x2) / 2 - 162) <= 12]
        assert len(centred) == 1, boxes
        aimed_blocks.add(centred[0].block)
    assert aimed_blocks == {0, 1, 2}
    a = render_detection_sample(np.random.default_rng(4), identities=["p0003A"])
    b = render_detection_sample(np.random.default_rng(4), ["p0003A"], aim_probability=0.0)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]


def test_block_crops():
    crops = block_crops("p0001A", None, 2, np.random.default_rng(1), 5)
    assert len(crops) == 5
    for c in crops:
        assert c.ndim == 3 and c.shape[2] == 3 and c.dtype == np.uint8
        assert c.shape[1] >= 8 and c.shape[1] > c.shape[0]  # blocks are wider than high
    same = block_crops("p0001", "A", 2, np.random.default_rng(1), 5)
    assert all(np.array_equal(x, y) for x, y in zip(crops, same, strict=True))
    assert crop_to(crops[0]).shape == (384, 128, 3)


def test_crops_of_one_block_resemble_each_other_more_than_other_blocks():
    """Mean colour-normalised appearance: crops of one block vs crops of another identity."""

    def signature(c: np.ndarray) -> np.ndarray:
        g = crop_to(c, (16, 32)).astype(np.float32).mean(axis=2)
        g -= g.mean()
        return g / (g.std() + 1e-6)

    rng = np.random.default_rng(2)
    a = [
        signature(c)
        for c in block_crops("p0010A", None, 0, rng, 6, occlusion_probability=0, blur_probability=0)
    ]
    b = [
        signature(c)
        for c in block_crops("p0011B", None, 0, rng, 6, occlusion_probability=0, blur_probability=0)
    ]
    within = np.mean([np.mean(x * y) for i, x in enumerate(a) for y in a[i + 1 :]])
    across = np.mean([np.mean(x * y) for x in a for y in b])
    assert within > across
