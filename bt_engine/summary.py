"""``summary.json``: how a run ended, built in one place.

:func:`build_summary` makes the dict that ``btrun`` writes (and tests and benches compare):
the engine's own keys (``status``, ``reason``, ``ticks``, ``mission_time_s``,
``wall_time_s``, ``mission``, ``seed``, ``rate_hz``, ``blackboard``), then the run target's
sections (``sim`` or ``vehicle``, ``safety``) and one section per mission resource that
reports on the run (:class:`~bt_engine.plugins.RunReporter`, e.g. ``perception``).
:func:`write_summary` writes it atomically.
"""

from __future__ import annotations

import json
import os
from typing import Any

from bt_engine.files import atomic_write_text
from bt_engine.mission import Mission
from bt_engine.plugins import RunReporter
from bt_engine.runner import RunResult
from bt_engine.ticklog import to_jsonable


def build_summary(
    result: RunResult,
    mission: Mission,
    *,
    mission_path: str,
    seed: int,
    rate_hz: float,
    sections: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``summary.json`` dict of a finished run.

    ``sections`` are the run target's parts (``{"sim": ..., "safety": ...}``); resources of
    the mission that implement :class:`RunReporter` add theirs under their resource names
    (never replacing a section already there).
    """
    summary: dict[str, Any] = {
        "status": result.status,
        "reason": result.reason,
        "ticks": result.ticks,
        "mission_time_s": round(result.mission_time_s, 4),
        "wall_time_s": round(result.wall_time_s, 4),
        "mission": os.path.abspath(mission_path),
        "seed": seed,
        "rate_hz": rate_hz,
        "blackboard": to_jsonable(mission.scope.all_items()),
    }
    if mission.leaf_failures:  # also those the tree handled (a Fallback, a retry)
        summary["leaf_failures"] = [
            {"failure": text, "times": n} for text, n in mission.leaf_failures.items()
        ]
    for key, value in (sections or {}).items():
        summary[key] = to_jsonable(value)
    for name, res in mission.ctx.resources.items():
        if name not in summary and isinstance(res, RunReporter):
            summary[name] = to_jsonable(res.run_summary())
    return summary


def result_lines(mission: Mission) -> list[str]:
    """The run's headline lines from the mission's reporting resources (e.g. the pallet)."""
    return [
        line
        for res in mission.ctx.resources.values()
        if isinstance(res, RunReporter)
        for line in res.result_lines()
    ]


def handled_failure_lines(mission: Mission, reason: str, limit: int = 10) -> list[str]:
    """Console lines for the leaf failures the run went on after (not the one that ended
    it): what a "continue anyway" branch swallowed."""
    items = [(t, n) for t, n in mission.leaf_failures.items() if t not in reason]
    lines = [f"handled: {t}" + (f" ({n} times)" if n > 1 else "") for t, n in items[:limit]]
    if len(items) > limit:
        lines.append(f"handled: ... and {len(items) - limit} more (summary.json leaf_failures)")
    return lines


def write_summary(run_dir: str, summary: dict[str, Any]) -> str:
    """Write ``summary.json`` in ``run_dir`` atomically (a temporary file, then a rename)."""
    path = os.path.join(run_dir, "summary.json")
    atomic_write_text(path, json.dumps(summary, indent=2))
    return path
