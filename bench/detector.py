"""Block detector speed: frames/s and latency of ``BlockDetector.detect`` on AI-deck frames.

Times the shipped weights (or ``--weights``) on ``--frames`` white-balanced synthetic
324 x 244 frames, batch 1, with 1 and 2 torch threads (``--threads``), and prints frames/s,
p50 and p95 latency per frame; then one line for ``detect_batch`` of 8 frames. The target
is >= 100 frames/s at batch 1 on one core. Everything counts: resize, standardisation,
network, decoding, NMS.

    .venv/bin/python bench/detector.py [--repeats 300] [--threads 1 2] [--weights PATH]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np
import torch

from perception.detector import BlockDetector
from perception.synth.dataset import _wb_factors, identity_names, render_detection_sample
from perception.synth.render import SensorModel
from perception.white_balance import preprocess


def sample_frames(n: int, seed: int = 7) -> list[np.ndarray]:
    """``n`` white-balanced synthetic frames (BGR uint8, 244 x 324)."""
    rng = np.random.default_rng(seed)
    factors = _wb_factors(SensorModel())
    names = identity_names(max(1, n // 4), "bench")
    return [preprocess(render_detection_sample(rng, [names[i // 4]])[0], factors) for i in range(n)]


def latencies(fn, frames: list[np.ndarray], repeats: int) -> list[float]:
    """Wall time (ms) of ``repeats`` calls, cycling through ``frames``, after 10 warm-ups."""
    for f in frames[:10]:
        fn(f)
    out = []
    for i in range(repeats):
        f = frames[i % len(frames)]
        t = time.perf_counter()
        fn(f)
        out.append((time.perf_counter() - t) * 1000.0)
    return out


def row(name: str, ms: list[float], per: int = 1) -> str:
    """One result line: frames/s (from the mean), p50, p95."""
    p95 = sorted(ms)[max(0, int(round(0.95 * len(ms))) - 1)]
    fps = 1000.0 * per / statistics.fmean(ms)
    return (
        f"{name:28s} {fps:7.1f} frames/s  p50 {statistics.median(ms):6.2f} ms  "
        f"p95 {p95:6.2f} ms  n={len(ms)}"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=300)
    ap.add_argument("--frames", type=int, default=16, help="distinct frames to cycle through")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--weights", default=None)
    args = ap.parse_args(argv)
    det = BlockDetector.load(args.weights)
    frames = sample_frames(args.frames)
    n_params = sum(p.numel() for p in det.model.parameters())
    print(
        f"{det.model_version}, {n_params} parameters, input {det.config.input_hw}, "
        f"frames {frames[0].shape}, cpus {os.cpu_count()}, load {os.getloadavg()[0]:.2f}"
    )
    blocks = [len(det.detect(f)) for f in frames]
    print(f"blocks found per frame: {blocks}")
    for threads in args.threads:
        torch.set_num_threads(threads)
        ms = latencies(det.detect, frames, args.repeats)
        print(row(f"detect, batch 1, {threads} thread(s)", ms))
    torch.set_num_threads(args.threads[0])
    batches = [frames[i : i + 8] for i in range(0, len(frames) - 7, 8)] or [frames]
    ms = latencies(det.detect_batch, batches, max(10, args.repeats // 8))
    print(row(f"detect_batch of 8, {args.threads[0]} thread(s)", ms, per=len(batches[0])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
