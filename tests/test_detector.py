"""Block detector: the shipped weights find the blocks of held-out renders; clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from perception.detector import (
    DEFAULT_WEIGHTS,
    FORMAT,
    BlockDetector,
    box_iou,
    nms,
)
from perception.errors import ModelError
from perception.sequencer import Detection
from perception.synth.dataset import _wb_factors, identity_names, render_detection_sample
from perception.synth.render import SensorModel
from perception.train_detector import main as train_main
from perception.white_balance import preprocess


@pytest.fixture(scope="module")
def detector() -> BlockDetector:
    return BlockDetector.load(threads=1)


@pytest.fixture(scope="module")
def frames() -> list[tuple[np.ndarray, list]]:
    """Held-out renders (identities never trained on) with their ground-truth boxes."""
    rng = np.random.default_rng(2024)
    factors = _wb_factors(SensorModel())
    names = identity_names(4, "x")
    out = []
    for i in range(12):
        raw, boxes = render_detection_sample(rng, [names[i // 3]])
        out.append((preprocess(raw, factors), boxes))
    return out


def test_shipped_weights_load(detector):
    assert detector.model_version.startswith("blockdet-v1-")
    assert len(detector.model_version) == len("blockdet-v1-") + 8
    assert detector.path == DEFAULT_WEIGHTS
    n_params = sum(p.numel() for p in detector.model.parameters())
    assert n_params < 300_000


def test_finds_visible_blocks_left_to_right(detector, frames):
    found = total = 0
    ious = []
    for bgr, boxes in frames:
        dets = detector.detect(bgr)
        assert all(isinstance(d, Detection) for d in dets)
        cxs = [d.cx for d in dets]
        assert cxs == sorted(cxs)
        full = [b for b in boxes if b.visible > 0.99 and b.x2 - b.x1 > 8]
        for b in full:
            total += 1
            gt = np.array([[b.x1, b.y1, b.x2, b.y2]])
            best = box_iou(np.array([[d.x1, d.y1, d.x2, d.y2] for d in dets]), gt).max(initial=0.0)
            if best > 0.6:
                found += 1
                ious.append(best)
        if len(full) == len(boxes) and full:
            # every block fully in view -> the detections are exactly those, in order
            gt_sorted = sorted(full, key=lambda b: b.x1 + b.x2)
            assert len(dets) == len(gt_sorted)
            for d, b in zip(dets, gt_sorted, strict=True):
                assert abs(d.cx - 0.5 * (b.x1 + b.x2)) < 0.25 * (b.x2 - b.x1)
    assert total >= 12
    assert found >= total - 1
    assert np.mean(ious) > 0.75


def test_min_score_filters(detector, frames):
    bgr = frames[0][0]
    loose = detector.detect(bgr, min_score=0.05)
    strict = detector.detect(bgr, min_score=0.5)
    assert all(d.score >= 0.5 for d in strict)
    assert all(d.score >= 0.05 for d in loose)
    assert len(loose) >= len(strict)
    assert detector.detect(bgr, min_score=1.01) == []


def test_detect_batch_matches_detect(detector, frames):
    imgs = [f[0] for f in frames[:3]]
    batch = detector.detect_batch(imgs)
    for img, dets in zip(imgs, batch, strict=True):
        single = detector.detect(img)
        assert len(single) == len(dets)
        for a, b in zip(single, dets, strict=True):
            assert abs(a.x1 - b.x1) < 0.5 and abs(a.score - b.score) < 1e-3
    assert detector.detect_batch([]) == []


def test_blank_frame_has_no_blocks(detector):
    assert detector.detect(np.full((244, 324, 3), 128, np.uint8)) == []


def test_nms_keeps_best_of_overlapping():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 0, 30, 10]], np.float32)
    keep = nms(boxes, np.array([0.6, 0.9, 0.5]), 0.45)
    assert keep.tolist() == [1, 2]


@pytest.mark.parametrize(
    "bad, message",
    [
        ("frame.png", "numpy array"),
        (np.zeros((244, 324), np.uint8), "shape"),
        (np.zeros((3, 244, 324), np.uint8), "shape"),
        (np.zeros((240, 320, 3), np.uint8), "shape"),
        (np.zeros((244, 324, 3), np.float32), "uint8"),
    ],
)
def test_bad_input_raises_model_error(detector, bad, message):
    with pytest.raises(ModelError, match=message):
        detector.detect(bad)


def test_missing_weights(tmp_path):
    path = tmp_path / "nope.pt"
    with pytest.raises(ModelError, match="no detector weights") as err:
        BlockDetector.load(str(path))
    assert str(path) in str(err.value)


def test_corrupt_weights(tmp_path):
    path = tmp_path / "random.pt"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, np.uint8).tobytes())
    with pytest.raises(ModelError, match="corrupt or unreadable"):
        BlockDetector.load(str(path))


def test_wrong_format_dict(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"format": "btrun-pcb", "state_dict": {}}, path)
    with pytest.raises(ModelError, match=f"not a {FORMAT} checkpoint"):
        BlockDetector.load(str(path))
    blob = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    torch.save({**blob, "format_version": 99}, path)
    with pytest.raises(ModelError, match="format version 99"):
        BlockDetector.load(str(path))
    state = dict(blob["state_dict"])
    state.pop(next(iter(state)))
    torch.save({**blob, "state_dict": state}, path)
    with pytest.raises(ModelError, match="do not fit"):
        BlockDetector.load(str(path))


@pytest.mark.slow
def test_smoke_training_writes_loadable_checkpoint(tmp_path):
    out = tmp_path / "smoke.pt"
    assert train_main(["train", "--smoke", "--quiet", "--out", str(out), "--seed", "3"]) == 0
    det = BlockDetector.load(str(out))
    assert det.model_version.startswith("blockdet-v1-")
    blob = torch.load(out, map_location="cpu", weights_only=True)
    assert blob["format"] == FORMAT and blob["trained"]["seed"] == 3
    assert "metrics" in blob["trained"]
    assert isinstance(det.detect(np.zeros((244, 324, 3), np.uint8)), list)
    # the operating point is calibrated and stored with the weights
    assert (
        blob["score_threshold"]
        == det.score_threshold
        == blob["trained"]["calibration"]["score_threshold"]
    )
    assert blob["trained"]["metrics"]["min_score"] == det.score_threshold


def test_shipped_detector_carries_its_calibrated_operating_point(detector, frames):
    """detect() without a min_score uses the threshold calibrated for these weights (below
    the old fixed 0.5: far blocks scoring 0.3 - 0.5 were dropped), chosen on validation
    renders by F1 and recorded with its sweep."""
    blob = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    cal = blob["trained"]["calibration"]
    assert detector.score_threshold == blob["score_threshold"] == cal["score_threshold"]
    assert 0.2 <= detector.score_threshold < 0.5
    best = max(cal["grid"], key=lambda r: (r["f1"], r["threshold"]))
    assert best["threshold"] == detector.score_threshold
    for bgr, _ in frames:
        assert detector.detect(bgr) == detector.detect(bgr, min_score=detector.score_threshold)
    assert [len(x) for x in detector.detect_batch([f for f, _ in frames])] == [
        len(detector.detect(f)) for f, _ in frames
    ]


@pytest.mark.parametrize("bad", [1.5, 0.0, "0.3", True, None])
def test_bad_operating_point_is_a_clear_error(tmp_path, bad):
    path = tmp_path / "bad.pt"
    blob = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    torch.save({**blob, "score_threshold": bad}, path)
    with pytest.raises(ModelError, match="score_threshold") as err:
        BlockDetector.load(str(path))
    assert repr(bad) in str(err.value) and str(path) in str(err.value)


@pytest.mark.parametrize("cmd", ["calibrate", "evaluate"])
def test_detector_cli_names_a_bad_weights_file_without_a_traceback(tmp_path, capsys, cmd):
    path = tmp_path / "nope.pt"
    assert train_main([cmd, "--weights", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(path) in err and "Traceback" not in err
    assert not path.exists()


def test_checkpoint_without_operating_point_keeps_the_old_threshold(tmp_path):
    path = tmp_path / "old.pt"
    blob = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    blob.pop("score_threshold")
    torch.save(blob, path)
    assert BlockDetector.load(str(path)).score_threshold == 0.5


def test_operating_point_is_the_best_f1_of_the_grid():
    """pick_threshold: precision against recall on a made-up sweep; ties go to the higher
    threshold (fewer false positives for the same F1)."""
    from perception.detector_eval import pick_threshold

    # 10 true blocks: 8 found at 0.9, 2 only at 0.35; false positives at 0.25 and 0.45
    scores = np.array([0.9] * 8 + [0.35, 0.35, 0.25, 0.45])
    tp = np.array([1] * 10 + [0, 0])
    thr, rows = pick_threshold(scores, tp, 10, grid=(0.2, 0.3, 0.4, 0.5))
    assert thr == 0.3  # 10 TP + 1 FP beats 8 TP + 1 FP (0.4) and 8 TP + 0 FP (0.5)
    assert [r["false_positives"] for r in rows] == [2, 1, 1, 0]
    thr, _ = pick_threshold(np.array([0.9, 0.9]), np.array([1, 1]), 2, grid=(0.2, 0.3))
    assert thr == 0.3


def test_inference_path_equals_the_module_to_float_rounding(detector, frames):
    from perception.detector import decode, to_input

    imgs = [f[0] for f in frames[:4]]
    with torch.inference_mode():
        ref = detector.model(to_input(imgs, detector.config.input_hw))
        fast = detector.forward(detector.input(imgs))
    assert torch.allclose(fast, ref, atol=1e-4)
    boxes, logits = decode(ref, detector.config.stride)
    fast_boxes, _ = detector.raw_boxes(imgs)
    (fh, fw), (ih, iw) = detector.config.frame_hw, detector.config.input_hw
    scale = np.array([fw / iw, fh / ih, fw / iw, fh / ih], np.float32)
    assert np.allclose(fast_boxes, boxes.numpy() * scale, atol=1e-2)


def test_changed_weights_are_folded_again():
    det = BlockDetector.load(threads=1)
    x = torch.zeros(1, 3, *det.config.input_hw)
    with torch.inference_mode():
        before = det.forward(x)
    with torch.no_grad():
        det.model.head.bias[0] += 1.0  # in place, as an optimiser step or load_state_dict
    with torch.inference_mode():
        after = det.forward(x)
        assert torch.allclose(after, det.model(x), atol=1e-4)
    assert torch.allclose(after[:, 0], before[:, 0] + 1.0, atol=1e-4)


def test_dark_paint_repaints_a_share_of_training_pallets():
    """``dark_paint`` repaints that share of the training pallets black or very dark (the
    detector's hardest look) and leaves the others' looks exactly as random_look drew them."""
    from perception.detector_data import varied_style
    from perception.synth.dataset import identity_names
    from perception.synth.looks import bgr_to_hsv

    names = identity_names(400, "t")[::2]  # one side per pallet
    plain = [varied_style(n, 0) for n in names]
    dark = [varied_style(n, 0, dark_paint=0.5) for n in names]

    def is_dark(s) -> bool:
        return (
            s.paint is not None and not isinstance(s.paint, str) and bgr_to_hsv(s.paint)[2] <= 0.3
        )

    changed = [d for p, d in zip(plain, dark, strict=True) if d != p]
    assert 0.4 < len(changed) / len(names) < 0.6
    assert all(is_dark(d) for d in changed)
    assert sum(is_dark(p) for p in plain) / len(names) < 0.05
