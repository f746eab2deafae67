"""The :class:`Campaign` a campaign file describes: its keys, limits, draws and fault cases.

``docs/campaigns.md`` documents every key (:data:`TOP_KEYS`). :mod:`bt_engine.campaign.spec`
reads a file into a :class:`Campaign` (and re-exports what is here); :func:`column_name` is
how a setting or metric name becomes a column of the results tables.
"""

from __future__ import annotations

import math
import random
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from bt_engine.campaign.metrics import Metric
from bt_engine.spec import Loc, Problem

#: Every top-level key of a campaign file, with what it holds (docs/campaigns.md).
TOP_KEYS: dict[str, str] = {
    "name": "a short name (default: the file name)",
    "description": "free text",
    "missions": "mission files (a list, or one path)",
    "rigs": "rig files (null: the plug-in's default rig)",
    "worlds": "world files (set as world.path; null: the rig's own world)",
    "seeds": "a list of seeds, or {start: N, count: M}",
    "set": "settings fixed for every run (any --set key: value)",
    "grid": "settings crossed with each other (key: [values])",
    "cycle": "settings that cycle with the seed (key: [values]; run k takes value k mod n)",
    "random": "settings drawn per run (key: {uniform|randint|normal|choice: ...})",
    "draw_seed": "seed of the random draws (default 0)",
    "faults": "fault schedules crossed with the rest: [{name, set, timeout_s}]",
    "timeout_s": "wall-clock seconds one run may take (default 600)",
    "max_time_s": "mission-time limit of one run in s (default: the mission's max_time, else 900)",
    "rate_hz": "tick rate (default 50)",
    "metrics": "columns read from each run's summary.json (name: path or operation)",
    "keep_runs": "which run folders to keep: failed (default), all or none",
    "flight_reports": "flight reports in kept folders: kept (default), failed or none",
    "mcap": "record run.mcap in each run (default false: a row re-flies identically with "
    "btrun run, which records it)",
    "max_rows": "the most rows the campaign may have (default 100,000; at most 1,000,000)",
}
#: The most rows a campaign may have unless its file raises it with ``max_rows:``.
MAX_ROWS = 100_000
#: The most ``max_rows:`` may raise it to (the results tables are built in memory).
MAX_ROWS_CEILING = 1_000_000
DRAWS = ("uniform", "randint", "normal", "choice")
KEEP_RUNS = ("failed", "all", "none")
FLIGHT_REPORTS = ("kept", "failed", "none")
#: Columns every results table has (parameter and metric names must differ from these).
FIXED_COLUMNS = ("row", "mission", "rig", "world", "seed", "fault", "status", "reason")
#: The other columns of the results tables, not named in the campaign file.
OTHER_COLUMNS = ("run_dir", "mission_path", "rig_path", "world_path", "wall_s")
_NOT_PLAIN = re.compile(r"[^A-Za-z0-9_]")


@dataclass(frozen=True)
class Draw:
    """A random draw of one setting: ``uniform [lo, hi]`` (numbers, or lists of numbers
    drawn item by item), ``randint [lo, hi]``, ``normal [mean, std]`` or ``choice [...]``;
    ``digits`` rounds uniform and normal draws."""

    kind: str
    args: tuple
    digits: int | None = None

    def sample(self, rng: random.Random) -> Any:
        """One value (the same ``rng`` state gives the same value on any machine)."""
        if self.kind == "choice":
            return self.args[rng.randrange(len(self.args))]
        if self.kind == "randint":
            return rng.randint(int(self.args[0]), int(self.args[1]))
        lo, hi = self.args
        if isinstance(lo, list):
            return [self._round(rng.uniform(a, b)) for a, b in zip(lo, hi, strict=True)]
        if self.kind == "normal":
            return self._round(rng.gauss(lo, hi))
        return self._round(rng.uniform(lo, hi))

    def _round(self, x: float) -> float:
        return round(x, self.digits) if self.digits is not None else x

    def extremes(self) -> list[Any]:
        """Values that bound every draw, to validate before anything flies (a normal draw:
        mean +- 4 standard deviations)."""
        if self.kind == "choice":
            return list(self.args)
        if self.kind == "normal":
            mean, std = self.args
            return [self._round(mean - 4 * std), self._round(mean + 4 * std)]
        return list(self.args)


