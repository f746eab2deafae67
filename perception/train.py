"""One entry point for training and evaluating btrun's two perception models.

::

    python -m perception.train detector train --out perception/weights/detector.pt --seed 0
    python -m perception.train detector evaluate --weights perception/weights/detector.pt
    python -m perception.train embedder train --out perception/weights/pcb_small.pt --seed 0
    python -m perception.train embedder eval --weights perception/weights/pcb_small.pt

Everything after the model name goes to :mod:`perception.train_detector` or
:mod:`perception.train_embedder` unchanged (``--help`` there lists the options). Both train
from scratch on synthetic renders with a fixed seed, on the CPU, in under about an hour each;
``--smoke`` runs a few steps in seconds.
"""

from __future__ import annotations

import sys

MODELS = {
    "detector": "perception.train_detector",
    "embedder": "perception.train_embedder",
}


def main(argv: list[str] | None = None) -> int:
    """Dispatch ``detector ...`` / ``embedder ...`` to the model's own command line."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    if not args or args[0] not in MODELS:
        got = f"unknown model {args[0]!r}" if args else "no model given"
        print(f"error: {got} (expected: {', '.join(MODELS)})\n\n{__doc__.strip()}", file=sys.stderr)
        return 2
    import importlib

    module = importlib.import_module(MODELS[args[0]])
    return int(module.main(args[1:]) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
