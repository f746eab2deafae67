"""CPU per side of a demo gallery build, by stage, before and after the faster synthesis.

``btrun gallery stats demo --rig rigs/aisle.yaml --set world.pallet_pool.count=2002``
builds a 4,000-side gallery in two worker processes, each enrolling one side at a time
(:func:`nodes.gallery.demo._enrol_side`: the side's canonical scene, the frames the block
sequencer needs, detection, embedding). This bench enrols ``--sides`` sides of that pool
the same way in one process, twice: with the texture synthesis and caches as they were
before they were made faster (``bench/relief_reference.py``: the baseline, in the same
run) and as shipped, alternating in blocks of sides so that both see the same load on a
shared machine. It prints CPU milliseconds per side by stage and checks that both give
the same frames (every rendered frame's hash), crops and embeddings, bit for bit::

    .venv/bin/python bench/gallery_build_speed.py            # 20 sides, blocks of 5
    .venv/bin/python bench/gallery_build_speed.py --sides 40 --block 10

Stages: ``long-face texture`` is the relief-lit texture of the scanned face
(:func:`perception.synth.relief.lit_face`: colour texture, height and normal maps,
shading); ``render`` the frames without it (other textures as first seen, projection,
sensor); ``detect`` the detector on the chosen frames; ``ground truth`` the block boxes
that choose them; ``scene`` the side's scene; ``embed + PNG`` the crops' embeddings and
PNGs; ``other`` the rest (sequencer, world data).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from typing import Any

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np

STAGES = ("long-face texture", "render", "detect", "ground truth", "scene", "embed + PNG")


class StageClock:
    """CPU time per stage; a stage's time excludes the stages timed inside it."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._stack: list[list[float]] = []  # [start, time of timed callees]

    def wrap(self, stage: str, f: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            self._stack.append([time.process_time(), 0.0])
            try:
                return f(*args, **kwargs)
            finally:
                start, inner = self._stack.pop()
                spent = time.process_time() - start
                self.seconds[stage] += spent - inner
                if self._stack:
                    self._stack[-1][1] += spent

        return timed


@contextmanager
def timed_stages(clock: StageClock, detector: Any, embedder: Any) -> Iterator[list[str]]:
    """Time the stages (wrapping the functions they call) and hash every rendered frame."""
    import perception.gallery_views as views
    from drivers.sim.renderers.pallet import PalletRenderer
    from perception.synth import relief

    frames: list[str] = []
    call = PalletRenderer.__call__

    def render(self: Any, *args: Any, **kwargs: Any) -> np.ndarray:
        raw = call(self, *args, **kwargs)
        frames.append(hashlib.sha1(np.ascontiguousarray(raw).tobytes()).hexdigest())
        return raw

    patches = [
        (relief, "lit_face", clock.wrap("long-face texture", relief.lit_face)),
        (PalletRenderer, "__call__", clock.wrap("render", render)),
        (PalletRenderer, "ground_truth", clock.wrap("ground truth", PalletRenderer.ground_truth)),
        (PalletRenderer, "__init__", clock.wrap("scene", PalletRenderer.__init__)),
        (detector, "detect", clock.wrap("detect", detector.detect)),
        (embedder, "describe", clock.wrap("embed + PNG", embedder.describe)),
        (views, "png_bytes", clock.wrap("embed + PNG", views.png_bytes)),
    ]
    saved = [(obj, name, obj.__dict__.get(name)) for obj, name, _ in patches]
    for obj, name, f in patches:
        setattr(obj, name, f)
    try:
        yield frames
    finally:
        for obj, name, f in saved:
            if f is None:
                delattr(obj, name)
            else:
                setattr(obj, name, f)


def main(argv: list[str] | None = None) -> int:
    """Enrol the sides both ways, print the table, exit 1 if the outputs differ."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", default="rigs/aisle.yaml")
    ap.add_argument("--pool", type=int, default=2002, help="world.pallet_pool.count")
    ap.add_argument("--sides", type=int, default=20, help="sides enrolled each way")
    ap.add_argument("--block", type=int, default=5, help="sides per turn of each way")
    ap.add_argument("--first", type=int, default=100, help="index of the first side")
    args = ap.parse_args(argv)

    import relief_reference

    from drivers.rig.loader import load_rig
    from drivers.sim.renderers import pallet
    from drivers.sim.world import load_world
    from nodes.gallery import demo
    from nodes.gallery.enrol_scan import look_overrides
    from nodes.perception_session import PerceptionSession
    from perception.detector import BlockDetector
    from perception.embedder import BlockEmbedder

    rig = load_rig(args.rig, {"world.pallet_pool.count": str(args.pool)})
    session = PerceptionSession(rig)
    world_path = session.world_path()
    overrides = getattr(rig, "world_overrides", None)
    identities = load_world(world_path, look_overrides(overrides)).enrolled_identities()
    jobs = list(enumerate(identities))[args.first : args.first + args.sides]
    # as a build worker: the shipped weights, one torch thread
    detector, embedder = BlockDetector.load(None, threads=1), BlockEmbedder.load(None, threads=1)
    demo._init_worker(world_path, overrides, session.camera, (detector, embedder))

    ways = {"before": relief_reference.reference, "after": nullcontext}
    clocks = {w: StageClock() for w in ways}
    total = dict.fromkeys(ways, 0.0)
    wall = dict.fromkeys(ways, 0.0)
    outputs: dict[str, list] = {w: [] for w in ways}
    frames: dict[str, list[str]] = {w: [] for w in ways}
    for context in ways.values():  # warm-up (imports, the models' first run): untimed
        pallet._SCENES.clear()
        with context():
            demo._enrol_side(jobs[0])
    for b0 in range(0, len(jobs), args.block):
        block = jobs[b0 : b0 + args.block]
        for way, context in ways.items():
            pallet._SCENES.clear()  # no scene (with its textures) made by the other way
            with context(), timed_stages(clocks[way], demo._WORKER["detector"], embedder) as fr:
                w0, c0 = time.perf_counter(), time.process_time()
                outputs[way] += [demo._enrol_side(job) for job in block]
                total[way] += time.process_time() - c0
                wall[way] += time.perf_counter() - w0
            frames[way] += fr
        print(f"  {b0 + len(block)}/{len(jobs)} sides each way", file=sys.stderr)

    n = len(jobs)
    print(f"{n} sides of {os.path.basename(world_path)} (pool {args.pool}), CPU ms per side")
    print(f"{'stage':<20}{'before':>10}{'after':>10}")
    for stage in STAGES:
        row = [1000 * clocks[w].seconds.get(stage, 0.0) / n for w in ways]
        print(f"{stage:<20}{row[0]:>10.1f}{row[1]:>10.1f}")
    other = [1000 * (total[w] - sum(clocks[w].seconds.values())) / n for w in ways]
    print(f"{'other':<20}{other[0]:>10.1f}{other[1]:>10.1f}")
    print(f"{'total CPU':<20}{1000 * total['before'] / n:>10.1f}{1000 * total['after'] / n:>10.1f}")
    print(f"{'(wall)':<20}{1000 * wall['before'] / n:>10.1f}{1000 * wall['after'] / n:>10.1f}")

    same_frames = frames["before"] == frames["after"]
    same = all(_same_side(a, b) for a, b in zip(outputs["before"], outputs["after"], strict=True))
    print(
        f"frames rendered: {len(frames['before'])} before, {len(frames['after'])} after, "
        f"{'identical' if same_frames else 'DIFFERENT'}; crops and embeddings "
        f"{'identical' if same else 'DIFFERENT'}"
    )
    return 0 if same and same_frames else 1


def _same_side(a: tuple, b: tuple) -> bool:
    """The same enrolment: identity, blocks found, embeddings, visibilities, PNG crops."""
    if a[:2] != b[:2] or a[4] != b[4]:
        return False
    return all(
        (x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y))
        for x, y in ((a[2], b[2]), (a[3], b[3]))
    )


if __name__ == "__main__":
    sys.exit(main())
