"""Train, calibrate and evaluate the PCB block embedder on synthetic pallets.

Commands (see ``docs/perception.md`` for the figures they produce)::

    python -m perception.train_embedder train --out perception/weights/pcb_small.pt --seed 0
    python -m perception.train_embedder calibrate --weights perception/weights/pcb_small.pt
    python -m perception.train_embedder eval --weights perception/weights/pcb_small.pt
    python -m perception.train_embedder train --smoke --out /tmp/smoke.pt   # CI: seconds

Identity splits never overlap (each prefix gives other texture seeds): training ``tr*``
(each (pallet side, block) is one class), validation ``va*`` (threshold calibration) and
``vu*`` (never enrolled), test ``te*`` and ``tu*`` (never enrolled). Training crops come
from varied looks and conditions (:mod:`perception.embedder_data`); each view is aged and
taken through the sensor again at random, and the visibility head learns which part of it
is hidden. Evaluation and calibration: :mod:`perception.embedder_eval`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from perception.embedder import (
    FORMAT,
    FORMAT_VERSION,
    BlockEmbedder,
    config_to_dict,
    to_tensor,
)
from perception.embedder_data import (
    BLOCKS,
    augment,
    render_crops,
    split_names,
    stripe_visibility,
)
from perception.embedder_eval import (
    evaluate,
    validate,
)
from perception.gallery import Thresholds
from perception.pcb import PCB, PCBConfig

INPUT_HW = (64, 112)
Log = Callable[[str], None]


# ------------------------------------------------------------------------------ training
@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run."""

    pallets: int = 400
    crops_per_block: int = 10
    steps: int = 4000
    classes_per_batch: int = 16
    crops_per_class: int = 4
    lr: float = 1e-3
    weight_decay: float = 5e-4
    cos_scale: float = 16.0
    cos_margin: float = 0.2
    triplet_margin: float = 0.3
    triplet_weight: float = 1.0
    visibility: bool = True  # the stripe visibility head (occlusion-aware matching)
    visibility_weight: float = 0.5
    normalisation: str = "robust"  # crop standardisation (perception.embedder.to_tensor)
    ageing: float = 0.5  # share of views aged (stains, dust, occluders, ...)
    ageing_strength: float = 0.8  # x the largest random ageing (25 % stains, 45 % hidden)
    sensor: float = 0.4  # share of views taken through the sensor again (noise, Bayer JPEG)
    mode: str = "varied"  # how crops are rendered (perception.embedder_data.MODES)
    init: str = ""  # start from these btrun-pcb weights (empty: from scratch)
    val_pallets: int = 150
    val_unknown_pallets: int = 200


SMOKE = TrainConfig(
    pallets=3,
    crops_per_block=3,
    steps=6,
    classes_per_batch=4,
    crops_per_class=2,
    val_pallets=3,
    val_unknown_pallets=1,
)


