"""A campaign's results: one record per finished row, then the tables.

Each finished row is saved at once as ``DIR/rows/<key>.json`` (written to a temporary file,
flushed to disk, renamed): an interrupted or killed campaign keeps every row it finished,
and running it again into the same folder skips them (:meth:`ResultStore.finished`).
:func:`write_tables` turns the records of the campaign's rows into ``results.parquet`` and
``results.csv`` (row order, one row per run) and ``columns.csv``, the tables' data
dictionary. The columns that depend on the wall clock (``wall_s`` and the metrics marked
``wall_clock``) come last and are named in the Parquet file's metadata
(``btrun.timing_columns``): :func:`comparable` drops them, and what is left is identical
whatever the number of workers or the back-end.

The files' column names are plain SQL identifiers: a setting key or a metric name becomes
:func:`~bt_engine.campaign.spec.column_name` of it (``wind.gust_std_mps`` ->
``wind_gust_std_mps``); ``columns.csv`` and the Parquet metadata (``btrun.columns``) map
each column back to its campaign key. :attr:`CampaignRun.table
<bt_engine.campaign.execution.CampaignRun.table>` (Python) keeps the campaign's own keys.
The CSV is for reading: floats to :data:`CSV_DIGITS` significant digits, lists as their
items joined by ``;``; the Parquet file keeps every value at full precision, typed.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from bt_engine.campaign.rows import Row
from bt_engine.campaign.spec import Campaign, column_name
from bt_engine.campaign.worker import CAMPAIGN_STATUSES, RUN_STATUSES
from bt_engine.files import read_bytes

#: the statuses a finished row has: the run's own, or the campaign's for a run that never
#: ended by itself
ROW_STATUSES = RUN_STATUSES + CAMPAIGN_STATUSES

TIMING_KEY = b"btrun.timing_columns"
COLUMNS_KEY = b"btrun.columns"
#: Significant digits of a float in ``results.csv`` (the Parquet file keeps them all).
CSV_DIGITS = 6
#: Between the items of a list in ``results.csv``.
LIST_SEPARATOR = ";"
#: What each column that is not a setting or a metric holds (``columns.csv``).
RUN_COLUMNS = {
    "row": "the row's name (r00000, r00001, ...): its place in the campaign",
    "mission": "the mission file as the campaign file names it (relative to the campaign file)",
    "rig": "the rig file as the campaign file names it; empty: the plug-in's default rig",
    "world": "the world file as the campaign file names it; empty: the rig's own world",
    "seed": "the run's seed",
    "fault": "the fault schedule's name",
    "status": "SUCCESS, FAILURE or ABORTED (the mission's), CRASHED or TIMEOUT (the campaign's)",
    "reason": "why the run ended so",
    "run_dir": "the kept run folder, relative to the output folder; empty: not kept",
    "mission_path": "the mission file flown, as an absolute path",
    "rig_path": "the rig file flown, as an absolute path; empty: the plug-in's default rig",
    "world_path": "the world file flown, as an absolute path; empty: the rig's own world",
    "wall_s": "wall-clock seconds of the run, as timed by its worker",
}


class ResultStore:
    """The per-row records under ``DIR/rows/``."""

    def __init__(self, out_dir: str) -> None:
        self.out_dir = out_dir
        self.rows_dir = os.path.join(out_dir, "rows")

    def finished(self) -> dict[str, dict[str, Any]]:
        """Every saved record, by row key (unreadable files are ignored: they re-run; so are
        files that are not regular, such as a FIFO, or larger than ``MAX_FILE_BYTES``: a
        record is read with the bounded reader of :mod:`bt_engine.files`; and records whose
        ``status`` is none of :data:`ROW_STATUSES`)."""
        out: dict[str, dict[str, Any]] = {}
        if not os.path.isdir(self.rows_dir):
            return out
        for name in os.listdir(self.rows_dir):
            if not name.endswith(".json"):
                continue
            data = read_bytes(os.path.join(self.rows_dir, name), [], what="results")
            if data is None:
                continue
            try:
                rec = json.loads(data)
            except ValueError:
                continue
            if isinstance(rec, dict) and rec.get("key") and rec.get("status") in ROW_STATUSES:
                out[rec["key"]] = rec  # a record with no status a run gives (hand-edited,
                # cut): not a finished row, it runs again
        return out

    def save(self, record: dict[str, Any]) -> None:
        """Save one row's record atomically and durably."""
        os.makedirs(self.rows_dir, exist_ok=True)
        path = os.path.join(self.rows_dir, f"{record['key']}.json")
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(record, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)


