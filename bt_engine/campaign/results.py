"""A campaign's results: one record per finished row, then the tables.

Each finished row is saved at once as ``DIR/rows/<key>.json`` (written to a temporary file,
flushed to disk, renamed): an interrupted or killed campaign keeps every row it finished,
and running it again into the same folder skips them (:meth:`ResultStore.finished`).
:func:`write_tables` turns the records of the campaign's rows into ``results.parquet`` and
``results.csv`` (row order, one row per run). The columns that depend on the wall clock
(``wall_s`` and the metrics marked ``wall_clock``) come last and are named in the Parquet
file's metadata (``btrun.timing_columns``): :func:`comparable` drops them, and what is
left is identical whatever the number of workers or the back-end.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable
from typing import Any

from bt_engine.campaign.rows import Row
from bt_engine.campaign.spec import Campaign
from bt_engine.files import read_bytes

TIMING_KEY = b"btrun.timing_columns"


class ResultStore:
    """The per-row records under ``DIR/rows/``."""

    def __init__(self, out_dir: str) -> None:
        self.out_dir = out_dir
        self.rows_dir = os.path.join(out_dir, "rows")

    def finished(self) -> dict[str, dict[str, Any]]:
        """Every saved record, by row key (unreadable files are ignored: they re-run; so are
        files that are not regular, such as a FIFO, or larger than ``MAX_FILE_BYTES``: a
        record is read with the bounded reader of :mod:`bt_engine.files`)."""
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
            if isinstance(rec, dict) and rec.get("key"):
                out[rec["key"]] = rec
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
    """(deterministic columns, wall-clock columns) of the campaign's table, in order."""
    det = ["row", "mission", "rig", "world", "seed"]
    if c.faults is not None:
        det.append("fault")
    det += c.parameters() + ["status", "reason"]
    det += [m.name for m in c.metrics if not m.wall_clock] + ["run_dir"]
    timing = ["wall_s"] + [m.name for m in c.metrics if m.wall_clock]
    return det, timing


def table_rows(c: Campaign, rows: Iterable[Row], records: dict[str, dict]) -> list[dict[str, Any]]:
    """One dict per row that has a record, in row order, keyed by column (``rows`` is
    iterated once: the lazy rows of :func:`~bt_engine.campaign.rows.expand` will do)."""
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
    """Write ``results.parquet`` and ``results.csv`` (atomically); return their paths."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    det, timing = columns(c)
    names = det + timing
    table = pa.table({n: _arrow_column([row[n] for row in cells]) for n in names})
    table = table.replace_schema_metadata(
        {TIMING_KEY: json.dumps(timing).encode(), b"btrun.campaign": c.name.encode()}
    )
    pq_path = os.path.join(out_dir, "results.parquet")
    pq.write_table(table, pq_path + ".tmp")
    os.replace(pq_path + ".tmp", pq_path)
    csv_path = os.path.join(out_dir, "results.csv")
    with open(csv_path + ".tmp", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(names)
        for row in cells:
            w.writerow([csv_text(row[n]) for n in names])
    os.replace(csv_path + ".tmp", csv_path)
    return pq_path, csv_path


def csv_text(value: Any) -> str:
    """A cell as CSV text: empty for None, true/false, lists as JSON, floats in full."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return repr(value) if isinstance(value, float) else str(value)


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
