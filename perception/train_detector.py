"""Train and evaluate the block detector (:mod:`perception.detector`) on synthetic renders.

Commands (figures in ``docs/detector.md``)::

    python -m perception.train_detector train --out perception/weights/detector.pt --seed 0
    python -m perception.train_detector evaluate --weights perception/weights/detector.pt \\
        --n 300 --seed 12345
    python -m perception.train_detector calibrate --weights perception/weights/detector.pt
    python -m perception.train_detector train --smoke --out /tmp/smoke.pt   # CI: seconds

Training frames come from :func:`perception.synth.dataset.render_detection_sample` for the
identities ``t0001A``... (``identity_names(ids, "t")``), rendered once before training (one
process; consecutive frames share an identity so the renderer's scene cache hits), white
balanced, shrunk to the network input and kept in memory. A ground-truth block less than
half inside the frame (``visible < 0.5``) is "don't care": no loss on the cells around it.
After training the operating point is calibrated and the model evaluated on other
identities and seeds (:mod:`perception.detector_eval`).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch
import torch.nn.functional as F

from perception.detector import (
    DEFAULT_WEIGHTS,
    FORMAT,
    FORMAT_VERSION,
    BlockDetector,
    BlockNet,
    DetectorConfig,
    config_to_dict,
    decode,
    to_input,
)
from perception.detector_data import (
    augment,
    build_targets,
    colour_augment,
    render_set,
)
from perception.detector_eval import calibrate, evaluate, format_calibration, format_metrics
from perception.errors import ModelError
from perception.synth.dataset import identity_names

Log = Callable[[str], None]


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (with the seed)."""

    frames: int = 10000
    identities: int = 1000
    wide_fraction: float = 0.1  # frames with a larger lateral offset: few or no blocks
    variety: bool = True  # random looks, ageings and view conditions (detector_data)
    distance_m: tuple[float, float] = (0.22, 1.3)
    yaw_deg: float = 32.0
    colour_augment: float = 0.8  # share of samples given colour_augment
    rack_fraction: float = 0.3  # frames with the pallet on a rack beam (rack_context)
    dark_paint: float = 0.08  # extra pallets painted black or very dark (varied_style)
    aim_fraction: float = 0.0  # frames aimed at a block as the scan's are (docs/detector.md)
    steps: int = 6000
    batch: int = 32
    lr: float = 3e-3
    weight_decay: float = 5e-4
    warmup: int = 150
    ema: float = 0.998
    eval_frames: int = 300


SMOKE = TrainConfig(frames=16, identities=4, steps=3, batch=4, warmup=1, eval_frames=6)


