"""The campaign file (YAML): how it is read into the :class:`Campaign` it describes.

Reading walks PyYAML's composed node graph (safe loader only; tags, anchors and aliases are
refused), so every problem carries ``file:line:col``, the offending value and what was
expected; all problems are collected before anything is reported, as for missions.
``docs/campaigns.md`` documents every key. What needs the plug-in (missions against the
node registry, settings against the rig schema) is checked in :mod:`bt_engine.campaign.check`.
The keys (:data:`TOP_KEYS`), limits and the :class:`Campaign` itself are in
:mod:`bt_engine.campaign.model` (importable from here too).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from bt_engine.campaign.metrics import Metric, metric_from_data
from bt_engine.campaign.model import (
    DRAWS,
    FIXED_COLUMNS,
    FLIGHT_REPORTS,
    KEEP_RUNS,
    MAX_ROWS_CEILING,
    OTHER_COLUMNS,
    TOP_KEYS,
    Campaign,
    Draw,
    FaultCase,
    column_name,
    setting_key,
)
from bt_engine.campaign.model import MAX_ROWS as MAX_ROWS
from bt_engine.campaign.yaml_reader import SAFE, Reader, scan, show
from bt_engine.files import read_bytes
from bt_engine.inputs import parse_set_value
from bt_engine.registry import suggest_name
from bt_engine.spec import Loc, MissionError, Problem


def load_campaign(path: str) -> Campaign:
    """Read and check a campaign file; raises :class:`MissionError` with every located
    problem (nothing runs). Missions and settings are checked later, with the plug-in
    (:func:`bt_engine.campaign.check.check_campaign`)."""
    problems: list[Problem] = []
    text = _read_campaign_file(path, problems)
    if text is None:
        raise MissionError(problems)
    problems = scan(text, path)
    if problems:
        raise MissionError(problems)
    try:
        root = yaml.compose(text, Loader=SAFE)
    except yaml.YAMLError as exc:  # pragma: no cover - scan() parsed the same text
        raise MissionError([Problem(Loc(path, 1, 1), f"YAML error: {exc}")]) from None
    r = Reader(path)
    if not isinstance(root, MappingNode):
        got = "the file is empty" if root is None else f"got {show(r, root)}"
        raise MissionError(
            [Problem(Loc(path, 1, 1), f"expected a mapping of campaign keys ({got})")]
        )
    c = Campaign(path=path, name=os.path.splitext(os.path.basename(path))[0])
    first: dict[str, tuple[str, Loc]] = {}  # setting key -> (section, where), for conflicts
    seen_top: set[str] = set()
    sections: dict[str, Node] = {}  # top-level key -> its value node (where a count is)
    for key, knode, v in r.pairs(root, "campaign"):
        seen_top.add(key)
        sections[key] = v
        if key not in TOP_KEYS:
            close = suggest_name(key, list(TOP_KEYS))
            hint = f" (did you mean '{close}'?)" if close else ""
            r.bad(knode, f"unknown key '{key}'{hint}; expected one of: {', '.join(TOP_KEYS)}")
        elif key in ("name", "description"):
            setattr(c, key, r.text(v, key) or getattr(c, key))
        elif key == "missions":
            c.missions, c.mission_paths = [], []
            for item in r.items(v):
                shown, found = r.file(item, "missions")
                c.missions.append(shown)
                c.mission_paths.append(found or "")
                if found:
                    c.file_locs.setdefault(found, r.loc(item))
                    _check_file(r, c, item, found, "missions")
            if not c.missions:
                r.bad(v, "missions: expected at least one mission file")
        elif key in ("rigs", "worlds"):
            shown_list, found_list = [], []
            for item in r.items(v):
                shown, found = r.file(item, key, allow_null=True)
                shown_list.append(shown)
                found_list.append(found)
                if found:
                    c.file_locs.setdefault(found, r.loc(item))
                    _check_file(r, c, item, found, key)
            if not shown_list:
                r.bad(v, f"{key}: expected at least one entry (null: the default)")
            else:
                setattr(c, key, shown_list)
                setattr(c, key[:-1] + "_paths", found_list)
        elif key == "seeds":
            c.seeds = _seeds(r, v)
        elif key == "max_rows":
            n = r.integer(v, key)
            if n is not None and not 1 <= n <= MAX_ROWS_CEILING:
                r.bad(v, f"max_rows: expected 1 to {MAX_ROWS_CEILING:,}, got {n:,}")
            elif n is not None:
                c.max_rows = n
        elif key == "draw_seed":
            c.draw_seed = r.integer(v, key) or 0
        elif key in ("timeout_s", "max_time_s", "rate_hz"):
            n = r.number(v, key, minimum=0.0)
            if n is not None:
                setattr(c, key, n)
        elif key in ("keep_runs", "flight_reports"):
            kv, choices = r.value(v), KEEP_RUNS if key == "keep_runs" else FLIGHT_REPORTS
            if kv not in choices:
                r.bad(v, f"{key}: expected one of {', '.join(choices)}, got {kv!r}")
            else:
                setattr(c, key, kv)
        elif key == "mcap":
            flag = r.value(v)
            if not isinstance(flag, bool):
                r.bad(v, f"mcap: expected true or false, got {flag!r}")
            else:
                c.mcap = flag
        elif key == "set":
            for k, kn, vn in _settings(r, v, "set", first):
                c.fixed[k] = _plain_value(r, vn, f"set.{k}")
                c.key_locs.setdefault(k, r.loc(kn))
        elif key in ("grid", "cycle"):
            for k, kn, vn in _settings(r, v, key, first):
                values = r.value(vn)
                if not isinstance(values, list) or not values:
                    r.bad(vn, f"{key}.{k}: expected a non-empty list of values, got {show(r, vn)}")
                    continue
                getattr(c, key)[k] = [_plain_value(r, item, f"{key}.{k}") for item in vn.value]
                c.key_locs.setdefault(k, r.loc(kn))
        elif key == "random":
            for k, kn, vn in _settings(r, v, "random", first):
                d = _draw(r, vn, f"random.{k}")
                if d is not None:
                    c.random[k] = d
                c.key_locs.setdefault(k, r.loc(kn))
        elif key == "faults":
            c.faults = _faults(r, v, first, c.key_locs)
        elif key == "metrics":
            c.metrics = _metrics(r, v, c.key_locs)
    if "missions" not in seen_top:
        r.bad(root, "missing required key 'missions' (the mission files to fly)")
    _check_columns(r, c, root)
    if "world.path" in first and c.worlds != [None]:
        r.bad(first["world.path"][1], "world.path is set here and by worlds: keep one")
    too_many = c.row_count_problem(_largest_factor(r, c, sections, root))
    if too_many is not None:
        r.problems.append(too_many)
    if r.problems:
        raise MissionError(r.problems)
    return c


def _read_campaign_file(path: str, problems: list[Problem]) -> str | None:
    """The campaign file's text: a regular file (never a FIFO or a device: refused before
    it is opened), at most ``MAX_FILE_BYTES``, UTF-8 (a byte that is not is located)."""
    data = read_bytes(path, problems, what="campaign files")
    if data is None:
        return None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        before = data[: exc.start]
        line, column = before.count(b"\n") + 1, exc.start - (before.rfind(b"\n") + 1) + 1
        problems.append(Problem(Loc(path, line, column), f"not UTF-8 text (byte {exc.start})"))
        return None


def _largest_factor(r: Reader, c: Campaign, sections: dict[str, Node], root: Node) -> Loc:
    """Where the campaign file writes its largest factor of rows (the seeds' count, a grid
    key's list, ...): where a row count over the limit is reported."""
    name, _ = max(c.dimensions(), key=lambda d: d[1])
    if name.startswith("grid."):
        return c.key_locs.get(name[5:], r.loc(sections.get("grid", root)))
    node = sections.get(name, root)
    if name == "seeds" and isinstance(node, MappingNode):
        node = next((vn for k, _, vn in r.pairs(node, "seeds") if k == "count"), node)
    return r.loc(node)


def _check_file(r: Reader, c: Campaign, node: Node, path: str, key: str) -> None:
    """A mission, rig or world file the campaign names is read once, before anything runs:
    a regular file (not a FIFO, a device, ...), at most ``MAX_FILE_BYTES``, UTF-8 text
    without NUL bytes; its SHA-256 goes into ``c.digests`` (the rows' keys)."""
    if path in c.digests:
        return
    shown = r.value(node)
    found: list[Problem] = []
    data = read_bytes(path, found, r.loc(node), what=key)
    for p in found:
        r.bad(p.loc, f"{key}: '{shown}': {p.message}")
    if data is None:
        return
    why = None
    nul = data.find(b"\0")
    if nul >= 0:
        why = f"holds a NUL byte (byte {nul}); {key} are text files"
    else:
        try:
            data.decode("utf-8")
        except UnicodeDecodeError as exc:
            why = f"is not UTF-8 text (byte {exc.start})"
    if why is not None:
        r.bad(node, f"{key}: '{shown}' {why}")
        return
    c.digests[path] = hashlib.sha256(data).hexdigest()


def _seeds(r: Reader, node: Node) -> Sequence[int]:
    if isinstance(node, MappingNode):
        got = {k: vn for k, _, vn in r.pairs(node, "seeds")}
        extra = set(got) - {"start", "count"}
        if extra or "count" not in got:
            r.bad(node, f"seeds: expected {{start: N, count: M}}, got keys {sorted(got)}")
            return [0]
        start = r.integer(got["start"], "seeds.start") if "start" in got else 0
        count = r.integer(got["count"], "seeds.count")
        if count is not None and count < 1:
            r.bad(got["count"], f"seeds.count: expected at least 1, got {count}")
            return [0]
        return range(start or 0, (start or 0) + (count or 1))  # never a list: it may be huge
    seeds = [r.integer(item, "seeds") for item in r.items(node)]
    if not seeds:
        r.bad(node, "seeds: expected at least one seed")
    if len(set(seeds)) != len(seeds):
        r.bad(node, "seeds: a seed is listed twice (the runs would be identical)")
    return [s for s in seeds if s is not None] or [0]


def _settings(r: Reader, node: Node, section: str, first: dict) -> list[tuple[str, Node, Node]]:
    """The ``key: value`` pairs of a settings section; a key set in two sections is a problem."""
    out = []
    for k, kn, vn in r.pairs(node, section):
        key = setting_key(k.strip())
        if "=" in key or any(ch.isspace() for ch in key):
            r.bad(kn, f"{section}: '{k}' is not a setting key (e.g. wind.gust_std_mps, scan_speed)")
            continue
        if key in first and not (
            section.startswith("faults") and first[key][0].startswith("faults")
        ):
            sec, loc = first[key]
            r.bad(kn, f"{section}: '{key}' is already set in {sec} (line {loc.line}); set it once")
            continue
        first.setdefault(key, (section, r.loc(kn)))
        out.append((key, kn, vn))
    return out


def _plain_value(r: Reader, node: Node, where: str) -> Any:
    if isinstance(node, ScalarNode) and not node.style:  # unquoted: read as --set reads
        return parse_set_value(node.value)  # it (off is text, not YAML 1.1's false; 0042 is
        # 42, not octal 34; 1:30 is text, not 90)
    v = r.value(node)
    ok = v is None or isinstance(v, (str, int, float, bool))
    if isinstance(v, list):
        ok = all(isinstance(x, (str, int, float, bool)) for x in v)
    if not ok:
        r.bad(node, f"{where}: expected a value or a list of values, got {show(r, node)}")
    return v


def _draw(r: Reader, node: Node, where: str) -> Draw | None:
    spec = r.value(node)
    if not isinstance(spec, dict):
        r.bad(node, f"{where}: expected a draw such as {{uniform: [0, 1]}}, got {show(r, node)}")
        return None
    kinds = [k for k in spec if k in DRAWS]
    extra = [k for k in spec if k not in DRAWS and k != "round"]
    if len(kinds) != 1 or extra:
        r.bad(
            node,
            f"{where}: expected one of {', '.join(DRAWS)} (and optionally round), "
            f"got keys {sorted(spec)}",
        )
        return None
    kind, args = kinds[0], spec[kinds[0]]
    digits = spec.get("round")
    if digits is not None and (
        not isinstance(digits, int) or isinstance(digits, bool) or digits < 0
    ):
        r.bad(node, f"{where}.round: expected a number of decimals (0 or more), got {digits!r}")
        return None
    if kind == "choice":
        if not isinstance(args, list) or not args:
            r.bad(node, f"{where}.choice: expected a non-empty list of values, got {args!r}")
            return None
        return Draw(kind, tuple(args))

    def num(x: Any) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool)

    pair = isinstance(args, list) and len(args) == 2
    if pair and kind == "uniform" and all(isinstance(a, list) for a in args):
        lo, hi = args
        if (
            len(lo) == len(hi)
            and lo
            and all(num(x) for x in lo + hi)
            and all(a <= b for a, b in zip(lo, hi, strict=True))
        ):
            return Draw(kind, (list(map(float, lo)), list(map(float, hi))), digits)
    elif pair and all(num(a) for a in args):
        a, b = args
        if kind == "randint" and all(isinstance(x, int) for x in args) and a <= b:
            return Draw(kind, (a, b))
        if kind == "uniform" and a <= b:
            return Draw(kind, (float(a), float(b)), digits)
        if kind == "normal" and b >= 0:
            return Draw(kind, (float(a), float(b)), digits)
    want = {
        "uniform": "[low, high] (numbers, low <= high; or two lists of numbers)",
        "randint": "[low, high] (integers, low <= high)",
        "normal": "[mean, standard deviation >= 0]",
    }[kind]
    r.bad(node, f"{where}.{kind}: expected {want}, got {args!r}")
    return None