@dataclass
class FaultCase:
    """One fault schedule: its name, settings (fixed values and draws), its own time-out."""

    name: str
    sets: dict[str, Any] = field(default_factory=dict)
    draws: dict[str, Draw] = field(default_factory=dict)
    timeout_s: float | None = None


@dataclass
class Campaign:
    """A validated campaign file (paths as written, and resolved in ``*_paths``)."""

    path: str
    name: str
    description: str = ""
    missions: list[str] = field(default_factory=list)
    mission_paths: list[str] = field(default_factory=list)
    rigs: list[str | None] = field(default_factory=lambda: [None])
    rig_paths: list[str | None] = field(default_factory=lambda: [None])
    worlds: list[str | None] = field(default_factory=lambda: [None])
    world_paths: list[str | None] = field(default_factory=lambda: [None])
    #: the seeds (``{start, count}`` is a ``range``: never expanded into a list)
    seeds: Sequence[int] = field(default_factory=lambda: [0])
    fixed: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)
    cycle: dict[str, list] = field(default_factory=dict)
    random: dict[str, Draw] = field(default_factory=dict)
    draw_seed: int = 0
    faults: list[FaultCase] | None = None
    timeout_s: float = 600.0
    max_time_s: float | None = None  # None: the mission's own (btrun run without --max-time)
    rate_hz: float = 50.0
    metrics: list[Metric] = field(default_factory=list)
    keep_runs: str = "failed"
    flight_reports: str = "kept"
    mcap: bool = False
    max_rows: int = MAX_ROWS
    #: SHA-256 of each mission / rig / world file, by resolved path (read once, bounded)
    digests: dict[str, str] = field(default_factory=dict)
    #: where each setting key was written (for the plug-in's problems with its value)
    key_locs: dict[str, Loc] = field(default_factory=dict)
    #: where each mission / rig / world entry was written, by resolved path
    file_locs: dict[str, Loc] = field(default_factory=dict)

    def parameters(self) -> list[str]:
        """The setting keys that vary between runs (the table's parameter columns)."""
        keys = [*self.grid, *self.cycle, *self.random]
        for case in self.faults or ():
            keys += [k for k in [*case.sets, *case.draws] if k not in keys]
        return list(dict.fromkeys(keys))

    def dimensions(self) -> list[tuple[str, int]]:
        """(what, how many) of each factor of the rows, in row order (seeds fastest)."""
        dims = [("missions", len(self.missions)), ("rigs", len(self.rigs))]
        dims += [("worlds", len(self.worlds))]
        dims += [("faults", len(self.faults) if self.faults is not None else 1)]
        dims += [(f"grid.{k}", len(v)) for k, v in self.grid.items()]
        return dims + [("seeds", len(self.seeds))]

    def row_count(self) -> int:
        """How many rows the campaign has: the product of :meth:`dimensions`, computed
        without generating any row."""
        return math.prod(n for _, n in self.dimensions())

    def row_count_problem(self, loc: Loc | None = None) -> Problem | None:
        """The problem of a campaign with more rows than ``max_rows`` (None if it has not),
        naming the count, its factors and the limit; at ``loc`` (default: the file's start)."""
        n = self.row_count()
        if n <= self.max_rows:
            return None
        factors = " x ".join(f"{k} {v:,}" for k, v in self.dimensions() if v != 1) or "1"
        how = (
            f"max_rows: raises it, up to {MAX_ROWS_CEILING:,}"
            if self.max_rows < MAX_ROWS_CEILING
            else "the most a campaign may have"
        )
        return Problem(
            loc or Loc(self.path, 1, 1),
            f"the campaign has {n:,} rows ({factors}); the limit is {self.max_rows:,} ({how})",
        )


def column_name(name: str) -> str:
    """The results tables' column for a setting key or a metric name: a plain SQL identifier,
    every character other than an ASCII letter, digit or underscore replaced by ``_``
    (``wind.gust_std_mps`` -> ``wind_gust_std_mps``), ``_`` in front of a leading digit."""
    plain = _NOT_PLAIN.sub("_", name)
    return "_" + plain if plain[:1].isdigit() else plain


def setting_key(key: str) -> str:
    """A ``--set`` key as the run reads it (a leading ``rig.`` is dropped)."""
    return key[4:] if key.startswith("rig.") and "." in key[4:] else key
