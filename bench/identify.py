"""Identification latency: embed three block crops, match them against a 10,000-entry gallery.

The mission identifies a pallet side from three block crops: the PCB embedder turns them into
three vectors (:class:`perception.embedder.BlockEmbedder`), then the gallery returns the entry
with the smallest mean of the three block distances (:meth:`perception.gallery.Gallery.match`).
This times both on a temporary SQLite gallery of ``--entries`` random unit vectors (matching
cost does not depend on the values) and prints p50/p95 over ``--repeats`` runs:

* ``embed 3 crops``: the shipped weights on three synthetic block crops (about 60 x 35 px);
* ``match (Gallery.match)``: the gallery's matching (matrix cached after the first call);
* ``match baseline (numpy loop)``: a brute-force per-entry Python loop, the naive way;
* ``identify (embed + match)``: what one identification costs the mission. Target < 100 ms;
* ``match + texture verification``: :meth:`Gallery.match` with the query's crops, on a
  gallery of ``--texture-sides`` sides stored with crops (the verifier's cost does not grow
  with the gallery: 8 candidates and at most 64 of its sides plus the shipped cohort).

    .venv/bin/python bench/identify.py [--entries 10000] [--repeats 50] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np
import torch

from perception.embedder import BlockEmbedder
from perception.gallery import Gallery
from perception.gallery_views import png_bytes
from perception.synth.dataset import block_crops


def timed(fn: Callable[[], object], repeats: int) -> list[float]:
    """Wall times (ms) of ``repeats`` calls after one warm-up call."""
    fn()
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1000.0)
    return out


def row(name: str, ms: list[float]) -> str:
    """One result line: p50, p95, mean."""
    p95 = sorted(ms)[max(0, int(round(0.95 * len(ms))) - 1)]
    return f"{name:32s} p50 {statistics.median(ms):8.2f} ms  p95 {p95:8.2f} ms  n={len(ms)}"


def fill_gallery(path: str, version: str, dim: int, entries: int, seed: int) -> Gallery:
    """A gallery file of ``entries`` random unit-norm block embeddings, one transaction."""
    g = Gallery.create(path, version, dim)
    rng = np.random.default_rng(seed)
    with g.conn:
        for i in range(entries):
            e = rng.standard_normal((3, dim)).astype(np.float32)
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            g.conn.execute(
                "INSERT INTO entries VALUES (?, ?, ?, ?)", (f"r{i:05d}", e.tobytes(), 0.0, "")
            )
    g._cache = None
    return g


def loop_match(g: Gallery, q: np.ndarray) -> str:
    """Naive baseline: one numpy distance computation per entry, in a Python loop."""
    ids, mat = g.matrix()
    best, best_d = "", float("inf")
    for i, e in enumerate(mat):
        d = float(np.linalg.norm(e - q, axis=1).mean())
        if d < best_d:
            best, best_d = ids[i], d
    return best


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--entries", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--texture-sides", type=int, default=100)
    args = ap.parse_args(argv)
    emb = BlockEmbedder.load(args.weights, threads=args.threads)
    rng = np.random.default_rng(0)
    crops = [block_crops("bench7A", None, b, rng, 1)[0] for b in range(3)]
    print(
        f"{emb.model_version}, dim {emb.dim}, torch threads {torch.get_num_threads()}, "
        f"crops {[c.shape[:2] for c in crops]}, gallery {args.entries} entries, load "
        f"{os.getloadavg()[0]:.2f}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        g = fill_gallery(os.path.join(tmp, "g.sqlite"), emb.model_version, emb.dim, args.entries, 1)
        print(f"gallery filled in {time.perf_counter() - t:.1f} s")
        q = emb.embed(crops)
        t = time.perf_counter()
        g.match(q)
        print(f"first match (reads the SQLite file) {1000 * (time.perf_counter() - t):.0f} ms")
        r_embed = timed(lambda: emb.embed(crops), args.repeats)
        r_match = timed(lambda: g.match(q), args.repeats)
        r_loop = timed(lambda: loop_match(g, q), max(3, args.repeats // 10))
        r_all = timed(lambda: g.match(emb.embed(crops)), args.repeats)
        assert loop_match(g, q) == g.match(q).best_id
        g.close()
        tg = Gallery.create(":memory:", emb.model_version, emb.dim)
        pngs = [png_bytes(c) for c in crops]
        for i in range(args.texture_sides):
            e = rng.standard_normal((3, emb.dim)).astype(np.float32)
            tg.enrol(f"t{i:04d}", e / np.linalg.norm(e, axis=1, keepdims=True), pngs)
        tg.match(q, crops=crops)  # decodes the gallery's crops once (cached)
        r_tex = timed(lambda: tg.match(q, crops=crops), max(5, args.repeats // 5))
    print(row("embed 3 crops", r_embed))
    print(row("match (Gallery.match)", r_match))
    print(row("match baseline (numpy loop)", r_loop))
    print(row("identify (embed + match)", r_all))
    print(row(f"match + texture ({args.texture_sides} sides)", r_tex))
    ok = statistics.median(r_all) < 100.0
    print(f"target p50 < 100 ms: {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
