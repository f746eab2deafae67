"""PCB embedder: shapes, part features, torchreid-compatible checkpoints, clear mismatch errors."""

from __future__ import annotations

import pytest
import torch

from perception.pcb import PCB, CheckpointError, PCBConfig, load_checkpoint


def test_eval_features_are_normalised_per_part_and_concatenated():
    m = PCB(PCBConfig(backbone="small", parts=4, num_classes=5)).eval()
    with torch.inference_mode():
        f = m(torch.randn(2, 3, 96, 160))
    assert f.shape == (2, m.embedding_dim) == (2, 4 * 256)
    parts = f.view(2, 256, 4)  # channel-major, like torchreid's view of (N, C, parts, 1)
    assert torch.allclose(parts.norm(dim=1), torch.ones(2, 4), atol=1e-5)


def test_training_returns_one_logit_set_per_part():
    m = PCB(PCBConfig(backbone="small", parts=6, num_classes=7)).train()
    out = m(torch.randn(2, 3, 96, 160))
    assert len(out) == 6 and out[0].shape == (2, 7)


def test_last_stage_keeps_stride_one():
    m = PCB(PCBConfig(backbone="small"))
    fm = m.featuremaps(torch.randn(1, 3, 96, 160))
    assert fm.shape[-2:] == (96 // 16, 160 // 16)  # stride 16, not 32


def test_torchreid_style_checkpoint_loads(tmp_path):
    """torchreid saves {'state_dict': ...} with 'module.' prefixes and its own classifier size."""
    src = PCB(PCBConfig(backbone="resnet50", num_classes=751))
    path = tmp_path / "pcb_p4.pth.tar"
    torch.save(
        {"state_dict": {"module." + k: v for k, v in src.state_dict().items()}, "epoch": 60}, path
    )
    dst = PCB(PCBConfig(backbone="resnet50", num_classes=10))
    load_checkpoint(dst, str(path))
    assert torch.equal(dst.layer4[2].conv3.weight, src.layer4[2].conv3.weight)


def test_mismatched_checkpoint_lists_the_keys(tmp_path):
    src = PCB(PCBConfig(backbone="resnet18"))
    path = tmp_path / "r18.pt"
    torch.save(src.state_dict(), path)
    with pytest.raises(CheckpointError) as e:
        load_checkpoint(PCB(PCBConfig(backbone="resnet50")), str(path))
    msg = str(e.value)
    assert (
        "does not fit PCB backbone 'resnet50'" in msg
        and "missing keys: " in msg
        and "layer1.0.conv3.weight" in msg
    )
    bad = tmp_path / "junk.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot read"):
        load_checkpoint(PCB(PCBConfig()), str(bad))
