"""One ``btrun run`` inside this process, quietly, and its ``summary.json`` (bench helper)."""

from __future__ import annotations

import json
import os
import sys
import tempfile


def run_summary(argv: list[str]) -> dict:
    """Run ``btrun`` with ``argv`` (``run MISSION ...``; ``--out`` is added: a temporary
    run folder), its standard output silenced; return the run's summary.json."""
    from bt_engine.cli import main

    with tempfile.TemporaryDirectory() as out:
        with open(os.devnull, "w") as devnull:
            stdout, sys.stdout = sys.stdout, devnull
            try:
                main([*argv, "--out", out])
            finally:
                sys.stdout = stdout
        with open(os.path.join(out, "summary.json")) as f:
            return json.load(f)
