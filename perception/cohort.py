"""The texture verifier's shipped cohort: block crops of synthetic pallets no gallery holds.

:mod:`perception.verify` scales a query block's correlation scores by its scores against
other pallets' blocks. A gallery of a few sides has too few others, so the verifier tops
them up with this cohort: clean views at the scan stand-off (0.4 m) of sides with varied
looks (every wood tone, paints, other face generators and markings), cut by the shipped
detector as in a mission, stored grey (about 0.2 MB).

    python -m perception.cohort --out perception/weights/cohort.npz --sides 48

Identities ``co*`` and texture seeds from 20,000 are used nowhere else (training uses
``tr*``, the robustness bench ``rb*`` from 9,000).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from perception.robustness import Pipeline
from perception.synth.appearance import SideStyle
from perception.synth.dataset import identity_names
from perception.synth.views import ViewConditions
from perception.verify import COHORT_PATH, save_cohort

PREFIX, SEED0 = "co", 20_000
#: looks cycled over the cohort's sides (SideStyle keywords)
LOOKS: tuple[dict, ...] = (
    {},
    {"wood": "grey"},
    {"wood": "yellowed"},
    {"wood": "dark"},
    {"paint": "blue"},
    {"wood": "pale", "marking": "stencil"},
    {"generator": "plank"},
    {"wood": "brown", "marking": "label"},
    {"paint": "red"},
    {"wood": "silver"},
    {"wood": "wet"},
    {"paint": "white"},
)


def build_cohort(pipe: Pipeline, sides: int, seed: int = 0) -> list[list[np.ndarray]]:
    """Crops (three per side) of ``sides`` cohort sides whose three blocks were all found."""
    rng = np.random.default_rng([seed, 11])
    out: list[list[np.ndarray]] = []
    names = identity_names(4 * sides, PREFIX)
    for i, name in enumerate(names):
        if len(out) == sides:
            break
        style = SideStyle(texture_seed=SEED0 + i, **LOOKS[i % len(LOOKS)])
        scan = pipe.scan(name, style, rng, view=ViewConditions(), jitter=False)
        if scan.complete:
            out.append([c for c in scan.crops if c is not None])
    if len(out) < sides:
        raise RuntimeError(f"only {len(out)} of {sides} cohort sides had three blocks found")
    return out


def main(argv: list[str] | None = None) -> int:
    """Build and write the cohort file."""
    ap = argparse.ArgumentParser(prog="python -m perception.cohort", description=__doc__)
    ap.add_argument("--out", default=COHORT_PATH)
    ap.add_argument("--sides", type=int, default=48)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--detector", default=None, help="detector weights (default: shipped)")
    args = ap.parse_args(argv)
    from perception.detector import BlockDetector

    t0 = time.perf_counter()
    pipe = Pipeline(BlockDetector.load(args.detector), None)
    sides = build_cohort(pipe, args.sides, args.seed)
    save_cohort(args.out, sides)
    print(f"{len(sides)} cohort sides written to {args.out} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
