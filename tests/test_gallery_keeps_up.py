"""The gallery keeps up with pallets that age, with the shipped models on rendered scans:
confident scans of a side that ages over 10 scans (confirmed by the embedding or by the
blocks' texture) are added as views, with their crops, and keep every side identified at
every scan, never as another pallet; without updates the heavily aged last scans are lost;
a look-alike pallet is never absorbed."""

from __future__ import annotations

import numpy as np
import pytest

from perception.detector import BlockDetector
from perception.embedder import BlockEmbedder
from perception.robustness import Pipeline, ageing_sequence, similar_never_absorbed
from perception.synth.ageing import progressive
from perception.synth.appearance import SideStyle, block_texture


@pytest.fixture(scope="module")
def pipe() -> Pipeline:
    return Pipeline(BlockDetector.load(threads=1), BlockEmbedder.load(threads=1))


def test_progressive_ageing_keeps_what_it_had():
    """Each step adds to the last: stains grow where they were (no jumping about)."""
    darker = []
    for k in range(1, 11):
        tex = block_texture("ag1", "A", 0, None).astype(float)
        aged = block_texture("ag1", "A", 0, SideStyle(ageing=progressive(k, 10, 5))).astype(float)
        darker.append(np.abs(aged - tex).max(axis=2) > 40)
    for a, b in zip(darker, darker[1:], strict=False):
        assert (a & ~b).mean() < 0.02  # what changed at step k is still changed at k + 1
    assert darker[-1].mean() > darker[0].mean() + 0.1


@pytest.mark.slow
def test_gallery_updates_keep_an_ageing_pallet_identified_at_every_scan(pipe):
    with_updates = ageing_sequence(pipe, sides=4, steps=10, update=True, seed=1)
    without = ageing_sequence(pipe, sides=4, steps=10, update=False, seed=1)
    right = [s["right"] for s in with_updates["steps"]]
    right_without = [s["right"] for s in without["steps"]]
    assert right == [4] * 10  # every side at every scan (issue 17's bar)
    assert sum(right_without) < sum(right)  # the last scans need the added views
    assert with_updates["views_added"] >= 10
    assert all(s["wrong"] == 0 for s in with_updates["steps"] + without["steps"])


@pytest.mark.slow
def test_a_look_alike_pallet_is_never_absorbed(pipe):
    res = similar_never_absorbed(pipe, sides=4, scans=5, seed=2)
    assert res["scans"] == 20
    assert res["named_enrolled"] == 0 and res["views_added"] == 0