def _forward_train(
    model: PCB,
    x: torch.Tensor,
    y: torch.Tensor,
    vis_map: torch.Tensor,
    stripe_vis: torch.Tensor,
    scale: float,
    margin: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Softmax loss of the part classifiers, the stripe vectors (N, parts, C) and the
    visibility loss of a batch.

    The classifiers are cosine classifiers with an additive margin (CosFace): logits
    ``scale * (cos - margin [target only])`` between the L2-normalised reduced part feature
    and the L2-normalised class weights. With thousands of classes and a dozen crops each, a
    plain linear softmax stays at chance for many epochs on this CPU budget; the normalised
    form learns from the first steps and trains the same distance the gallery uses. Each
    stripe's loss counts with the stripe's visible fraction (``stripe_vis`` (N, parts)): a
    stripe behind a strap cannot tell classes apart. The visibility head learns the visible
    fraction of every cell (``vis_map`` (N, 1, h, w)).
    """
    fmap = model.featuremaps(x)
    logits_v = model.visibility_map(fmap)
    v_g, _ = model.pool_parts(fmap, logits_v)
    stripes = F.normalize(v_g, p=2, dim=1).squeeze(-1).transpose(1, 2)
    v_h = model.conv5(model.dropout(v_g))
    target = F.one_hot(y, model.config.num_classes).to(v_h.dtype) * margin
    w = stripe_vis.clamp(min=0.02)
    ce = x.new_zeros(())
    for i in range(model.config.parts):
        f = F.normalize(v_h[:, :, i, :].flatten(1), dim=1)
        cw = F.normalize(model.classifier[i].weight, dim=1)
        per = F.cross_entropy(scale * (f @ cw.T - target), y, reduction="none")
        ce = ce + (per * w[:, i]).sum() / w[:, i].sum()
    l_vis = (
        F.binary_cross_entropy_with_logits(logits_v, vis_map)
        if logits_v is not None
        else x.new_zeros(())
    )
    return ce / model.config.parts, stripes, l_vis


def weighted_distances(stripes: torch.Tensor, vis: torch.Tensor) -> torch.Tensor:
    """(N, N) block distances of stripe vectors (N, parts, C) weighted by the product of the
    stripes' visibilities (N, parts), as the gallery compares blocks."""
    cos = torch.einsum("ipc,jpc->ijp", stripes, stripes)
    w = (vis[:, None, :] * vis[None, :, :]).clamp(min=0.02)
    return ((w * (2.0 - 2.0 * cos)).sum(-1) / w.sum(-1)).clamp(min=1e-12).sqrt()


def batch_hard_triplet(dist: torch.Tensor, labels: torch.Tensor, margin: float) -> torch.Tensor:
    """Batch-hard triplet loss on a distance matrix (hardest positive, hardest negative)."""
    same = labels[:, None] == labels[None, :]
    pos = (dist * same).max(dim=1).values
    neg = (dist + same * 10.0).min(dim=1).values
    return F.relu(pos - neg + margin).mean()


def _batch(
    crops: list,
    classes: np.ndarray,
    counts: np.ndarray,
    cfg: TrainConfig,
    rng: np.random.Generator,
    input_hw: tuple[int, int],
    fmap_hw: tuple[int, int],
    parts: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Images, labels, cell visibility maps and stripe visibilities of one batch."""
    imgs, labels, maps, stripes = [], [], [], []
    for c in classes:
        for k in rng.choice(
            counts[c], cfg.crops_per_class, replace=counts[c] < cfg.crops_per_class
        ):
            img, hidden = augment(
                crops[c][k], rng, input_hw, cfg.ageing, cfg.sensor, strength=cfg.ageing_strength
            )
            imgs.append(img)
            labels.append(int(c))
            cells = cv2.resize(hidden, (fmap_hw[1], fmap_hw[0]), interpolation=cv2.INTER_AREA)
            maps.append(1.0 - cells)
            stripes.append(stripe_visibility(hidden, parts))
    return (
        to_tensor(imgs, cfg.normalisation),
        torch.tensor(labels),
        torch.from_numpy(np.stack(maps)[:, None].astype(np.float32)),
        torch.from_numpy(np.stack(stripes)),
    )


def _init_from(model: PCB, path: str, log: Log) -> None:
    """Start from a btrun-pcb checkpoint's backbone and reduction (the classifiers and a
    visibility head it lacks start fresh)."""
    blob = torch.load(path, map_location="cpu", weights_only=True)
    state = {k: v for k, v in blob["state_dict"].items() if not k.startswith("classifier.")}
    missing, unexpected = model.load_state_dict(state, strict=False)
    fresh = [k for k in missing if not k.startswith(("classifier.", "visibility."))]
    if fresh or unexpected:
        raise ValueError(f"{path} does not fit: missing {fresh}, unexpected {unexpected}")
    log(f"initialised from {path} (fresh: {', '.join(sorted({k.split('.')[0] for k in missing}))})")


def train(
    cfg: TrainConfig, seed: int, jobs: int, log: Log, input_hw: tuple[int, int] = INPUT_HW
) -> tuple[PCB, dict]:
    """Render the training crops, train a PCB-small model; return it and run statistics."""
    t0 = time.perf_counter()
    torch.manual_seed(seed)
    names = split_names("tr", cfg.pallets)
    log(f"rendering {len(names)} training identities x {BLOCKS} blocks x {cfg.crops_per_block}")
    data = render_crops(names, cfg.crops_per_block, seed, jobs, log, mode=cfg.mode)
    crops = [ks for ident in data for ks in ident]  # class c = identity * 3 + block
    counts = np.array([len(k) for k in crops])
    n_classes = len(crops)
    render_s = time.perf_counter() - t0
    log(f"{int(counts.sum())} crops of {n_classes} classes rendered in {render_s:.0f} s")
    model = PCB(
        PCBConfig(
            num_classes=n_classes,
            input_hw=input_hw,
            visibility=cfg.visibility,
            normalisation=cfg.normalisation,
        )
    ).train()
    if cfg.init:
        _init_from(model, cfg.init, log)
    with torch.no_grad():
        fmap_hw = tuple(model.featuremaps(torch.zeros(1, 3, *input_hw)).shape[2:])
    parts = model.config.parts
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    warm = max(1, cfg.steps // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt,
        lambda s: (
            min(1.0, (s + 1) / warm)
            * 0.5
            * (1 + math.cos(math.pi * min(1.0, s / max(1, cfg.steps))))
        ),
    )
    rng = np.random.default_rng(seed)
    usable = np.flatnonzero(counts >= 1)
    t1, run_loss = time.perf_counter(), []
    for step in range(1, cfg.steps + 1):
        cls = rng.choice(usable, cfg.classes_per_batch, replace=False)
        x, y, vmap, svis = _batch(crops, cls, counts, cfg, rng, input_hw, fmap_hw, parts)
        ce, stripes, l_vis = _forward_train(model, x, y, vmap, svis, cfg.cos_scale, cfg.cos_margin)
        tri = batch_hard_triplet(weighted_distances(stripes, svis), y, cfg.triplet_margin)
        loss = ce + cfg.triplet_weight * tri + cfg.visibility_weight * l_vis
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        run_loss.append((ce.item(), tri.item(), l_vis.item()))
        if step % 100 == 0 or step == cfg.steps:
            ce_m, tri_m, vis_m = np.mean(run_loss[-100:], axis=0)
            epoch = step * len(y) / counts.sum()
            log(
                f"step {step}/{cfg.steps} epoch {epoch:.2f} softmax {ce_m:.3f} "
                f"triplet {tri_m:.3f} visibility {vis_m:.3f} lr {sched.get_last_lr()[0]:.2e} "
                f"elapsed {time.perf_counter() - t0:.0f} s"
            )
    model.eval()
    stats = {
        "train_identities": len(names),
        "classes": n_classes,
        "crops": int(counts.sum()),
        "render_s": round(render_s, 1),
        "train_s": round(time.perf_counter() - t1, 1),
    }
    return model, stats


# ------------------------------------------------------------------------------ CLI
def save_checkpoint(
    path: str, model: PCB, thresholds: Thresholds, metrics: dict, training: dict
) -> None:
    """Write a ``btrun-pcb`` checkpoint (classifier weights dropped: not used at inference)."""
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("classifier.")}
    torch.save(
        {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "config": config_to_dict(model.config),
            "state_dict": state,
            "thresholds": {
                "max_distance": thresholds.max_distance,
                "min_margin": thresholds.min_margin,
            },
            "metrics": metrics,
            "training": training,
        },
        path,
    )


def cmd_train(args: argparse.Namespace, log: Log) -> int:
    """Train, calibrate the thresholds on the validation split, save the checkpoint."""
    t0 = time.perf_counter()
    cfg = SMOKE if args.smoke else TrainConfig(pallets=args.pallets, steps=args.steps)
    cfg = replace(cfg, init=args.init or "", lr=args.lr or cfg.lr)
    for key in ("ageing", "ageing_strength", "triplet_margin"):
        if getattr(args, key, None) is not None:
            cfg = replace(cfg, **{key: getattr(args, key)})
    model, stats = train(cfg, args.seed, args.jobs, log)
    tmp_emb = BlockEmbedder(model, "calibrating", Thresholds())
    th, figures = validate(
        tmp_emb, cfg.val_pallets, cfg.val_unknown_pallets, args.seed, args.jobs, log
    )
    metrics = {**figures, **stats}
    minutes = (time.perf_counter() - t0) / 60
    training = {
        "command": " ".join(["python -m perception.train_embedder", *sys.argv[1:]]),
        "seed": args.seed,
        "minutes": round(minutes, 2),
        "threads": torch.get_num_threads(),
        "config": cfg.__dict__,
    }
    save_checkpoint(args.out, model, th, metrics, training)
    log(f"thresholds {th}; validation {json.dumps(metrics['validation'])}")
    log(f"decisions {json.dumps(metrics['validation_decisions'])}")
    log(f"saved {args.out} after {minutes:.1f} min")
    return 0


def cmd_calibrate(args: argparse.Namespace, log: Log) -> int:
    """Recalibrate the thresholds of a btrun checkpoint on the validation split (same
    weights; the file, hence the model version, changes)."""
    try:
        emb = BlockEmbedder.load(args.weights)
        blob = torch.load(args.weights, map_location="cpu", weights_only=False)
    except Exception as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    th, figures = validate(
        emb, TrainConfig.val_pallets, TrainConfig.val_unknown_pallets, args.seed, args.jobs, log
    )
    metrics = {**blob.get("metrics", {}), **figures}
    training = {
        **blob.get("training", {}),
        "calibrated": "python -m perception.train_embedder " + " ".join(sys.argv[1:]),
    }
    emb.model.eval()
    save_checkpoint(args.out or args.weights, emb.model, th, metrics, training)
    log(f"thresholds {th}; decisions {json.dumps(figures['validation_decisions'])}")
    return 0


def cmd_eval(args: argparse.Namespace, log: Log) -> int:
    """Evaluate a checkpoint on the held-out test split and print (and save) the figures."""
    try:
        emb = BlockEmbedder.load(args.weights, args.backbone)
    except Exception as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    report = evaluate(emb, args, log)
    report["eval_s"] = round(time.perf_counter() - t0, 1)
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            f.write(text + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(
        prog="python -m perception.train_embedder",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    tr = sub.add_parser("train", help="train + calibrate, write a checkpoint")
    tr.add_argument("--out", required=True)
    tr.add_argument("--pallets", type=int, default=TrainConfig.pallets)
    tr.add_argument("--steps", type=int, default=TrainConfig.steps)
    tr.add_argument("--smoke", action="store_true", help="tiny run for tests (seconds)")
    tr.add_argument("--init", default="", help="start from these btrun-pcb weights")
    tr.add_argument("--lr", type=float, default=None, help="peak learning rate")
    tr.add_argument("--ageing", type=float, default=None, help="share of training views aged")
    tr.add_argument(
        "--ageing-strength", type=float, default=None, help="x the largest random ageing"
    )
    tr.add_argument("--triplet-margin", type=float, default=None, help="triplet loss margin")
    ca = sub.add_parser("calibrate", help="recalibrate a checkpoint's unknown thresholds")
    ca.add_argument("--weights", required=True)
    ca.add_argument("--out", default="", help="write here (default: over --weights)")
    ev = sub.add_parser("eval", help="held-out test figures and baselines")
    ev.add_argument("--weights", default=None)
    ev.add_argument("--backbone", default=None)
    ev.add_argument("--test-pallets", type=int, default=500)
    ev.add_argument("--unknown-pallets", type=int, default=100)
    ev.add_argument("--json", default="")
    for p in (tr, ca, ev):
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
        p.add_argument("--jobs", type=int, default=1, help="rendering processes (default 1)")
        p.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:7.1f}s] {msg}", file=sys.stderr, flush=True)

    commands = {"train": cmd_train, "calibrate": cmd_calibrate, "eval": cmd_eval}
    return commands[args.cmd](args, log)


if __name__ == "__main__":
    raise SystemExit(main())
