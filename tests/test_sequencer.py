"""The block sequencer, frame by frame: order, tracking, best crop, the reference's pitfalls."""

from __future__ import annotations

import numpy as np

from perception.sequencer import BlockSequencer, Detection, SequencerParams, sharpness

W, H = 324, 244


def frame(
    blocks: dict[int, float], sharp: dict[int, bool] | None = None, width: int = 60
) -> tuple[np.ndarray, list[Detection]]:
    """An image with block ``k`` drawn at centre x, filled with value 40*k (+ texture if sharp)."""
    img = np.full((H, W, 3), 10, np.uint8)
    dets = []
    rng = np.random.default_rng(0)
    for k, cx in blocks.items():
        x1, x2 = int(cx - width / 2), int(cx + width / 2)
        x1c, x2c = max(x1, 0), min(x2, W)
        if x2c <= x1c:
            continue
        patch = np.full((80, x2c - x1c, 3), 40 * k, np.uint8)
        if (sharp or {}).get(k, True):
            patch = patch + rng.integers(0, 30, patch.shape, dtype=np.uint8)
        img[80:160, x1c:x2c] = patch
        dets.append(Detection(x1c, 80, x2c, 160, 0.9))
    return img, dets


def block_value(crop: np.ndarray) -> int:
    return int(round(float(np.median(crop)) / 40.0))


def sweep(seq, speed=8.0, spacing=150.0, n=3, start=-40.0, sharp_at=None):
    """Blocks 1..n spaced ``spacing`` px apart, moving right ``speed`` px per frame."""
    x0 = start
    for _ in range(400):
        pos = {k: x0 - (k - 1) * spacing for k in range(1, n + 1)}
        visible = {k: x for k, x in pos.items() if -30 < x < W + 30}
        sharp = sharp_at(pos) if sharp_at else None
        img, dets = frame(visible, sharp)
        seq.update(img, dets)
        if seq.done:
            break
        x0 += speed
    return seq


def test_three_blocks_committed_in_order_with_their_own_crops():
    seq = sweep(BlockSequencer())
    assert seq.done and [b.index for b in seq.blocks] == [1, 2, 3]
    assert [block_value(b.crop) for b in seq.blocks] == [1, 2, 3]


def test_two_blocks_in_view_are_not_mixed():
    # spacing 100 px: the next block is in view while the previous crosses the centre
    seq = sweep(BlockSequencer(), spacing=100.0)
    assert [block_value(b.crop) for b in seq.blocks] == [1, 2, 3]


def test_commit_happens_only_after_crossing_right_threshold():
    p = SequencerParams(max_distance_left_px=60, min_distance_right_px=20)
    seq = BlockSequencer(p)
    for cx in (100, 130, 150, 162, 170, 180):  # centre is 162
        img, dets = frame({1: cx})
        seq.update(img, dets)
    assert seq.blocks == []
    img, dets = frame({1: 190})  # 28 px right of centre
    assert len(seq.update(img, dets)) == 1


def test_best_crop_of_the_pass_wins_over_a_blurred_later_one():
    # inside the left window: sharp first, then blurred frames; the sharp crop is committed
    def sharp_at(pos):
        return {k: not (100 < x < 162) or x < 120 for k, x in pos.items()}

    seq = sweep(BlockSequencer(), sharp_at=sharp_at)
    for b in seq.blocks:
        assert sharpness(b.crop) > 10.0


def test_partial_block_at_the_border_is_not_preferred():
    seq = BlockSequencer(SequencerParams(max_distance_left_px=200))
    img, dets = frame({1: 20})  # cut by the left border
    seq.update(img, dets)
    img, dets = frame({1: 120})
    seq.update(img, dets)
    img, dets = frame({1: 200})
    (b,) = seq.update(img, dets)
    assert b.box.x1 > 2  # the complete view was committed


def test_alternating_detections_do_not_commit_a_stale_crop_twice():
    """The reference kept one crop variable: seen left, then right, then left far away, then
    right again -> it committed block 1's crop twice. Tracks prevent that."""
    seq = BlockSequencer()
    for cx in (110, 130, 150):
        seq.update(*frame({1: cx}))
    seq.update(*frame({1: 200}))  # block 1 committed
    seq.update(*frame({2: 20}))  # block 2 appears far left (outside the window)
    seq.update(*frame({1: 206}))  # block 1 detected again on the right
    seq.update(*frame({1: 212, 2: 40}))
    assert len(seq.blocks) == 1


def test_stops_after_three_and_reset():
    seq = sweep(BlockSequencer(), n=5)
    assert len(seq.blocks) == 3
    img, dets = frame({4: 200})
    assert seq.update(img, dets) == []
    seq.reset()
    assert seq.blocks == [] and not seq.done
