"""``btrun inventory``: what the site store knows of the inventories flown.

::

    btrun inventory history A-03-2                 # what was found at A-03-2, run by run
    btrun inventory history --pallet 111           # where pallet 111 was seen, run by run
    btrun inventory diff RUN_A RUN_B               # places whose answer changed
    btrun inventory runs                           # the runs recorded
    btrun inventory import runs/inventory-*        # load run folders flown before
    btrun inventory history A-03-2 --store postgresql://btrun@db.site/btrun --json

``--store`` as in ``btrun run`` (default ``$BTRUN_STORE``, else ``runs/site.sqlite``).
Errors are one line each, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Any

from bt_engine.arg_types import count
from bt_engine.spec import plural
from store import InventoryStore, StoreError, default_url, disabled
from store.inventory import flown_by


def _limit(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--limit",
        type=count("a number of runs"),
        default=None,
        metavar="N",
        help="the newest N runs",
    )


def setup(p: argparse.ArgumentParser) -> None:
    """Arguments of ``btrun inventory``."""
    sub = p.add_subparsers(dest="inventory_command", metavar="SUBCOMMAND", required=True)
    hi = sub.add_parser(
        "history", help="what was found at a place, or where a pallet was seen, run by run"
    )
    hi.add_argument("place", nargs="?", help="place name, e.g. A-03-2")
    hi.add_argument(
        "--pallet", metavar="PALLET", help="where this pallet (any side: 111, 111B) was seen"
    )
    _limit(hi)
    di = sub.add_parser("diff", help="what changed between two inventories")
    di.add_argument("run_a", help="the earlier run (its folder's name, or the folder)")
    di.add_argument("run_b", help="the later run")
    rs = sub.add_parser("runs", help="the runs the store holds")
    _limit(rs)
    im = sub.add_parser("import", help="record run folders (flown before, or offline)")
    im.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    for sp in (hi, di, rs, im):
        sp.add_argument(
            "--store",
            metavar="URL",
            default=None,
            help="sqlite:///FILE or postgresql://... (default: $BTRUN_STORE, else "
            "runs/site.sqlite)",
        )
        sp.add_argument("--json", action="store_true", help="JSON instead of a table")


def run(args: argparse.Namespace) -> int:
    """Run one ``btrun inventory`` subcommand; return the exit code."""
    url = args.store or default_url()
    if disabled(url):
        print("btrun inventory: --store none has nothing to show", file=sys.stderr)
        return 2
    from store.db import db_errors, parse_url

    try:
        with InventoryStore.open(url, create=args.inventory_command == "import") as store:
            return _COMMANDS[args.inventory_command](store, args)
    except StoreError as exc:
        print(f"btrun inventory: {exc}", file=sys.stderr)
        return 2
    except db_errors() as exc:  # a damaged file, a schema of another program: one line
        where = parse_url(url).shown
        print(
            f"btrun inventory: {where}: the store cannot be used: "
            f"{str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__} "
            "(a damaged file or another program's database: check it with `sqlite3 FILE "
            "'PRAGMA integrity_check'`, or restore a copy)",
            file=sys.stderr,
        )
        return 2


def _when(t: Any) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t)) if t else "-"


def _table(title: str, columns: list[str], rows: list[list[Any]]) -> None:
    from rich.console import Console
    from rich.table import Table

    print(title)
    table = Table(box=None, header_style="bold")
    for c in columns:
        table.add_column(c, no_wrap=True)
    for r in rows:
        table.add_row(*["-" if v is None or v == "" else str(v) for v in r])
    Console(width=max(100, 24 * len(columns))).print(table)


def _number(v: Any) -> str | None:
    return f"{v:.3f}" if isinstance(v, float) else None


def _pallet_history(store: InventoryStore, args: argparse.Namespace) -> int:
    from perception.expected import pallet_key, pallet_of

    want = pallet_of(args.pallet)
    key = pallet_key(want)  # any case: a WMS may write the licence plate lower-case
    found = [h for h in store.answers_like(want) if pallet_key(h["answer"] or "") == key]
    found = found[-args.limit :] if args.limit else found
    if not found:
        raise StoreError(f"{store.shown}: pallet {args.pallet!r} was not seen in any run")
    if args.json:
        print(json.dumps(found, indent=1))
        return 0
    title = f"pallet {want}: seen {plural(len(found), 'time')} ({store.shown})"
    _rows_table(title, found, ("place", "answer", "status", "drone", "distance"))
    return 0


def _rows_table(title: str, found: list[dict], keys: tuple[str, ...]) -> None:
    """Run, start, what flew it (rig or fleet: one store may hold several sites), the
    row's ``keys`` (numbers to 3 places), the run's status: a table."""
    _table(
        title,
        ["run", "started", "rig or fleet", *keys, "run status"],
        [
            [h["run"], _when(h["started"]), (flown_by(h) or "").partition(" ")[2]]
            + [_number(h[k]) if k in ("distance", "margin") else h[k] for k in keys]
            + [h["run_status"]]
            for h in found
        ],
    )
    sites = sorted({flown_by(h) for h in found} - {None})
    if len(sites) > 1:
        print(
            f"note: runs of {len(sites)} rigs or fleets ({', '.join(sites)}): where they are "
            "different sites, a place of one name is a different rack in each"
        )


def _history(store: InventoryStore, args: argparse.Namespace) -> int:
    if (args.place is None) == (args.pallet is None):
        raise StoreError("history takes a place (history A-03-2) or a pallet (--pallet 111)")
    if args.pallet is not None:
        return _pallet_history(store, args)
    found = store.history(args.place, args.limit)
    if not found:
        places = store.places()
        if args.place in places:  # rows there, each carried over from a run kept beside it
            raise StoreError(
                f"{store.shown}: place {args.place!r} has only rows that resumed runs "
                "carried over; each is in the history of the run that found it"
            )
        close = close_place(args.place, places)
        hint = (
            f" (did you mean {close[0]}?)"
            if close
            else f" (where a pallet was seen: history --pallet {args.place})"
        )
        raise StoreError(f"{store.shown}: no row for place {args.place!r}{hint}")
    if args.json:
        print(json.dumps(found, indent=1))
        return 0
    title = f"{args.place}: {len(found)} runs ({store.shown})"
    _rows_table(title, found, ("answer", "status", "drone", "distance", "margin"))
    return 0


def close_place(name: str, places: list[str]) -> list[str]:
    """The place ``name`` was meant to be, as a list of none or one: one that differs only
    in case or leading zeros first (``a-05-2`` -> ``A-05-2``), else the closest spelling
    (difflib, case ignored)."""
    import difflib
    import re

    def canonical(text: str) -> str:
        return re.sub(r"\d+", lambda m: str(int(m.group())), text.strip().upper())

    want = canonical(name)
    same = [p for p in places if canonical(p) == want]
    if same:
        return same[:1]
    upper = {p.upper(): p for p in places}
    close = difflib.get_close_matches(name.upper(), list(upper), n=1)
    return [upper[c] for c in close]


def _run_name(text: str) -> str:
    """A run named by its id or by its folder (``runs/inventory-...``)."""
    return os.path.basename(os.path.normpath(text)) if os.path.isdir(text) else text


def _diff(store: InventoryStore, args: argparse.Namespace) -> int:
    args.run_a, args.run_b = _run_name(args.run_a), _run_name(args.run_b)
    changes = store.diff(args.run_a, args.run_b)
    warning = store.diff_warning(args.run_a, args.run_b)
    if args.json:
        doc: dict[str, Any] = {"a": args.run_a, "b": args.run_b, "changes": changes}
        if warning:
            doc["warning"] = warning
        print(json.dumps(doc, indent=1))
        return 0
    if warning:
        print(f"btrun inventory: warning: {warning}", file=sys.stderr)
    if not changes:
        print(f"{args.run_a} -> {args.run_b}: no place changed")
        return 0
    counts: dict[str, int] = {}
    for c in changes:
        counts[c["change"]] = counts.get(c["change"], 0) + 1
    _table(
        f"{args.run_a} -> {args.run_b}: "
        + ", ".join(f"{n} {k}" for k, n in sorted(counts.items())),
        ["place", "change", args.run_a, args.run_b],
        [[c["place"], c["change"], c["a"], c["b"]] for c in changes],
    )
    return 0


def _runs(store: InventoryStore, args: argparse.Namespace) -> int:
    runs = store.runs(args.limit)
    if args.json:
        print(json.dumps(runs, indent=1))
        return 0
    _table(
        f"{plural(len(runs), 'run')} ({store.shown})",
        ["run", "started", "status", "rows", "rig or fleet", "seed", "host"],
        [
            [
                r["run"],
                _when(r["started"]),
                r["status"],
                r["rows"],
                (flown_by(r) or "").partition(" ")[2],  # as history names it
                r["seed"],
                r["host"],
            ]
            for r in runs
        ],
    )
    return 0


def _import(store: InventoryStore, args: argparse.Namespace) -> int:
    from nodes.site.importer import check_run, import_run
    from nodes.site.recording import run_id

    refused = []
    for run_dir in args.run_dirs:  # every folder checked before any is written
        try:
            check_run(run_dir)
        except StoreError as exc:
            refused.append(str(exc))
    if refused:
        for why in refused:
            print(f"btrun inventory import: {why}", file=sys.stderr)
        print(f"nothing imported ({plural(len(refused), 'folder')} refused)", file=sys.stderr)
        return 2
    done = {}
    for run_dir in args.run_dirs:
        done[run_id(run_dir)] = import_run(store, run_dir)
    if args.json:
        print(json.dumps(done, indent=1))
    else:
        for run, n in done.items():
            print(f"imported {run}: {n} rows into {store.shown}")
    return 0


_COMMANDS = {"history": _history, "diff": _diff, "runs": _runs, "import": _import}
