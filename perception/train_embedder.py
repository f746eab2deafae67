"""Train, calibrate and evaluate the PCB block embedder on synthetic pallets; baselines.

Commands (see ``docs/perception.md`` for the figures they produce)::

    python -m perception.train_embedder train --out perception/weights/pcb_small.pt --seed 0
    python -m perception.train_embedder eval --weights perception/weights/pcb_small.pt
    python -m perception.train_embedder train --smoke --out /tmp/smoke.pt   # CI: seconds

Identity splits never overlap (each prefix gives other texture seeds): training ``tr*``
(each (pallet side, block) is one class), validation ``va*`` (threshold calibration: enrolled
and non-enrolled pallets), test ``te*`` (gallery of 500 pallets x 2 sides) and ``tu*``
(non-enrolled test pallets, the "unknown" queries). Gallery entries and queries are
independent renders (:func:`perception.synth.dataset.block_crops`), one crop per block, as
the mission enrols from one scan.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from perception.embedder import (
    FORMAT,
    FORMAT_VERSION,
    BlockEmbedder,
    config_to_dict,
    resize_crop,
    to_tensor,
)
from perception.gallery import Thresholds
from perception.pcb import PCB, PCBConfig
from perception.synth.dataset import block_crops, identity_names

BLOCKS = 3
INPUT_HW = (64, 112)
Log = Callable[[str], None]


# ------------------------------------------------------------------------------ crops
def _render_identity(job: tuple[str, int, int]) -> list[list[np.ndarray]]:
    name, n, seed = job
    rng = np.random.default_rng([seed, *name.encode()])
    return [block_crops(name, None, b, rng, n) for b in range(BLOCKS)]


def render_crops(
    names: list[str], per_block: int, seed: int, jobs: int = 1, log: Log | None = None
) -> list[list[list[np.ndarray]]]:
    """Crops ``[identity][block][k]`` (``per_block`` each), deterministic in ``seed`` and
    each name whatever ``jobs`` (worker processes) is."""
    work = [(n, per_block, seed) for n in names]
    out: list[list[list[np.ndarray]]] = []
    t0 = time.perf_counter()
    pool = mp.get_context("fork").Pool(jobs) if jobs > 1 else None
    try:
        it = pool.imap(_render_identity, work, chunksize=4) if pool else map(_render_identity, work)
        for i, crops in enumerate(it, 1):
            out.append(crops)
            if log and (i % 100 == 0 or i == len(work)):
                log(
                    f"  rendered {i}/{len(work)} identities "
                    f"({i * BLOCKS * per_block} crops, {time.perf_counter() - t0:.0f} s)"
                )
    finally:
        if pool:
            pool.close()
            pool.join()
    return out


def split_names(kind: str, pallets: int) -> list[str]:
    """Both sides of ``pallets`` synthetic pallets of split ``kind`` (tr, va, vu, te, tu)."""
    return identity_names(2 * pallets, prefix=kind)


# ------------------------------------------------------------------------------ training
@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run."""

    pallets: int = 300
    crops_per_block: int = 12
    steps: int = 3000
    classes_per_batch: int = 16
    crops_per_class: int = 4
    lr: float = 1e-3
    weight_decay: float = 5e-4
    cos_scale: float = 16.0
    cos_margin: float = 0.2
    triplet_margin: float = 0.3
    triplet_weight: float = 1.0
    val_pallets: int = 150
    val_unknown_pallets: int = 50


SMOKE = TrainConfig(
    pallets=3,
    crops_per_block=3,
    steps=6,
    classes_per_batch=4,
    crops_per_class=2,
    val_pallets=3,
    val_unknown_pallets=1,
)