def giou(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """IoU and generalised IoU of matching rows of two (M, 4) box tensors."""
    ix = (torch.minimum(a[:, 2], b[:, 2]) - torch.maximum(a[:, 0], b[:, 0])).clamp(min=0)
    iy = (torch.minimum(a[:, 3], b[:, 3]) - torch.maximum(a[:, 1], b[:, 1])).clamp(min=0)
    inter = ix * iy
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a + area_b - inter + 1e-7
    iou = inter / union
    cw = torch.maximum(a[:, 2], b[:, 2]) - torch.minimum(a[:, 0], b[:, 0])
    ch = torch.maximum(a[:, 3], b[:, 3]) - torch.minimum(a[:, 1], b[:, 1])
    hull = cw * ch + 1e-7
    return iou, iou - (hull - union) / hull


def detection_loss(
    out: torch.Tensor, obj: torch.Tensor, weight: torch.Tensor, tbox: torch.Tensor, stride: int
) -> tuple[torch.Tensor, dict[str, float]]:
    """Objectness BCE (per positive) + 2 x (1 - GIoU) + L1 of centre / log size (in cells)."""
    boxes, logits = decode(out, stride)
    npos = max(1.0, float(obj.sum()))
    l_obj = (F.binary_cross_entropy_with_logits(logits, obj, reduction="none") * weight).sum()
    l_obj = l_obj / npos
    pos = obj > 0.5
    if pos.any():
        p, t = boxes[pos], tbox[pos]
        _, g = giou(p, t)
        l_giou = (1.0 - g).mean()
        pc = torch.stack(((p[:, 0] + p[:, 2]) / 2, (p[:, 1] + p[:, 3]) / 2), 1) / stride
        tc = torch.stack(((t[:, 0] + t[:, 2]) / 2, (t[:, 1] + t[:, 3]) / 2), 1) / stride
        pwh = torch.log((p[:, 2:] - p[:, :2]).clamp(min=1e-3))
        twh = torch.log((t[:, 2:] - t[:, :2]).clamp(min=1e-3))
        l_l1 = (pc - tc).abs().mean() + (pwh - twh).abs().mean()
    else:
        l_giou = l_l1 = boxes.sum() * 0.0
    loss = l_obj + 2.0 * l_giou + l_l1
    return loss, {"obj": l_obj.item(), "giou": l_giou.item(), "l1": l_l1.item()}


# ------------------------------------------------------------------------------ train
def train(
    cfg: TrainConfig, seed: int, log: Log, det_config: DetectorConfig | None = None
) -> tuple[BlockNet, dict]:
    """Render the training set, train a :class:`BlockNet` (EMA weights returned)."""
    det_config = det_config or DetectorConfig()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed + 1)
    t0 = time.perf_counter()
    names = identity_names(cfg.identities, "t")
    data = render_set(
        names,
        cfg.frames,
        seed,
        det_config,
        wide_fraction=cfg.wide_fraction,
        variety=cfg.variety,
        distance_m=cfg.distance_m,
        yaw_deg=cfg.yaw_deg,
        rack_fraction=cfg.rack_fraction,
        dark_paint=cfg.dark_paint,
        aim_fraction=cfg.aim_fraction,
        log=log,
    )
    render_s = time.perf_counter() - t0
    log(f"rendered {cfg.frames} training frames of {len(names)} identities in {render_s:.0f} s")
    sx = det_config.input_hw[1] / det_config.frame_hw[1]
    sy = det_config.input_hw[0] / det_config.frame_hw[0]
    in_scale = np.array([sx, sy, sx, sy, 1.0], np.float32)
    model = BlockNet(det_config)
    ema = BlockNet(det_config)
    ema.load_state_dict(model.state_dict())
    ema.eval()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)

    def lr_at(step: int) -> float:
        if step < cfg.warmup:
            return cfg.lr * (step + 1) / cfg.warmup
        frac = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
        return cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * frac)))

    t1 = time.perf_counter()
    running: dict[str, float] = {}
    n = len(data.images)
    for step in range(cfg.steps):
        idx = rng.integers(n, size=cfg.batch)
        imgs, bxs = [], []
        for j in idx:
            im, b = augment(data.images[j], data.boxes[j] * in_scale, rng)
            if rng.random() < cfg.colour_augment:
                im = colour_augment(im, rng)
            imgs.append(im)
            bxs.append(b)
        obj, weight, tbox = build_targets(bxs, det_config)
        x = to_input(imgs, det_config.input_hw)
        model.train()
        out = model(x)
        loss, parts = detection_loss(
            out,
            torch.from_numpy(obj),
            torch.from_numpy(weight),
            torch.from_numpy(tbox),
            det_config.stride,
        )
        for g in opt.param_groups:
            g["lr"] = lr_at(step)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        opt.step()
        decay = min(cfg.ema, (1 + step) / (10 + step))
        with torch.no_grad():
            for pe, pm in zip(ema.state_dict().values(), model.state_dict().values(), strict=True):
                if pe.dtype.is_floating_point:
                    pe.mul_(decay).add_(pm.detach(), alpha=1 - decay)
                else:
                    pe.copy_(pm)
        for k, v in {"loss": loss.item(), **parts}.items():
            running[k] = 0.95 * running.get(k, v) + 0.05 * v
        if (step + 1) % 100 == 0 or step + 1 == cfg.steps:
            el = time.perf_counter() - t1
            log(
                f"step {step + 1}/{cfg.steps} loss {running['loss']:.3f} "
                f"(obj {running['obj']:.3f} giou {running['giou']:.3f} l1 {running['l1']:.3f}) "
                f"lr {lr_at(step):.2e} {el:.0f} s ({el / (step + 1):.2f} s/step)"
            )
    info = {
        "render_seconds": round(render_s, 1),
        "train_seconds": round(time.perf_counter() - t1, 1),
        "frames": cfg.frames,
        "identities": f"{names[0]}..{names[-1]}",
        "batch": cfg.batch,
        "variety": cfg.variety,
        "distance_m": list(cfg.distance_m),
        "yaw_deg": cfg.yaw_deg,
        "colour_augment": cfg.colour_augment,
        "aim_fraction": cfg.aim_fraction,
    }
    return ema, info


# -------------------------------------------------------------------------------- CLI
def _with_operating_point(blob: dict, detector: BlockDetector, path: str, n: int, log: Log) -> dict:
    """Calibrate ``detector`` (the weights of ``blob``; :func:`perception.detector_eval.
    calibrate`), store its threshold and sweep in ``blob`` and write ``blob`` to ``path``."""
    cal = calibrate(detector, n, log)
    log(format_calibration(cal))
    blob["score_threshold"] = cal["score_threshold"]
    blob.setdefault("trained", {})["calibration"] = cal
    torch.save(blob, path)
    return blob


