"""``btrun campaign CAMPAIGN.yaml --out DIR``: the command line of :func:`run_campaign`.

Exit codes: 0 every selected row has a result (whatever the runs' outcomes: the table says
them) and none is CRASHED, 1 interrupted (Ctrl-C; the finished rows are kept, the same
command resumes), 2 invalid input (located problems, a Dask scheduler that does not answer
or Dask workers that lack the missions' nodes; nothing ran), 3 every row has a result but
some are CRASHED (``--retry-crashed`` runs them again).
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import sys
from collections import Counter
from typing import Any

from bt_engine.arg_types import positive
from bt_engine.campaign.pool import CONNECT_TIMEOUT_S

KEEP_CHOICES = ("failed", "all", "none")
#: exit code of a campaign whose every row has a result, some of them CRASHED
EXIT_CRASHED = 3


def setup(p: argparse.ArgumentParser) -> None:
    """The options of ``btrun campaign``."""
    p.add_argument("campaign", help="campaign file (.yaml; docs/campaigns.md)")
    p.add_argument("--out", help="output folder (results, report, kept runs); required to run")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help=f"local worker processes (default: one per core, here {os.cpu_count()})",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask cluster (e.g. tcp://HOST:8786) instead of local processes",
    )
    p.add_argument(
        "--connect-timeout",
        type=positive("a time in s", 3600.0),  # inf and 1e11 reached Dask and threading
        default=CONNECT_TIMEOUT_S,
        metavar="SECONDS",
        help=f"how long the Dask scheduler has to answer (default {CONNECT_TIMEOUT_S:g})",
    )
    p.add_argument("--limit", type=int, default=None, metavar="N", help="run only the first N rows")
    p.add_argument(
        "--dry-run", action="store_true", help="check the campaign and list its rows; fly nothing"
    )
    p.add_argument(
        "--retry-crashed",
        action="store_true",
        help="run again the rows saved as CRASHED in --out (once their cause is fixed)",
    )
    p.add_argument(
        "--keep-runs",
        choices=KEEP_CHOICES,
        default=None,
        help="run folders to keep: failed (default: the runs that did not succeed), all, none",
    )


def run(args: argparse.Namespace) -> int:
    """Run the command; :class:`~bt_engine.spec.MissionError` propagates (exit code 2)."""
    from bt_engine.campaign.check import check_campaign
    from bt_engine.campaign.execution import finished_keys, other_campaign, run_campaign
    from bt_engine.campaign.pool import SchedulerUnreachable, WorkerError, WorkersCannotRun
    from bt_engine.campaign.report import print_summary
    from bt_engine.campaign.results import ResultStore
    from bt_engine.campaign.rows import dry_run_lines, expand
    from bt_engine.campaign.spec import load_campaign
    from bt_engine.spec import MissionError

    if args.limit is not None and args.limit < 1:
        print("btrun campaign: --limit must be at least 1", file=sys.stderr)
        return 2
    if args.workers is not None and args.workers < 1:
        print("btrun campaign: --workers must be at least 1", file=sys.stderr)
        return 2
    c = load_campaign(args.campaign)
    taken = other_campaign(c, args.out) if args.out else None
    if taken is not None:  # the dry run says it too
        raise MissionError([taken])
    if args.dry_run:
        rows = expand(c, args.include_path)
        checked = check_campaign(c, rows, args.include_path)
        selected = rows[: args.limit] if args.limit is not None else rows
        saved = ResultStore(args.out).finished() if args.out else {}
        done = set(finished_keys(saved, getattr(args, "retry_crashed", False)))
        for line in dry_run_lines(c, selected, done):  # generated line by line
            print(line)
        n_done = sum(r.key in done for r in selected) if done else 0
        print(
            f"{len(selected)} rows ({len(rows)} in the campaign), {n_done} already finished; "
            f"{checked} settings combinations checked; nothing was run."
        )
        return 0
    if not args.out:
        print("btrun campaign: --out DIR is required (results go there)", file=sys.stderr)
        return 2
    old_handler = _take_ctrl_c()
    try:
        result = run_campaign(
            c,
            args.out,
            workers=args.workers,
            scheduler=args.scheduler,
            connect_timeout_s=args.connect_timeout,
            limit=args.limit,
            keep_runs=args.keep_runs,
            include_paths=args.include_path,
            retry_crashed=getattr(args, "retry_crashed", False),
        )
    except (SchedulerUnreachable, WorkersCannotRun) as exc:  # bad input: nothing ran
        print(f"btrun campaign: {exc}", file=sys.stderr)
        return 2
    except (WorkerError, OSError) as exc:  # the finished rows are saved: the command resumes
        print(f"btrun campaign: {exc}", file=sys.stderr)
        return 1
    finally:
        if old_handler is not None:
            signal.signal(signal.SIGINT, old_handler)
    counts = Counter(r["status"] for r in result.table)
    outcome = ", ".join(f"{s} {n}" for s, n in counts.most_common()) or "no runs"
    print_summary(result.campaign, result.table)
    print(
        f"{len(result.table)}/{len(result.selected)} rows finished ({len(result.ran)} ran now, "
        f"{result.wall_s:.1f} s): {outcome}"
    )
    print(f"results: {result.parquet}, {result.csv} (columns: {result.out_dir}/columns.csv)")
    print(f"report: {result.report}")
    if result.interrupted or not result.complete:
        print(
            f"interrupted: the {len(result.table)} finished rows are kept in {args.out}; "
            f"resume with: {resume_command(args)}",
            file=sys.stderr,
        )
        return 1
    crashed = counts.get("CRASHED", 0)
    if crashed:
        print(
            f"btrun campaign: {crashed} of {len(result.table)} rows CRASHED (a run raised or "
            "its worker process died: their reason column and campaign_error.log say why); "
            "once the cause is fixed, run them again with: "
            f"{resume_command(args, retry_crashed=True)}",
            file=sys.stderr,
        )
        return EXIT_CRASHED
    return 0


def _take_ctrl_c() -> Any:
    """Make Ctrl-C raise KeyboardInterrupt while the campaign runs (it stops the workers,
    keeps the finished rows and prints the resume line); return the handler it replaced
    (None outside the main thread). The ``btrun`` launcher leaves a handler that only
    records the signal (for ``btrun run``, whose runner acts on it): a campaign has no
    runner of its own, and the Ctrl-C was lost."""
    try:
        return signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread
        return None


def resume_command(args: argparse.Namespace, retry_crashed: bool = False) -> str:
    """The command line that resumes this campaign: the same campaign file and folder, and
    every option that says where and how its rows run (``--scheduler`` and its time-out,
    ``--workers``, ``--limit``, ``--keep-runs``, ``--include-path``, ``--retry-crashed``,
    given or ``retry_crashed``), quoted for a shell."""
    cmd = ["btrun", "campaign", args.campaign, "--out", args.out]
    if args.scheduler:
        cmd += ["--scheduler", args.scheduler]
        if args.connect_timeout != CONNECT_TIMEOUT_S:
            cmd += ["--connect-timeout", f"{args.connect_timeout:g}"]
    elif args.workers is not None:
        cmd += ["--workers", str(args.workers)]
    if args.limit is not None:
        cmd += ["--limit", str(args.limit)]
    if args.keep_runs:
        cmd += ["--keep-runs", args.keep_runs]
    for path in getattr(args, "include_path", None) or ():
        cmd += ["--include-path", path]
    if retry_crashed or getattr(args, "retry_crashed", False):
        cmd.append("--retry-crashed")
    return shlex.join(cmd)
