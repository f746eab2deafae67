"""Block embedder: shipped weights, held-out identification, thresholds, clear errors, smoke
training, baselines (fast: one small rendered split shared by the tests)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from perception.embedder import DEFAULT_WEIGHTS, BlockEmbedder
from perception.embedder_data import render_crops, split_names
from perception.embedder_eval import baselines, embed_with, mean_block_distances, rank_metrics
from perception.errors import ModelError
from perception.pcb import PCB, PCBConfig
from perception.train_embedder import main


@pytest.fixture(scope="module")
def emb() -> BlockEmbedder:
    return BlockEmbedder.load(threads=1)


@pytest.fixture(scope="module")
def held_out() -> list:
    """10 held-out pallet sides (test split), two independent renders per block."""
    return render_crops(split_names("te", 5), 2, seed=123)


def test_shipped_weights_load_with_thresholds(emb):
    assert emb.model_version.startswith("pcb-small-v1-") and len(emb.model_version) == 21
    assert emb.dim == emb.config.parts * 256
    th = emb.thresholds
    assert 0.0 < th.max_distance < 2.0 and 0.0 <= th.min_margin < 1.0
    assert emb.metrics["validation"]["rank1"] > 0.9


def test_embeddings_are_unit_rows_of_any_crop_size(emb):
    rng = np.random.default_rng(0)
    crops = [rng.integers(0, 255, (h, w, 3), dtype=np.uint8) for h, w in ((20, 37), (90, 160))]
    out = emb.embed(crops)
    assert out.shape == (2, emb.dim) and out.dtype == np.float32
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-5)
    assert emb.embed([]).shape == (0, emb.dim)


def test_held_out_sides_are_identified(emb, held_out):
    g, q = embed_with(emb, held_out, 0), embed_with(emb, held_out, 1)
    dist = mean_block_distances(q, g)
    m = rank_metrics(dist, np.arange(len(held_out)))
    assert m["rank1"] >= 0.9, m
    # per block, too: one block's two renders are closer than that block of the other sides
    for b in range(3):
        d = np.linalg.norm(q[:, b, None, :] - g[None, :, b, :], axis=2)
        assert np.mean(np.argmin(d, axis=1) == np.arange(len(d))) >= 0.7


@pytest.mark.parametrize(
    "crop, words",
    [
        (np.zeros((0, 10, 3), np.uint8), "empty crop"),
        (np.zeros((20, 30), np.uint8), "shape (20, 30)"),
        (np.zeros((20, 30, 3), np.float32), "float32"),
        (np.zeros((20, 30, 4), np.uint8), "(20, 30, 4)"),
    ],
)
def test_bad_crops_are_model_errors(emb, crop, words):
    with pytest.raises(ModelError, match=words.replace("(", r"\(").replace(")", r"\)")):
        emb.embed([np.zeros((20, 30, 3), np.uint8), crop])


def test_missing_and_corrupt_weights_name_the_file(tmp_path):
    missing = str(tmp_path / "nope.pt")
    with pytest.raises(ModelError, match="nope.pt"):
        BlockEmbedder.load(missing)
    bad = tmp_path / "corrupt.pt"
    bad.write_bytes(open(DEFAULT_WEIGHTS, "rb").read()[:5000])
    with pytest.raises(ModelError, match="corrupt.pt: corrupt or unreadable"):
        BlockEmbedder.load(str(bad))


def test_other_backbone_lists_the_keys(tmp_path):
    path = tmp_path / "r18.pt"
    torch.save({"state_dict": PCB(PCBConfig(backbone="resnet18")).state_dict()}, path)
    with pytest.raises(ModelError) as e:
        BlockEmbedder.load(str(path), backbone="resnet50")
    assert "r18.pt" in str(e.value) and "missing keys: " in str(e.value)
    blob = torch.load(DEFAULT_WEIGHTS, weights_only=True)  # ours, with a wrong-shaped tensor
    blob["state_dict"]["conv1.weight"] = torch.zeros(8, 3, 7, 7)
    torch.save(blob, tmp_path / "shape.pt")
    with pytest.raises(ModelError, match=r"shape mismatch: conv1.weight \(8, 3, 7, 7\)"):
        BlockEmbedder.load(str(tmp_path / "shape.pt"))
    with pytest.raises(ModelError, match="pass backbone="):
        BlockEmbedder.load(str(path))


def test_torchreid_pcb_p4_checkpoint_loads(tmp_path):
    src = PCB(PCBConfig(backbone="resnet50", num_classes=751))
    path = tmp_path / "pcb_p4.pth.tar"
    torch.save({"state_dict": {"module." + k: v for k, v in src.state_dict().items()}}, path)
    emb = BlockEmbedder.load(str(path), backbone="resnet50")
    assert emb.dim == 4 * 2048 and emb.model_version.startswith("pcb-resnet50-ext-")
    assert emb.thresholds.max_distance == float("inf")


@pytest.mark.slow
def test_smoke_training_gives_a_loadable_checkpoint(tmp_path):
    out = str(tmp_path / "smoke.pt")
    assert main(["train", "--smoke", "--out", out, "--quiet"]) == 0
    emb = BlockEmbedder.load(out)
    assert emb.embed([np.full((30, 50, 3), 120, np.uint8)]).shape == (1, emb.dim)
    blob = torch.load(out, weights_only=True)
    assert blob["format"] == "btrun-pcb" and blob["training"]["seed"] == 0
    assert set(blob["thresholds"]) == {"max_distance", "min_margin"}


def test_baselines_run_on_a_tiny_split(held_out):
    out = baselines(held_out, held_out, 0, 1)
    for name in ("raw_pixels", "hsv_histogram"):
        assert 0.0 <= out[name]["rank1"] <= out[name]["rank5"] <= 1.0
        assert out[name]["queries"] == len(held_out)