def cmd_train(args: argparse.Namespace, log: Log) -> int:
    """Render, train, calibrate the operating point, evaluate on held-out renders, write
    the checkpoint."""
    cfg = SMOKE if args.smoke else TrainConfig()
    overrides = {"steps": args.steps, "frames": args.frames}
    cfg = replace(cfg, **{k: v for k, v in overrides.items() if v is not None})
    t0 = time.perf_counter()
    model, info = train(cfg, args.seed, log)
    command = "python -m perception.train_detector " + " ".join(
        sys.argv[1:] if args.argv is None else args.argv
    )
    blob = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "config": config_to_dict(model.config),
        "state_dict": model.state_dict(),
        "trained": {"seed": args.seed, "steps": cfg.steps, "command": command, **info},
    }
    torch.save(blob, args.out)
    if cfg.eval_frames:
        blob = _with_operating_point(
            blob, BlockDetector.load(args.out), args.out, cfg.eval_frames, log
        )
        detector = BlockDetector.load(args.out)
        metrics = evaluate(detector, cfg.eval_frames, 12345, log)
        blob["trained"]["metrics"] = metrics
        log(format_metrics(metrics))
        varied = evaluate(detector, cfg.eval_frames, 12346, log, variety=True)
        blob["trained"]["metrics_varied"] = varied
        log(format_metrics(varied))
        racked = evaluate(detector, cfg.eval_frames, 12347, log, variety=True, racks=True)
        blob["trained"]["metrics_racks"] = racked
        log(format_metrics(racked))
    blob["trained"]["wall_seconds"] = round(time.perf_counter() - t0, 1)
    torch.save(blob, args.out)
    log(f"wrote {args.out} ({blob['trained']['wall_seconds']:.0f} s)")
    return 0


def cmd_calibrate(args: argparse.Namespace, log: Log) -> int:
    """Choose a checkpoint's operating point and write it into the checkpoint (or a copy)."""
    src = args.weights or DEFAULT_WEIGHTS
    detector = BlockDetector.load(src)  # a clear error for a file that is not a checkpoint
    blob = torch.load(src, map_location="cpu", weights_only=True)
    out = args.out or src
    _with_operating_point(blob, detector, out, args.n, log)
    detector = BlockDetector.load(out)
    print(f"{detector.model_version} ({out}): score_threshold {detector.score_threshold}")
    return 0


def cmd_evaluate(args: argparse.Namespace, log: Log) -> int:
    """Print the held-out figures of a checkpoint."""
    detector = BlockDetector.load(args.weights)
    metrics = evaluate(detector, args.n, args.seed, log, args.min_score, args.variety, args.racks)
    print(f"{detector.model_version} ({detector.path})")
    print(format_metrics(metrics))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(
        prog="python -m perception.train_detector",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    tr = sub.add_parser("train", help="render, train, write a checkpoint")
    tr.add_argument("--out", required=True)
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--steps", type=int, default=None)
    tr.add_argument("--frames", type=int, default=None, help="training renders")
    tr.add_argument("--smoke", action="store_true", help="tiny run for tests (seconds)")
    ev = sub.add_parser("evaluate", help="held-out precision / recall / AP")
    ev.add_argument("--weights", default=None)
    ev.add_argument("--n", type=int, default=300)
    ev.add_argument("--seed", type=int, default=12345)
    ev.add_argument(
        "--min-score", type=float, default=None, help="default: the checkpoint's operating point"
    )
    ev.add_argument("--variety", action="store_true", help="varied looks and conditions")
    ev.add_argument("--racks", action="store_true", help="every pallet on a rack beam")
    ca = sub.add_parser("calibrate", help="choose the operating point, write it into a checkpoint")
    ca.add_argument("--weights", default=None, help="default: the shipped detector.pt")
    ca.add_argument("--out", default=None, help="write a calibrated copy here (default: in place)")
    ca.add_argument("--n", type=int, default=300, help="validation frames per set (4 sets)")
    for p in (tr, ev, ca):
        p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
        p.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    args.argv = argv
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:7.1f}s] {msg}", file=sys.stderr, flush=True)

    commands = {"train": cmd_train, "evaluate": cmd_evaluate, "calibrate": cmd_calibrate}
    try:
        return commands[args.cmd](args, log)
    except ModelError as exc:  # a missing, foreign or damaged weights file: say which
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