def augment(crop: np.ndarray, rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    """One training view: jittered scale/offset/rotation into ``hw``, colour and gain jitter,
    sometimes lower resolution or blur, sometimes an erased patch. BGR uint8."""
    h, w = hw
    ch, cw = crop.shape[:2]
    sx, sy = w / cw * rng.uniform(0.9, 1.1), h / ch * rng.uniform(0.9, 1.1)
    ang = math.radians(rng.normal(0.0, 2.0))
    c, s = math.cos(ang), math.sin(ang)
    m = np.array([[sx * c, -sy * s, 0.0], [sx * s, sy * c, 0.0]], np.float32)
    centre = m[:, :2] @ np.array([cw / 2, ch / 2], np.float32)
    m[:, 2] = np.array([w / 2, h / 2]) - centre + rng.normal(0.0, 0.04, 2) * (w, h)
    out = cv2.warpAffine(crop, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    f = out.astype(np.float32)
    gain = rng.uniform(0.75, 1.3) * rng.normal(1.0, 0.05, 3)
    f = (f - 128.0) * rng.uniform(0.8, 1.2) + 128.0
    f = f * gain.astype(np.float32)
    if rng.random() < 0.3:
        k = rng.uniform(0.35, 0.8)
        small = cv2.resize(
            f, (max(4, int(w * k)), max(4, int(h * k))), interpolation=cv2.INTER_AREA
        )
        f = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < 0.3:
        eh, ew = int(h * rng.uniform(0.1, 0.4)), int(w * rng.uniform(0.1, 0.4))
        y, x = int(rng.integers(0, h - eh + 1)), int(rng.integers(0, w - ew + 1))
        f[y : y + eh, x : x + ew] = rng.uniform(0, 255, 3)
    f += rng.normal(0.0, rng.uniform(0.0, 4.0), f.shape).astype(np.float32)
    return np.clip(f, 0, 255).astype(np.uint8)


def _forward_train(
    model: PCB, x: torch.Tensor, y: torch.Tensor, scale: float, margin: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Softmax loss of the part classifiers and the gallery feature (unit norm) of a batch.

    The classifiers are cosine classifiers with an additive margin (CosFace): logits
    ``scale * (cos - margin [target only])`` between the L2-normalised reduced part feature
    and the L2-normalised class weights. With thousands of classes and a dozen crops each, a
    plain linear softmax stays at chance for many epochs on this CPU budget; the normalised
    form learns from the first steps and trains the same distance the gallery uses.
    """
    v_g = model.parts_avgpool(model.featuremaps(x))
    feat = F.normalize(v_g, p=2, dim=1).flatten(1) / math.sqrt(model.config.parts)
    v_h = model.conv5(model.dropout(v_g))
    target = F.one_hot(y, model.config.num_classes).to(v_h.dtype) * margin
    ce = x.new_zeros(())
    for i in range(model.config.parts):
        f = F.normalize(v_h[:, :, i, :].flatten(1), dim=1)
        w = F.normalize(model.classifier[i].weight, dim=1)
        ce = ce + F.cross_entropy(scale * (f @ w.T - target), y)
    return ce / model.config.parts, feat


def batch_hard_triplet(feat: torch.Tensor, labels: torch.Tensor, margin: float) -> torch.Tensor:
    """Batch-hard triplet loss (hardest positive, hardest negative per anchor)."""
    d = torch.cdist(feat, feat)
    same = labels[:, None] == labels[None, :]
    pos = (d * same).max(dim=1).values
    neg = (d + same * 10.0).min(dim=1).values
    return F.relu(pos - neg + margin).mean()


def train(
    cfg: TrainConfig, seed: int, jobs: int, log: Log, input_hw: tuple[int, int] = INPUT_HW
) -> tuple[PCB, dict]:
    """Render the training crops, train a PCB-small model; return it and run statistics."""
    t0 = time.perf_counter()
    torch.manual_seed(seed)
    names = split_names("tr", cfg.pallets)
    log(f"rendering {len(names)} training identities x {BLOCKS} blocks x {cfg.crops_per_block}")
    data = render_crops(names, cfg.crops_per_block, seed, jobs, log)
    crops = [ks for ident in data for ks in ident]  # class c = identity * 3 + block
    counts = np.array([len(k) for k in crops])
    n_classes = len(crops)
    render_s = time.perf_counter() - t0
    log(f"{int(counts.sum())} crops of {n_classes} classes rendered in {render_s:.0f} s")
    model = PCB(PCBConfig(num_classes=n_classes, input_hw=input_hw)).train()
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
        imgs, labels = [], []
        for c in cls:
            for k in rng.choice(
                counts[c], cfg.crops_per_class, replace=counts[c] < cfg.crops_per_class
            ):
                imgs.append(augment(crops[c][k], rng, input_hw))
                labels.append(int(c))
        x, y = to_tensor(imgs), torch.tensor(labels)
        ce, feat = _forward_train(model, x, y, cfg.cos_scale, cfg.cos_margin)
        tri = batch_hard_triplet(feat, y, cfg.triplet_margin)
        loss = ce + cfg.triplet_weight * tri
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        run_loss.append((ce.item(), tri.item()))
        if step % 100 == 0 or step == cfg.steps:
            ce_m, tri_m = np.mean(run_loss[-100:], axis=0)
            epoch = step * len(imgs) / counts.sum()
            log(
                f"step {step}/{cfg.steps} epoch {epoch:.2f} softmax {ce_m:.3f} "
                f"triplet {tri_m:.3f} lr {sched.get_last_lr()[0]:.2e} "
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


# ------------------------------------------------------------------------------ evaluation
def embed_with(emb: BlockEmbedder, data: list[list[list[np.ndarray]]], k: int) -> np.ndarray:
    """Embeddings (identities, 3, dim) of crop ``k`` of every block, batched."""
    flat = [ident[b][min(k, len(ident[b]) - 1)] for ident in data for b in range(BLOCKS)]
    out = np.concatenate([emb.embed(flat[i : i + 192]) for i in range(0, len(flat), 192)])
    return out.reshape(len(data), BLOCKS, -1)


def mean_block_distances(q: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(Q, G) mean over the three blocks of the Euclidean block-to-block distances."""
    total = np.zeros((len(q), len(g)), np.float64)
    for b in range(BLOCKS):
        qb, gb = q[:, b].astype(np.float64), g[:, b].astype(np.float64)
        d2 = (qb**2).sum(1)[:, None] + (gb**2).sum(1)[None, :] - 2.0 * qb @ gb.T
        total += np.sqrt(np.maximum(d2, 0.0))
    return total / BLOCKS


def rank_metrics(dist: np.ndarray, truth: np.ndarray) -> dict:
    """Rank-1, rank-5 and mAP (one relevant entry per query) from a (Q, G) distance matrix."""
    true_d = dist[np.arange(len(dist)), truth]
    rank = (dist < true_d[:, None]).sum(1)  # 0 = first
    return {
        "rank1": float(np.mean(rank == 0)),
        "rank5": float(np.mean(rank < 5)),
        "mAP": float(np.mean(1.0 / (rank + 1))),
        "queries": int(len(dist)),
        "gallery": int(dist.shape[1]),
    }


def best_and_margin(dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index of the best entry, its distance and the margin to the runner-up, per query."""
    order = np.argsort(dist, axis=1)[:, :2]
    rows = np.arange(len(dist))
    d1, d2 = dist[rows, order[:, 0]], dist[rows, order[:, 1]]
    return order[:, 0], d1, d2 - d1


def calibrate(known: np.ndarray, truth: np.ndarray, unknown: np.ndarray) -> tuple[Thresholds, dict]:
    """Thresholds from validation distances (known queries vs. the gallery, their true
    entries, and non-enrolled queries vs. the gallery).

    Rule: ``max_distance`` = 99.5th percentile of the best distance of correctly identified
    known queries. ``min_margin`` = just above the largest margin of every validation answer
    that passes ``max_distance`` and is wrong: a known query matched to another entry, or a
    non-enrolled query (its best and runner-up are both impostors, so its lead is small);
    capped at the 1st percentile of the correct answers' margins, so that the margin turns
    at most about 1 % of the right answers into "unknown".
    """
    best, d1, margin = best_and_margin(known)
    ok = best == truth
    max_d = float(np.percentile(d1[ok], 99.5)) if ok.any() else float("inf")
    wrong = margin[(~ok) & (d1 <= max_d)]
    if len(unknown):
        _, u1, um = best_and_margin(unknown)
        wrong = np.concatenate([wrong, um[u1 <= max_d]])
    min_m = float(wrong.max() + 1e-4) if len(wrong) else 0.0
    if ok.sum() >= 20:
        min_m = min(min_m, float(np.percentile(margin[ok], 1.0)))
    th = Thresholds(round(max_d, 4), round(min_m, 4))
    return th, decision_report(th, known, truth, unknown)


def decision_report(
    th: Thresholds, known: np.ndarray, truth: np.ndarray, unknown: np.ndarray
) -> dict:
    """Accept/unknown outcome of the thresholds on known and non-enrolled queries."""
    best, d1, margin = best_and_margin(known)
    accept = (d1 <= th.max_distance) & (margin >= th.min_margin)
    ok = best == truth
    _, u1, um = best_and_margin(unknown) if len(unknown) else (None, np.zeros(0), np.zeros(0))
    u_accept = (u1 <= th.max_distance) & (um >= th.min_margin)
    return {
        "known_queries": int(len(known)),
        "known_correct_accepted": int((accept & ok).sum()),
        "known_wrong_accepted": int((accept & ~ok).sum()),
        "known_unknown_rate": float(np.mean(~accept)),
        "unknown_queries": int(len(unknown)),
        "unknown_accepted": int(u_accept.sum()),
        "unknown_unknown_rate": float(np.mean(~u_accept)) if len(unknown) else float("nan"),
        "genuine_distance_p50": float(np.median(d1[ok])) if ok.any() else float("nan"),
        "impostor_distance_p50": float(np.median(u1)) if len(u1) else float("nan"),
    }


def pixel_features(crops: list[np.ndarray], size_wh: tuple[int, int] = (28, 16)) -> np.ndarray:
    """Raw-pixel baseline: colour crop resized to 28 x 16, zero-mean, unit-norm."""
    f = np.stack([resize_crop(c, size_wh[::-1]).astype(np.float32).ravel() for c in crops])
    f -= f.mean(1, keepdims=True)
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-6)


def histogram_features(crops: list[np.ndarray]) -> np.ndarray:
    """Colour-histogram baseline: HSV 8 x 6 x 6 histogram, square-rooted (Hellinger), unit-norm."""
    out = []
    for c in crops:
        hsv = cv2.cvtColor(c, cv2.COLOR_BGR2HSV)
        h = cv2.calcHist([hsv], [0, 1, 2], None, [8, 6, 6], [0, 180, 0, 256, 0, 256]).ravel()
        h = np.sqrt(h / max(h.sum(), 1.0))
        out.append(h / max(np.linalg.norm(h), 1e-6))
    return np.stack(out).astype(np.float32)


def baselines(gallery: list, queries: list, k_gallery: int = 0, k_query: int = 1) -> dict:
    """Rank-1/5/mAP of the raw-pixel and colour-histogram nearest neighbours (same rule:
    mean of the three block distances) on crops ``[identity][block][k]``."""
    out = {}
    truth = np.arange(len(queries))
    for name, fn in (("raw_pixels", pixel_features), ("hsv_histogram", histogram_features)):

        def feats(data: list, k: int, fn: Callable = fn) -> np.ndarray:
            flat = [ident[b][min(k, len(ident[b]) - 1)] for ident in data for b in range(BLOCKS)]
            return fn(flat).reshape(len(data), BLOCKS, -1)

        dist = mean_block_distances(feats(queries, k_query), feats(gallery, k_gallery))
        out[name] = rank_metrics(dist, truth)
    return out


def evaluate(emb: BlockEmbedder, args: argparse.Namespace, log: Log) -> dict:
    """Test-split figures: rank-1/5/mAP, baselines, the thresholds' unknown rates."""
    names = split_names("te", args.test_pallets)
    unk = split_names("tu", args.unknown_pallets)
    log(f"rendering {len(names)} test identities (gallery + query) and {len(unk)} unknown ones")
    data = render_crops(names, 2, args.seed + 1000, args.jobs, log)
    udata = render_crops(unk, 1, args.seed + 2000, args.jobs, log)
    t0 = time.perf_counter()
    g, q, u = embed_with(emb, data, 0), embed_with(emb, data, 1), embed_with(emb, udata, 0)
    embed_s = time.perf_counter() - t0
    dist = mean_block_distances(q, g)
    truth = np.arange(len(names))
    report = {"model_version": emb.model_version, "embedder": rank_metrics(dist, truth)}
    report["embed_ms_per_crop"] = round(embed_s * 1000 / (3 * (2 * len(data) + len(udata))), 2)
    report["baselines"] = baselines(data, data, 0, 1)
    report["thresholds"] = {
        "max_distance": emb.thresholds.max_distance,
        "min_margin": emb.thresholds.min_margin,
    }
    report["decisions"] = decision_report(emb.thresholds, dist, truth, mean_block_distances(u, g))
    return report


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


def validate(
    emb: BlockEmbedder, pallets: int, unknown_pallets: int, seed: int, jobs: int, log: Log
) -> tuple[Thresholds, dict]:
    """Calibrate the "unknown" thresholds on the validation split (``va``: enrolled,
    ``vu``: not enrolled; never trained on, never tested on); thresholds and figures."""
    vnames = split_names("va", pallets)
    vunk = split_names("vu", unknown_pallets)
    log(f"calibrating on {len(vnames)} validation identities + {len(vunk)} non-enrolled")
    vdata = render_crops(vnames, 2, seed + 500, jobs, log)
    udata = render_crops(vunk, 1, seed + 600, jobs, log)
    g, q = embed_with(emb, vdata, 0), embed_with(emb, vdata, 1)
    u = embed_with(emb, udata, 0)
    dist = mean_block_distances(q, g)
    truth = np.arange(len(vnames))
    th, dec = calibrate(dist, truth, mean_block_distances(u, g))
    return th, {"validation": rank_metrics(dist, truth), "validation_decisions": dec}


def cmd_train(args: argparse.Namespace, log: Log) -> int:
    """Train, calibrate the thresholds on the validation split, save the checkpoint."""
    t0 = time.perf_counter()
    cfg = SMOKE if args.smoke else TrainConfig(pallets=args.pallets, steps=args.steps)
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
