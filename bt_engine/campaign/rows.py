"""A campaign's rows: one per run, in a fixed order, each a pure function of the campaign.

Order: missions x rigs x worlds x fault schedules x grid values (last key fastest) x seeds.
Random draws are seeded by ``draw_seed`` and the row's own identity (mission, rig, world,
fault, grid values, seed, setting key), not by its position: adding seeds or grid values
leaves the other rows' draws alone. A row's ``key`` hashes everything its result depends on
(the mission, rig and world file contents included), so a resumed campaign reuses a finished
row only when nothing it depends on changed.

The rows are never held in a list: :class:`CampaignRows` counts them arithmetically (a
campaign over its ``max_rows`` is refused before any row exists) and computes row ``i``
from ``i`` alone, when it is asked for.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
from collections.abc import Container, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, overload

from bt_engine.campaign.spec import Campaign
from bt_engine.files import read_bytes
from bt_engine.loading import load_spec
from bt_engine.spec import MissionError


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
    """The SHA-256 of a file's bytes (a bounded read: a FIFO, a device or a file over the
    limit is ``unreadable``), once per path."""
    if not path:
        return ""
    if path not in cache:
        data = read_bytes(path, [])
        cache[path] = hashlib.sha256(data).hexdigest() if data is not None else "unreadable"
    return cache[path]


def check_row_count(c: Campaign) -> int:
    """The campaign's row count, computed without generating a row; raises
    :class:`MissionError` if it is over ``c.max_rows``."""
    problem = c.row_count_problem()
    if problem is not None:
        raise MissionError([problem])
    return c.row_count()


class CampaignRows(Sequence[Row]):
    """The rows of a campaign, in order, generated one at a time when asked for (never held
    in a list): ``len()`` is arithmetic, ``rows[i]`` computes row ``i`` alone, a slice is
    another lazy view, iteration yields the rows one by one."""

    def __init__(
        self,
        c: Campaign,
        indices: range | None = None,
        _base: Any = None,
        include_paths: list[str] | None = None,
    ) -> None:
        self.campaign = c
        if _base is None:
            check_row_count(c)
            self._cases = c.faults if c.faults is not None else [None]
            self._grid_keys = list(c.grid)
            self._sizes = [n for _, n in c.dimensions()]
            self._digests: dict[str, str] = dict(c.digests)
            self._includes = _include_digests(c.mission_paths, include_paths, self._digests)
            self._shared = {
                "max_time_s": c.max_time_s,
                "rate_hz": c.rate_hz,
                "metrics": [[m.name, m.op, m.text, m.wall_clock] for m in c.metrics],
            }
        else:  # a view: the same campaign, other indices
            self._cases, self._grid_keys = _base._cases, _base._grid_keys
            self._sizes, self._digests, self._shared = _base._sizes, _base._digests, _base._shared
            self._includes = _base._includes
        self.indices = range(c.row_count()) if indices is None else indices

    def __len__(self) -> int:
        return len(self.indices)

    @overload
    def __getitem__(self, i: int) -> Row: ...

    @overload
    def __getitem__(self, i: slice) -> CampaignRows: ...

    def __getitem__(self, i: int | slice) -> Row | CampaignRows:
        if isinstance(i, slice):
            return CampaignRows(self.campaign, self.indices[i], self)
        return self._row(self.indices[i])

    def __iter__(self) -> Iterator[Row]:
        for index in self.indices:
            yield self._row(index)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, (CampaignRows, list, tuple)):
            return NotImplemented
        return len(self) == len(other) and all(a == b for a, b in zip(self, other, strict=True))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"<CampaignRows {self.campaign.name}: {len(self)} rows>"

    def _row(self, index: int) -> Row:
        """Row ``index`` of the campaign (its place in every factor, seeds fastest)."""
        c = self.campaign
        places, rest = [], index
        for size in reversed(self._sizes):
            rest, place = divmod(rest, size)
            places.append(place)
        places.reverse()
        i_m, i_r, i_w, i_f, *i_grid, k = places
        m, mp = c.missions[i_m], c.mission_paths[i_m]
        rg, rp = c.rigs[i_r], c.rig_paths[i_r]
        w, wp = c.worlds[i_w], c.world_paths[i_w]
        case = self._cases[i_f]
        grid = {key: c.grid[key][j] for key, j in zip(self._grid_keys, i_grid, strict=True)}
        seed = c.seeds[k]
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
            "mission": [m, _file_digest(mp, self._digests), *self._includes.get(mp, ())],
            "rig": [rg, _file_digest(rp, self._digests)],
            "world": [w, _file_digest(wp, self._digests)],
            "seed": seed,
            "settings": sorted((k, value_text(v)) for k, v in settings.items()),
            "timeout_s": timeout,
            **self._shared,
        }
        key = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()
        return Row(
            index=index,
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


def expand(c: Campaign, include_paths: list[str] | None = None) -> CampaignRows:
    """Every row of the campaign, in order, as a lazy sequence (nothing is generated until
    asked for); raises :class:`MissionError` first if the campaign has more than
    ``max_rows`` rows. A row's key covers the files its mission includes (found as
    ``btrun run --include-path`` finds them), so an edited subtree runs its rows again."""
    return CampaignRows(c, include_paths=include_paths)


def _include_digests(
    missions: list[str], include_paths: list[str] | None, cache: dict[str, str]
) -> dict[str, list[str]]:
    """Per mission file, ``[path, SHA-256]`` of every file it includes, nested ones too
    (none for a mission without includes, whose row keys stay as they were; a mission that
    does not load has none either: the campaign's check refuses it)."""
    out: dict[str, list[str]] = {}
    for path in dict.fromkeys(missions):
        try:
            spec = load_spec(path, include_paths)
        except Exception:  # noqa: BLE001 - said by check_campaign, with its location
            continue
        rel = os.path.dirname(os.path.abspath(path))
        out[path] = [
            x
            for inc in spec.includes
            for x in (os.path.relpath(os.path.abspath(inc), rel), _file_digest(inc, cache))
        ]
    return out


def _rng(draw_seed: int, identity: str, key: str) -> random.Random:
    # a str seed is hashed with SHA-512: the same draws on every machine and Python run
    return random.Random(f"btrun-campaign/{draw_seed}/{identity}/{key}")


def dry_run_lines(c: Campaign, rows: Iterable[Row], done: Container[str]) -> Iterator[str]:
    """The rows as text lines (``--dry-run``): name, mission, rig, world, seed, fault,
    parameters, and whether a result is already in the output folder. Two passes over
    ``rows`` (the column widths, then the lines): pass a sequence, such as
    :class:`CampaignRows`, that can be iterated twice; no list of the rows is made."""
    params = c.parameters()
    head = ["row", "mission", "rig", "world", "seed"] + (["fault"] if c.faults else []) + params

    def cells(r: Row) -> list[str]:
        out = [r.name, r.mission, r.rig or "-", r.world or "-", str(r.seed)]
        if c.faults:
            out.append(r.fault or "-")
        out += [value_text(r.params.get(p)) if p in r.params else "-" for p in params]
        return out + ["yes" if r.key in done else ""]

    widths = [len(h) for h in head + ["done"]]
    for r in rows:
        widths = [max(w, len(cell)) for w, cell in zip(widths, cells(r), strict=True)]

    def line(row: list[str]) -> str:
        return "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()

    yield line(head + ["done"])
    for r in rows:
        yield line(cells(r))
