"""Running a campaign: check, skip what is finished, run the rest, save, tabulate, report.

:func:`run_campaign` is what ``btrun campaign`` (and the bench scripts) call. Every row is
saved the moment its result arrives (:class:`~bt_engine.campaign.results.ResultStore`);
the tables and the report are rebuilt from the saved rows at the end, also after Ctrl-C,
which stops the workers and keeps the finished rows (running the same campaign into the
same folder resumes it). The progress (done/total, failures, ETA) goes to stderr: a
``rich.progress`` bar on a terminal, plain lines in a log.

The rows are never a list: they are generated as the pool asks for them (and once more
for the tables), so memory follows the finished rows and the runs in flight, not the size
of the campaign (which :func:`~bt_engine.campaign.rows.expand` bounds by ``max_rows``).
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, TextIO

from bt_engine.campaign.check import check_campaign, mission_node_ids
from bt_engine.campaign.pool import CONNECT_TIMEOUT_S, DaskPool, LocalPool
from bt_engine.campaign.results import ResultStore, table_rows, write_tables
from bt_engine.campaign.rows import Row, expand
from bt_engine.campaign.spec import Campaign, load_campaign
from bt_engine.spec import Loc, MissionError, Problem


@dataclass
class CampaignRun:
    """What :func:`run_campaign` did."""

    campaign: Campaign
    out_dir: str
    #: every row of the campaign, in order (a lazy sequence: generated when read)
    rows: Sequence[Row]
    #: the rows asked for (``limit`` applied), in order (lazy too)
    selected: Sequence[Row]
    #: names of the rows that ran in this call (the others were already finished)
    ran: list[str] = field(default_factory=list)
    #: the table, one dict per finished row of the campaign, in row order
    table: list[dict[str, Any]] = field(default_factory=list)
    #: every saved record of the campaign's rows, by row key (what the workers returned)
    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    interrupted: bool = False
    wall_s: float = 0.0
    parquet: str = ""
    csv: str = ""
    report: str = ""

    @property
    def complete(self) -> bool:
        """Every selected row has a result."""
        names = {t["row"] for t in self.table}
        return all(r.name in names for r in self.selected)


def finished_keys(records: dict[str, dict[str, Any]], retry_crashed: bool) -> frozenset[str]:
    """The keys of the saved rows a run skips: all, or all but the CRASHED ones."""
    if not retry_crashed:
        return frozenset(records)
    return frozenset(k for k, rec in records.items() if rec.get("status") != "CRASHED")


def payload(c: Campaign, row: Row, out_dir: str, keep: str, include_paths: list[str]) -> dict:
    """What a worker needs to run ``row`` (JSON; paths absolute)."""
    return {
        "key": row.key,
        "name": row.name,
        "mission_path": os.path.abspath(row.mission_path),
        "rig_path": os.path.abspath(row.rig_path) if row.rig_path else None,
        "sets": row.set_items(),
        "seed": row.seed,
        "rate_hz": c.rate_hz,
        "max_time_s": c.max_time_s,
        "timeout_s": row.timeout_s,
        "run_dir": os.path.abspath(os.path.join(out_dir, "runs", row.folder)),
        "keep": keep,
        "flight_reports": c.flight_reports,
        "mcap": c.mcap,
        "metrics": [[m.name, m.source] for m in c.metrics],
        "include_paths": [os.path.abspath(p) for p in include_paths],
    }


class Progress:
    """The campaign's progress on ``stream`` (default stderr): rows done of total,
    failures, throughput and ETA.

    On a terminal, a ``rich.progress`` bar redrawn in place; otherwise (a CI log, a file)
    plain lines: one at the start, one per finished row at most every ``interval_s``
    seconds, one at the end."""

    def __init__(
        self,
        total: int,
        done: int,
        todo: int,
        stream: TextIO | None = None,
        interval_s: float = 10.0,
    ) -> None:
        self.total, self.done, self.todo = total, done, todo
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.interval_s = interval_s
        self.failed = 0
        self.ran = 0
        self.t0 = time.monotonic()
        self._last = -math.inf
        self._bar: Any = None  # rich.progress.Progress, on a terminal once started
        self._task: Any = None

    def line(self) -> str:
        """The current progress text (a plain line)."""
        elapsed = time.monotonic() - self.t0
        eta = "-"
        if self.ran:
            rest = (self.todo - self.ran) * elapsed / self.ran
            eta = _duration(rest)
        return (
            f"campaign: {self.done}/{self.total} done, {self.failed} failed, "
            f"{self._rate():.2f} runs/s, ETA {eta}"
        )

    def _rate(self) -> float:
        elapsed = time.monotonic() - self.t0
        return self.ran / elapsed if elapsed > 0 else 0.0

    def _start_bar(self) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        from rich.progress import Progress as Bar

        console = Console(file=self.stream, force_terminal=True)
        self._bar = Bar(
            TextColumn("campaign"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("[red]{task.fields[failed]} failed[/red]"),
            TextColumn("{task.fields[rate]} runs/s"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
        )
        self._task = self._bar.add_task(
            "campaign", total=self.total, completed=self.done, failed=0, rate="0.00"
        )
        self._bar.start()

    def update(self, status: str | None = None, force: bool = False) -> None:
        """Count one finished row (if ``status``) and show it (a terminal: the bar; a log:
        a line, at most one every ``interval_s`` seconds unless ``force``)."""
        if status is not None:
            self.done += 1
            self.ran += 1
            self.failed += status != "SUCCESS"
        if self.tty:
            if self._bar is None:
                self._start_bar()
            self._bar.update(
                self._task,
                completed=self.done,
                failed=self.failed,
                rate=f"{self._rate():.2f}",
            )
            return
        now = time.monotonic()
        if force or now - self._last >= self.interval_s:
            print(self.line(), file=self.stream, flush=True)
            self._last = now

    def close(self) -> None:
        """End the progress: the bar stays as it ended; a log gets a last line."""
        if not self.tty:
            self.update(force=True)
        elif self._bar is not None:
            self._bar.refresh()
            self._bar.stop()
            self._bar = None


def _duration(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def other_campaign(c: Campaign, out_dir: str) -> Problem | None:
    """A problem when ``out_dir`` holds the results of another campaign (the name its
    ``results.parquet`` records differs): running this one there had replaced that one's
    tables and report, and mixed both campaigns' run folders, without a word. None when
    the folder is new, holds this campaign (a resume, an edited file), or cannot tell."""
    path = os.path.join(out_dir, "results.parquet")
    if not os.path.isfile(path):
        return None
    try:
        import pyarrow.parquet as pq

        meta = pq.read_schema(path).metadata or {}
        theirs = meta[b"btrun.campaign"].decode()
    except Exception:  # noqa: BLE001 - an unreadable table: the rows' keys still tell
        return None
    if theirs == c.name:
        return None
    return Problem(
        Loc("--out", 0, 0),
        f"{out_dir} holds the results of campaign {theirs!r} (its results.parquet), not of "
        f"{c.name!r}: running it there would replace them; give another --out (or continue "
        "that campaign there)",
    )


def run_campaign(
    campaign: str | Campaign,
    out_dir: str,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
    limit: int | None = None,
    keep_runs: str | None = None,
    include_paths: list[str] | None = None,
    progress: TextIO | None = None,
    report: bool = True,
    retry_crashed: bool = False,
) -> CampaignRun:
    """Check the campaign (raises :class:`~bt_engine.spec.MissionError`: nothing runs), run
    its unfinished rows (the first ``limit`` only, if given) on ``workers`` local processes
    (default: one per core) or on the Dask cluster at ``scheduler`` (raises
    :class:`~bt_engine.campaign.pool.SchedulerUnreachable` if it does not answer within
    ``connect_timeout_s``: nothing runs), write the tables and the report into ``out_dir``.
    The progress, and the cluster's dashboard link, go to ``progress`` (default stderr).
    Ctrl-C returns with ``interrupted`` set.

    A row saved as CRASHED counts as finished unless ``retry_crashed``: then it runs again
    (after the cause, a worker without the plug-in, say, was fixed). On a Dask cluster,
    every worker connected is first asked whether its worker processes know the
    missions' nodes (:meth:`~bt_engine.campaign.pool.DaskPool.check_workers`; raises
    :class:`~bt_engine.campaign.pool.WorkersCannotRun`: nothing runs)."""
    c = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    taken = other_campaign(c, out_dir)
    if taken is not None:  # before anything is checked or written
        raise MissionError([taken])
    include_paths = list(include_paths or ())
    rows = expand(c, include_paths)  # lazy; raises first if there are more than c.max_rows
    check_campaign(c, rows, include_paths)
    keep = keep_runs or c.keep_runs
    selected = rows[:limit] if limit is not None else rows
    store = ResultStore(out_dir)
    records = store.finished()
    finished = finished_keys(records, retry_crashed)  # what was there before: to skip
    n_todo = sum(r.key not in finished for r in selected)
    stream = progress or sys.stderr
    pool: LocalPool | DaskPool | None = None
    if n_todo and scheduler:  # before anything is written: a wrong address fails at once
        pool = DaskPool(scheduler, connect_timeout_s)
        print(f"campaign: {pool.describe()}", file=stream, flush=True)
        try:  # workers without the plug-in: every row CRASHED, unknown node
            pool.check_workers(mission_node_ids(c, include_paths))
        except BaseException:
            pool.close()
            raise
    try:
        os.makedirs(out_dir, exist_ok=True)
        copy = os.path.join(out_dir, "campaign.yaml")  # what these results were made from
        if os.path.abspath(c.path) != os.path.abspath(copy):
            shutil.copyfile(c.path, copy)
    except BaseException:
        if pool is not None:
            pool.close()
        raise
    result = CampaignRun(c, out_dir, rows, selected)
    prog = Progress(len(selected), len(selected) - n_todo, n_todo, stream)
    t0 = time.perf_counter()
    if n_todo:
        if pool is None:
            log_dir = os.path.join(out_dir, "logs")
            os.makedirs(log_dir, exist_ok=True)
            pool = LocalPool(workers or os.cpu_count() or 1, log_dir)
        # row key -> names of its rows handed out (two rows may share a key); the pool's
        # threads add to it, this one takes from it
        in_flight: dict[str, deque[str]] = {}
        lock = threading.Lock()

        def payloads() -> Iterator[dict[str, Any]]:
            """The payloads of the rows to run, made when the pool asks for the next one."""
            for r in selected:
                if r.key not in finished:
                    with lock:
                        in_flight.setdefault(r.key, deque()).append(r.name)
                    yield payload(c, r, out_dir, keep, include_paths)

        try:
            prog.update(force=True)
            for rec in pool.results(payloads()):
                if rec.get("run_dir"):
                    rec["run_dir"] = os.path.relpath(rec["run_dir"], out_dir)
                with lock:
                    names = in_flight[rec["key"]]
                    rec["row"] = names.popleft()
                    if not names:
                        del in_flight[rec["key"]]
                rec["finished"] = time.time()
                store.save(rec)
                records[rec["key"]] = rec
                result.ran.append(rec["row"])
                prog.update(rec.get("status"))
        except KeyboardInterrupt:
            result.interrupted = True
        finally:
            prog.close()
            if result.interrupted:
                pool.stop()
            else:
                pool.close()
    result.wall_s = time.perf_counter() - t0
    done = [r for r in rows if r.key in records]  # one pass; as many as the records
    result.table = table_rows(c, done, records)
    result.records = {r.key: records[r.key] for r in done}
    result.parquet, result.csv = write_tables(out_dir, c, result.table)
    if report:
        from bt_engine.campaign.report import write_report

        result.report = write_report(out_dir, c, result.table)
    return result
