"""Evaluation and threshold calibration of the PCB embedder on rendered splits; baselines.

Distances follow the gallery's rule (:mod:`perception.gallery_math`): per block the stripe
distance weighted by the stripes' visibility in both crops, per side the mean of the three
blocks (each weighted by its query stripes' visibility).

Calibration (:func:`calibrate`) picks the "unknown" thresholds on a validation split that
is neither trained nor tested on: enrolled sides queried under varied conditions (far,
turned, noisy, compressed, aged, occluded) and sides that were never enrolled. Rule: for
each candidate ``max_distance`` (quantiles of the right answers' distances), the margin
must exceed, with a cushion, the largest margin of every answer that would be wrong (an
enrolled side matched to another, or a non-enrolled side) and whose distance passes
``max_distance`` with a cushion; the pair answering the most enrolled queries right wins.
So on validation no wrong answer and no non-enrolled side is accepted, with room to spare.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from perception.embedder import BlockEmbedder, resize_crop
from perception.embedder_data import BLOCKS, age_crop, render_crops, split_names
from perception.gallery import Thresholds
from perception.gallery_math import MIN_BLOCK_WEIGHT, MIN_STRIPE_WEIGHT

Log = Callable[[str], None]

#: cushions of the calibration: impostors are looked for up to max_distance x (1 + this) ...
DISTANCE_CUSHION = 0.08
#: ... and the margin must beat their largest margin x (1 + this) + MARGIN_FLOOR
MARGIN_CUSHION = 0.25
MARGIN_FLOOR = 0.01


@dataclass
class Described:
    """Embeddings (n, 3, dim) and stripe visibilities (n, 3, parts) of n sides."""

    vectors: np.ndarray
    visibility: np.ndarray


def describe_sides(emb: BlockEmbedder, data: list, k: int) -> Described:
    """Embeddings and visibilities of crop ``k`` of every block of every side, batched."""
    flat = [ident[b][min(k, len(ident[b]) - 1)] for ident in data for b in range(BLOCKS)]
    vecs, viss = [], []
    for i in range(0, len(flat), 192):
        d = emb.describe(flat[i : i + 192])
        vecs.append(d.vectors)
        viss.append(d.visibility)
    n = len(data)
    return Described(
        np.concatenate(vecs).reshape(n, BLOCKS, -1), np.concatenate(viss).reshape(n, BLOCKS, -1)
    )


def embed_with(emb: BlockEmbedder, data: list[list[list[np.ndarray]]], k: int) -> np.ndarray:
    """Embeddings (identities, 3, dim) of crop ``k`` of every block, batched."""
    return describe_sides(emb, data, k).vectors


def side_distances(q: Described, g: Described) -> np.ndarray:
    """(Q, G) side distances with stripe visibilities (the gallery's rule)."""
    parts = q.visibility.shape[-1]
    total = np.zeros((len(q.vectors), len(g.vectors)))
    bw = np.maximum(q.visibility.mean(-1), MIN_BLOCK_WEIGHT)  # (Q, 3)
    for b in range(BLOCKS):
        qs = q.vectors[:, b].reshape(len(q.vectors), parts, -1).astype(np.float64)
        gs = g.vectors[:, b].reshape(len(g.vectors), parts, -1).astype(np.float64)
        qs /= np.maximum(np.linalg.norm(qs, axis=-1, keepdims=True), 1e-12)
        gs /= np.maximum(np.linalg.norm(gs, axis=-1, keepdims=True), 1e-12)
        num = np.zeros_like(total)
        den = np.zeros_like(total)
        for p in range(parts):
            cos = qs[:, p] @ gs[:, p].T
            w = np.maximum(
                q.visibility[:, b, p][:, None] * g.visibility[:, b, p][None, :], MIN_STRIPE_WEIGHT
            )
            num += w * (2.0 - 2.0 * cos)
            den += w
        total += bw[:, b][:, None] * np.sqrt(np.maximum(num / den, 0.0))
    return total / bw.sum(1)[:, None]


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


def safe_margin(known: np.ndarray, truth: np.ndarray, unknown: np.ndarray, max_d: float) -> float:
    """The smallest margin that rejects, with the cushions, every would-be wrong answer
    (enrolled matched to another side, or non-enrolled) passing ``max_distance``."""
    best, d1, margin = best_and_margin(known)
    reach = max_d * (1.0 + DISTANCE_CUSHION)
    wrong = margin[(best != truth) & (d1 <= reach)]
    if len(unknown):
        _, u1, um = best_and_margin(unknown)
        wrong = np.concatenate([wrong, um[u1 <= reach]])
    top = float(wrong.max()) if len(wrong) else 0.0
    return top * (1.0 + MARGIN_CUSHION) + MARGIN_FLOOR


def calibrate(known: np.ndarray, truth: np.ndarray, unknown: np.ndarray) -> tuple[Thresholds, dict]:
    """Thresholds from validation distances (known queries vs. the gallery, their true
    entries, and non-enrolled queries vs. the gallery): see the module doc."""
    best, d1, margin = best_and_margin(known)
    ok = best == truth
    if not ok.any():
        th = Thresholds(0.0, 1.0)
        return th, decision_report(th, known, truth, unknown)
    candidates = np.unique(np.quantile(d1[ok], np.linspace(0.5, 1.0, 51)))
    best_th, best_right = Thresholds(float(candidates[0]), 1.0), -1
    for max_d in candidates:
        min_m = safe_margin(known, truth, unknown, float(max_d))
        right = int((ok & (d1 <= max_d) & (margin >= min_m)).sum())
        if right > best_right:
            best_th, best_right = Thresholds(float(max_d), min_m), right
    th = Thresholds(round(best_th.max_distance, 4), round(best_th.min_margin + 5e-5, 4))
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


def aged_copy(data: list, seed: int, strength: float = 0.8) -> list:
    """The same crops, each aged at random (stains, dust, occluders, ...), deterministic."""
    rng = np.random.default_rng(seed)
    return [[[age_crop(c, rng, strength)[0] for c in block] for block in ident] for ident in data]


def condition_split(
    kind: str, unknown_kind: str, pallets: int, unknown_pallets: int, seed: int, jobs: int, log: Log
) -> tuple[list, list, list]:
    """Enrolment crops (clean, 0.4 m), queries (varied; half of them aged) of ``pallets``
    pallets of split ``kind``, and queries of ``unknown_pallets`` never-enrolled pallets."""
    names, unk = split_names(kind, pallets), split_names(unknown_kind, unknown_pallets)
    log(
        f"rendering {len(names)} {kind} identities (enrolment + queries) and {len(unk)} {unknown_kind}"
    )
    gallery = render_crops(names, 1, seed, jobs, log, mode="enrol")
    queries = render_crops(names, 2, seed + 1, jobs, log, mode="varied")
    others = render_crops(unk, 2, seed + 2, jobs, log, mode="varied")
    aged, aged_others = aged_copy(queries, seed + 3), aged_copy(others, seed + 4)
    q = [
        [[block[0], aged_block[1]] for block, aged_block in zip(i, a, strict=True)]
        for i, a in zip(queries, aged, strict=True)
    ]
    u = [
        [[block[0], aged_block[1]] for block, aged_block in zip(i, a, strict=True)]
        for i, a in zip(others, aged_others, strict=True)
    ]
    return gallery, q, u


def distances(
    emb: BlockEmbedder, gallery: list, queries: list, unknown: list
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Known query distances (2Q, G), their true entries, non-enrolled distances (2U, G)."""
    g = describe_sides(emb, gallery, 0)
    qs = [describe_sides(emb, queries, k) for k in (0, 1)]
    us = [describe_sides(emb, unknown, k) for k in (0, 1)]
    known = np.concatenate([side_distances(q, g) for q in qs])
    truth = np.concatenate([np.arange(len(gallery))] * 2)
    unk = np.concatenate([side_distances(u, g) for u in us])
    return known, truth, unk


def validate(
    emb: BlockEmbedder, pallets: int, unknown_pallets: int, seed: int, jobs: int, log: Log
) -> tuple[Thresholds, dict]:
    """Calibrate the "unknown" thresholds on the validation split (``va``: enrolled,
    ``vu``: never enrolled; neither trained nor tested on); thresholds and figures."""
    g, q, u = condition_split("va", "vu", pallets, unknown_pallets, seed + 500, jobs, log)
    known, truth, unk = distances(emb, g, q, u)
    th, dec = calibrate(known, truth, unk)
    return th, {"validation": rank_metrics(known, truth), "validation_decisions": dec}


def evaluate(emb: BlockEmbedder, args: argparse.Namespace, log: Log) -> dict:
    """Test-split figures: rank-1/5/mAP (clean and varied), baselines, the thresholds'
    decisions on enrolled and never-enrolled sides."""
    names = split_names("te", args.test_pallets)
    log(f"rendering {len(names)} test identities (two clean renders each)")
    data = render_crops(names, 2, args.seed + 1000, args.jobs, log)
    t0 = time.perf_counter()
    g, q = describe_sides(emb, data, 0), describe_sides(emb, data, 1)
    embed_s = time.perf_counter() - t0
    truth = np.arange(len(names))
    report = {
        "model_version": emb.model_version,
        "embedder": rank_metrics(side_distances(q, g), truth),
    }
    report["embed_ms_per_crop"] = round(embed_s * 1000 / (3 * 2 * len(data)), 2)
    report["baselines"] = baselines(data, data, 0, 1)
    report["thresholds"] = {
        "max_distance": emb.thresholds.max_distance,
        "min_margin": emb.thresholds.min_margin,
    }
    gv, qv, uv = condition_split(
        "te", "tu", args.test_pallets, args.unknown_pallets, args.seed + 2000, args.jobs, log
    )
    known, truth2, unk = distances(emb, gv, qv, uv)
    report["varied"] = rank_metrics(known, truth2)
    report["decisions"] = decision_report(emb.thresholds, known, truth2, unk)
    return report


__all__ = [
    "Described",
    "baselines",
    "best_and_margin",
    "calibrate",
    "condition_split",
    "decision_report",
    "describe_sides",
    "distances",
    "embed_with",
    "evaluate",
    "histogram_features",
    "mean_block_distances",
    "pixel_features",
    "rank_metrics",
    "safe_margin",
    "side_distances",
    "validate",
]