def _faults(r: Reader, node: Node, first: dict, key_locs: dict) -> list[FaultCase]:
    if not isinstance(node, SequenceNode) or not node.value:
        r.bad(
            node,
            f"faults: expected a list of fault schedules ({{name, set}}), got {show(r, node)}",
        )
        return []
    cases: list[FaultCase] = []
    for i, item in enumerate(node.value):
        where = f"faults[{i}]"
        fields = {k: (kn, vn) for k, kn, vn in r.pairs(item, where)}
        for k, (kn, _) in fields.items():
            if k not in ("name", "set", "timeout_s"):
                r.bad(kn, f"{where}: unknown key '{k}' (expected name, set, timeout_s)")
        if "name" not in fields:
            r.bad(item, f"{where}: missing 'name' (it names the fault in the results)")
            continue
        name = r.text(fields["name"][1], f"{where}.name") or "?"
        if any(c.name == name for c in cases):
            r.bad(fields["name"][1], f"{where}.name: '{name}' is used twice")
        case = FaultCase(name)
        if "timeout_s" in fields:
            case.timeout_s = r.number(fields["timeout_s"][1], f"{where}.timeout_s", minimum=0.0)
        if "set" in fields:
            for k, kn, vn in _settings(r, fields["set"][1], f"faults[{name}]", first):
                key_locs.setdefault(k, r.loc(kn))
                if isinstance(vn, MappingNode):
                    d = _draw(r, vn, f"{where}.set.{k}")
                    if d is not None:
                        case.draws[k] = d
                else:
                    case.sets[k] = _plain_value(r, vn, f"{where}.set.{k}")
        cases.append(case)
    return cases


