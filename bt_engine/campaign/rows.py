"""A campaign's rows: one per run, in a fixed order, each a pure function of the campaign.

Order: missions x rigs x worlds x fault schedules x grid values (last key fastest) x seeds.
Random draws are seeded by ``draw_seed`` and the row's own identity (mission, rig, world,
fault, grid values, seed, setting key), not by its position: adding seeds or grid values
leaves the other rows' draws alone. A row's ``key`` hashes everything its result depends on
(the mission, rig and world file contents included), so a resumed campaign reuses a finished
row only when nothing it depends on changed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import random
from dataclasses import dataclass, field
from typing import Any

from bt_engine.campaign.spec import Campaign


@dataclass(frozen=True)
class Row:
    """One run of a campaign (an in-process ``btrun run MISSION --rig R --seed S --set ...``)."""

    index: int
    key: str
    mission: str
    mission_path: str
    rig: str | None
    rig_path: str | None
    world: str | None
    world_path: str | None
    seed: int
    fault: str | None
    timeout_s: float
    #: the settings that vary between rows (the table's parameter columns)
    params: dict[str, Any] = field(default_factory=dict)
    #: every setting of the run, fixed ones included
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The row's short name (``r00042``)."""
        return f"r{self.index:05d}"

    @property
    def folder(self) -> str:
        """Its run folder's name under ``DIR/runs/`` (stable across resumes)."""
        return f"{self.name}-{self.key[:8]}"

    def set_items(self) -> list[str]:
        """The ``--set KEY=VALUE`` items of the run (``world.path`` from ``worlds:``)."""
        items = [f"{k}={value_text(v)}" for k, v in self.settings.items()]
        if self.world_path:
            items.append(f"world.path={self.world_path}")
        return items


def value_text(value: Any) -> str:
    """A setting value as ``--set`` reads it (YAML scalars; lists in flow style)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        return (
            "["
            + ", ".join(value_text(v) if not isinstance(v, str) else json.dumps(v) for v in value)
            + "]"
        )
    return _float_text(value) if isinstance(value, float) else str(value)


def _float_text(x: float) -> str:
    """A float as YAML 1.1 reads it back (``5e-05`` is text there; ``5.0e-05`` a number)."""
    if math.isnan(x):
        return ".nan"
    if math.isinf(x):
        return ".inf" if x > 0 else "-.inf"
    text = repr(x)
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def _file_digest(path: str | None, cache: dict[str, str]) -> str:
    if not path:
        return ""
    if path not in cache:
        try:
            with open(path, "rb") as f:
                cache[path] = hashlib.sha256(f.read()).hexdigest()
        except OSError:
            cache[path] = "unreadable"
    return cache[path]


def expand(c: Campaign) -> list[Row]:
    """Every row of the campaign, in order."""
    rows: list[Row] = []
    digests: dict[str, str] = {}
    cases = c.faults if c.faults is not None else [None]
    grid_keys = list(c.grid)
    combos = list(itertools.product(*(c.grid[k] for k in grid_keys))) if grid_keys else [()]
    shared = {
        "max_time_s": c.max_time_s,
        "rate_hz": c.rate_hz,
        "metrics": [[m.name, m.op, m.text, m.wall_clock] for m in c.metrics],
    }
    missions = zip(c.missions, c.mission_paths, strict=True)
    for (m, mp), (rg, rp), (w, wp) in itertools.product(
        missions, zip(c.rigs, c.rig_paths, strict=True), zip(c.worlds, c.world_paths, strict=True)
    ):
        for case in cases:
            for combo in combos:
                grid = dict(zip(grid_keys, combo, strict=True))
                for k, seed in enumerate(c.seeds):
                    params: dict[str, Any] = dict(grid)
                    params.update({key: vals[k % len(vals)] for key, vals in c.cycle.items()})
                    identity = json.dumps([m, rg, w, case.name if case else None, grid, seed])
                    for key, draw in c.random.items():
                        params[key] = draw.sample(_rng(c.draw_seed, identity, key))
                    if case is not None:
                        params.update(case.sets)
                        for key, draw in case.draws.items():
                            params[key] = draw.sample(_rng(c.draw_seed, identity, key))
                    settings = {**c.fixed, **params}
                    timeout = case.timeout_s if case is not None and case.timeout_s else c.timeout_s
                    content = {
                        "mission": [m, _file_digest(mp, digests)],
                        "rig": [rg, _file_digest(rp, digests)],
                        "world": [w, _file_digest(wp, digests)],
                        "seed": seed,
                        "settings": sorted((k, value_text(v)) for k, v in settings.items()),
                        "timeout_s": timeout,
                        **shared,
                    }
                    key = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()
                    rows.append(
                        Row(
                            index=len(rows),
                            key=key,
                            mission=m,
                            mission_path=mp,
                            rig=rg,
                            rig_path=rp,
                            world=w,
                            world_path=wp,
                            seed=seed,
                            fault=case.name if case is not None else None,
                            timeout_s=timeout,
                            params=params,
                            settings=settings,
                        )
                    )
    return rows


def _rng(draw_seed: int, identity: str, key: str) -> random.Random:
    # a str seed is hashed with SHA-512: the same draws on every machine and Python run
    return random.Random(f"btrun-campaign/{draw_seed}/{identity}/{key}")


def dry_run_lines(c: Campaign, rows: list[Row], done: set[str]) -> list[str]:
    """The rows as text lines (``--dry-run``): name, mission, rig, world, seed, fault,
    parameters, and whether a result is already in the output folder."""
    params = c.parameters()
    head = ["row", "mission", "rig", "world", "seed"] + (["fault"] if c.faults else []) + params
    table = [head + ["done"]]
    for r in rows:
        cells = [r.name, r.mission, r.rig or "-", r.world or "-", str(r.seed)]
        if c.faults:
            cells.append(r.fault or "-")
        cells += [value_text(r.params.get(p)) if p in r.params else "-" for p in params]
        table.append(cells + ["yes" if r.key in done else ""])
    widths = [max(len(row[i]) for row in table) for i in range(len(head) + 1)]
    return [
        "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
        for row in table
    ]