def columns(c: Campaign) -> tuple[list[str], list[str]]:
    """(deterministic columns, wall-clock columns) of the campaign's table, in order, by
    their keys in :attr:`CampaignRun.table` (setting keys and metric names as the campaign
    file writes them; :func:`table_columns` gives the files' names)."""
    det = ["row", "mission", "rig", "world", "seed"]
    if c.faults is not None:
        det.append("fault")
    det += c.parameters() + ["status", "reason"]
    det += [m.name for m in c.metrics if not m.wall_clock]
    det += ["run_dir", "mission_path", "rig_path", "world_path"]
    timing = ["wall_s"] + [m.name for m in c.metrics if m.wall_clock]
    return det, timing


@dataclass(frozen=True)
class Column:
    """One column of the results files (a line of ``columns.csv``)."""

    #: its name in the files (a plain SQL identifier)
    name: str
    #: its key in :attr:`CampaignRun.table`: the setting key or metric name as written
    key: str
    #: ``run`` (every table has it), ``setting`` or ``metric``
    kind: str
    #: the value depends on the wall clock (not in :func:`comparable`)
    wall_clock: bool
    #: what it holds (for a metric: its expression over summary.json)
    description: str


def table_columns(c: Campaign) -> list[Column]:
    """The columns of ``results.parquet`` / ``results.csv``, in order."""
    det, timing = columns(c)
    params = set(c.parameters())
    metrics = {m.name: m for m in c.metrics}
    out = []
    for key in det + timing:
        if key in metrics:
            m = metrics[key]
            kind, description = "metric", f"summary.json: {m.text}"
        elif key in params:
            kind, description = "setting", _setting_description(c, key)
        else:
            kind, description = "run", RUN_COLUMNS.get(key, "")
        out.append(Column(column_name(key), key, kind, key in timing, description))
    return out


def _setting_description(c: Campaign, key: str) -> str:
    if key in c.grid:
        where = "grid (every value crossed with the rest)"
    elif key in c.cycle:
        where = "cycle (the k-th seed of each combination takes value k mod n)"
    elif key in c.random:
        where = "random (drawn per run)"
    else:
        where = "faults (set by the fault schedules; empty in the others)"
    return f"--set {key}: {where}"


def table_rows(c: Campaign, rows: Iterable[Row], records: dict[str, dict]) -> list[dict[str, Any]]:
    """One dict per row that has a record, in row order, keyed by :func:`columns` (``rows``
    is iterated once: the lazy rows of :func:`~bt_engine.campaign.rows.expand` will do)."""
    det, timing = columns(c)
    out = []
    for r in rows:
        rec = records.get(r.key)
        if rec is None:
            continue
        metrics = rec.get("metrics") or {}
        cell: dict[str, Any] = {
            "row": r.name,
            "mission": r.mission,
            "rig": r.rig or "",
            "world": r.world or "",
            "seed": r.seed,
            "fault": r.fault or "",
            "status": rec.get("status"),
            "reason": rec.get("reason", ""),
            "run_dir": rec.get("run_dir", ""),
            "mission_path": os.path.abspath(r.mission_path),
            "rig_path": os.path.abspath(r.rig_path) if r.rig_path else "",
            "world_path": os.path.abspath(r.world_path) if r.world_path else "",
            "wall_s": rec.get("wall_s"),
        }
        cell.update({p: r.params.get(p) for p in c.parameters()})
        cell.update({m.name: metrics.get(m.name) for m in c.metrics})
        out.append({k: cell.get(k) for k in det + timing})
    return out