def _metrics(r: Reader, node: Node, locs: dict[str, Loc]) -> list[Metric]:
    out = []
    for name, kn, vn in r.pairs(node, "metrics"):
        locs[f"metrics.{name}"] = r.loc(kn)
        try:
            out.append(metric_from_data(name, r.value(vn)))
        except ValueError as exc:
            r.bad(vn, f"metrics.{name}: {exc}")
    return out


def _check_columns(r: Reader, c: Campaign, root: Node) -> None:
    """Parameter and metric names become columns: they must not clash, neither as written
    nor as the plain column names of the tables (:func:`column_name`; compared without
    case, as SQL compares unquoted names)."""
    taken = set(FIXED_COLUMNS) | set(OTHER_COLUMNS)
    owner = {n: f"the column '{n}'" for n in taken}  # plain column (lower case) -> whose
    for key in c.parameters():
        where = c.key_locs.get(key, r.loc(root))
        if key in taken:
            r.bad(
                where,
                f"'{key}' is a column of its own; "
                f"a setting may not be named {', '.join(sorted(taken))}",
            )
            continue
        col = column_name(key).lower()
        if col in owner:
            r.bad(
                where,
                f"the setting '{key}' and {owner[col]} would both be the results column "
                f"'{column_name(key)}'; rename one",
            )
        owner.setdefault(col, f"the setting '{key}'")
    params = set(c.parameters())
    for m in c.metrics:
        where = c.key_locs.get(f"metrics.{m.name}", r.loc(root))
        if m.name in taken or m.name in params:
            r.bad(where, f"metrics: '{m.name}' is already a column (fixed or a setting); rename it")
            continue
        col = column_name(m.name).lower()
        if col in owner:
            r.bad(
                where,
                f"metrics: '{m.name}' and {owner[col]} would both be the results column "
                f"'{column_name(m.name)}'; rename one",
            )
        owner.setdefault(col, f"the metric '{m.name}'")