def _arrow_column(values: list[Any]) -> Any:
    """A typed Arrow array; values of mixed types become JSON text."""
    import pyarrow as pa

    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, OverflowError):
        return pa.array([None if v is None else json.dumps(v) for v in values], pa.string())


def write_tables(out_dir: str, c: Campaign, cells: list[dict[str, Any]]) -> tuple[str, str]:
    """Write ``results.parquet``, ``results.csv`` and ``columns.csv`` (each atomically);
    return the paths of the first two. ``cells`` are :func:`table_rows`."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = table_columns(c)
    timing = [col.name for col in cols if col.wall_clock]
    table = pa.table({col.name: _arrow_column([row[col.key] for row in cells]) for col in cols})
    table = table.replace_schema_metadata(
        {
            TIMING_KEY: json.dumps(timing).encode(),
            COLUMNS_KEY: json.dumps([asdict(col) for col in cols]).encode(),
            b"btrun.campaign": c.name.encode(),
            b"btrun.campaign_file": os.path.abspath(c.path).encode(),
        }
    )
    pq_path = os.path.join(out_dir, "results.parquet")
    pq.write_table(table, pq_path + ".tmp")
    os.replace(pq_path + ".tmp", pq_path)
    csv_path = os.path.join(out_dir, "results.csv")
    with open(csv_path + ".tmp", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow([col.name for col in cols])
        for row in cells:
            w.writerow([csv_text(row[col.key]) for col in cols])
    os.replace(csv_path + ".tmp", csv_path)
    dictionary = os.path.join(out_dir, "columns.csv")
    with open(dictionary + ".tmp", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["column", "kind", "source", "wall_clock", "description"])
        for col in cols:
            source = col.key if col.kind != "run" else ""  # the campaign file's name for it
            w.writerow([col.name, col.kind, source, csv_text(col.wall_clock), col.description])
    os.replace(dictionary + ".tmp", dictionary)
    return pq_path, csv_path


def csv_text(value: Any) -> str:
    """A cell as CSV text: empty for None (and NaN, infinities), ``true``/``false``, floats
    to :data:`CSV_DIGITS` significant digits (``0.00462965``, ``3.0``, ``1.5e-05``), a list
    as its items joined by ``;`` (``0.1;0.25;0.3``; a missing item is empty; an empty list an
    empty cell); a mapping, a list holding lists or mappings, or a list with an item that
    holds ``;``, as JSON (floats rounded alike)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return _float_text(value)
    if isinstance(value, list) and all(_joinable(v) for v in value):
        return LIST_SEPARATOR.join(csv_text(v) for v in value)
    if isinstance(value, (list, dict)):
        return json.dumps(_rounded(value))
    return str(value)


def _float_text(x: float) -> str:
    text = f"{x:.{CSV_DIGITS}g}"
    return text + ".0" if text.lstrip("-").isdigit() else text  # still reads as a float


def _joinable(v: Any) -> bool:
    """An item that may be joined with ``;`` (and read back by splitting)."""
    if isinstance(v, str):
        return LIST_SEPARATOR not in v
    return v is None or isinstance(v, (bool, int, float))


def _rounded(value: Any) -> Any:
    """``value`` with its floats rounded as in the CSV (for the cells written as JSON)."""
    if isinstance(value, float):
        return float(_float_text(value)) if math.isfinite(value) else None
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value


def read_results(path: str) -> Any:
    """A results table (``results.parquet``, or the campaign folder holding it)."""
    import pyarrow.parquet as pq

    if os.path.isdir(path):
        path = os.path.join(path, "results.parquet")
    return pq.read_table(path)


def comparable(table: Any) -> Any:
    """The table without its wall-clock columns (identical for identical campaigns)."""
    meta = table.schema.metadata or {}
    timing = json.loads(meta.get(TIMING_KEY, b"[]"))
    return table.drop_columns(
        [n for n in timing if n in table.column_names]
    ).replace_schema_metadata(None)
