"""``btrun gallery``: enrol, list, remove, export and check the pallets of a gallery file.

::

    btrun gallery list pallets.sqlite
    btrun gallery list site.sqlite --page 3 --per-page 100   # a page of a big gallery
    btrun gallery stats site.sqlite               # sides, pallets, views, model, size, dates
    btrun gallery stats demo --rig rigs/aisle.yaml --set world.pallet_pool.count=2000  # 4,000 sides
    btrun gallery enrol pallets.sqlite 7A --crops b1.png b2.png b3.png   # three crops, left to right
    btrun gallery enrol pallets.sqlite 7A --run runs/20261122-101500      # what a flight scanned
    btrun gallery enrol pallets.sqlite 2B --world-side 2B                 # a rendered scan (simulator)
    btrun gallery remove pallets.sqlite 7A
    btrun gallery export pallets.sqlite out/      # entries.json, embeddings.npy, crops as PNG
    btrun gallery evaluate pallets.sqlite         # how far apart the enrolled sides are
    btrun gallery history pallets.sqlite 7A       # enrolment, added views, rollbacks of 7A
    btrun gallery rollback pallets.sqlite 7A      # undo the latest view added to 7A
                                                  # (or a pallet enrolled in btrun console's review)
    btrun gallery demo                            # build (if needed) and show the demo gallery
    btrun gallery list demo --rig rigs/aisle.yaml # the aisle's demo gallery (the rig's world)
    btrun gallery enrol pallets 7A --run runs/... --store postgresql://btrun@db/btrun  # in PostgreSQL

``demo`` stands for the demo gallery of the rig's world (``--rig``, as in a mission run:
default the warehouse's) wherever a gallery is named. Errors are one line each,
with exit code 2.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import sys
import time
from typing import Any

import numpy as np

from bt_engine.arg_types import count
from bt_engine.spec import plural
from perception.gallery_pg import is_gallery_url

#: how an operator's review (``btrun console``) names itself in a gallery's history ``run``
REVIEW_RUN = "console review"


#: ``btrun gallery list`` shows every side of a gallery up to this size, else a page
LIST_ALL_UP_TO = 1000
#: sides per page of ``btrun gallery list``
PER_PAGE = 100


class GalleryCommandError(Exception):
    """A user error of ``btrun gallery`` (printed, exit code 2)."""


def setup(p: argparse.ArgumentParser) -> None:
    """Arguments of ``btrun gallery``."""
    sub = p.add_subparsers(dest="gallery_command", metavar="SUBCOMMAND", required=True)
    ls = sub.add_parser("list", help="the enrolled pallet sides (a page of them)")
    ls.add_argument("gallery")
    ls.add_argument("--page", type=count("a page number"), default=None, help="page number, from 1")
    ls.add_argument(
        "--per-page",
        type=count("a number of sides per page"),
        default=None,
        help=f"sides per page (default {PER_PAGE}; every side of a gallery of at most "
        f"{LIST_ALL_UP_TO} when neither option is given)",
    )
    st = sub.add_parser("stats", help="sides, pallets, views, model, thresholds, size, dates")
    st.add_argument("gallery")
    en = sub.add_parser("enrol", help="enrol a pallet side from crops, a run or a rendered scan")
    en.add_argument("gallery", help="gallery file (created if missing)")
    en.add_argument("name", help="identity, e.g. 7A")
    src = en.add_mutually_exclusive_group(required=True)
    src.add_argument("--crops", nargs=3, metavar="PNG", help="three block crops, left to right")
    src.add_argument("--run", metavar="RUN_DIR", help="a run folder whose scan found 3 blocks")
    src.add_argument("--world-side", metavar="ID", help="render an enrolment scan of this side")
    en.add_argument("--no-replace", action="store_true", help="refuse if NAME is enrolled")
    rm = sub.add_parser("remove", help="remove a pallet side")
    rm.add_argument("gallery")
    rm.add_argument("name")
    ex = sub.add_parser("export", help="write entries.json, embeddings.npy and the crops")
    ex.add_argument("gallery")
    ex.add_argument("out_dir")
    ev = sub.add_parser("evaluate", help="distances between the enrolled sides vs the thresholds")
    ev.add_argument("gallery")
    hi = sub.add_parser("history", help="the audit trail of a side (or of every side)")
    hi.add_argument("gallery")
    hi.add_argument("name", nargs="?", default=None, help="identity (default: all)")
    rb = sub.add_parser("rollback", help="undo a view added after an identification")
    rb.add_argument("gallery")
    rb.add_argument("name")
    rb.add_argument("--view", type=int, default=None, help="view id (default: the latest)")
    sub.add_parser("demo", help="build (if needed) the demo gallery and print its path")
    for sp in (ls, st, en, rm, ex, ev, hi, rb, sub.choices["demo"]):
        sp.add_argument(
            "--rig",
            default=None,
            help="rig: its camera and world (whose demo gallery 'demo' is); default sim",
        )
        sp.add_argument("--embedder", default="", help="embedder weights (default: shipped)")
        sp.add_argument("--detector", default="", help="detector weights (default: shipped)")
        sp.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="a rig or world.KEY setting, as in a mission run (a demo gallery of 4,000 "
            "sides: world.pallet_pool.count set to 2000 on a world with a pool, such as "
            "rigs/aisle.yaml's)",
        )
        sp.add_argument(
            "--store",
            default=None,
            metavar="URL",
            help="a site store on PostgreSQL (postgresql://...): GALLERY is then the name of a "
            "gallery in it, not a file (docs/store.md)",
        )


def run(args: argparse.Namespace) -> int:
    """Run one ``btrun gallery`` subcommand; return the exit code."""
    from nodes.perception_session import PerceptionError

    try:
        return _COMMANDS[args.gallery_command](args)
    except (GalleryCommandError, PerceptionError) as exc:
        print(f"btrun gallery: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        from perception.errors import ModelError
        from perception.gallery import GalleryError

        if isinstance(exc, (GalleryError, ModelError)):
            print(f"btrun gallery: {exc}", file=sys.stderr)
            return 2
        raise


def _session(args: argparse.Namespace) -> Any:
    from drivers.rig.loader import load_rig
    from nodes.perception_session import PerceptionSession

    overrides = {}
    for item in getattr(args, "set", None) or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise GalleryCommandError(f"--set {item}: expected KEY=VALUE")
        overrides[key.strip()] = value.strip()
    from drivers.settings import ConfigError

    try:
        rig = load_rig(args.rig, overrides or None)
    except ConfigError as exc:
        raise GalleryCommandError(str(exc)) from None
    return PerceptionSession(rig, log=print)


def _open(args: argparse.Namespace, create: bool = False) -> tuple[Any, Any]:
    s = _session(args)
    emb = s.embedder(args.embedder)
    spec = _spec(args)
    if spec != "demo" and not create and not is_gallery_url(spec) and not os.path.exists(spec):
        raise GalleryCommandError(f"{spec}: no such gallery file")
    det = s.detector(args.detector) if spec == "demo" else None
    return s, s.gallery(spec, emb, create=create, detector=det)


def _spec(args: argparse.Namespace) -> str:
    """The gallery named: a file, ``demo``, or with ``--store postgresql://...`` the
    gallery of that name in the store (``URL#NAME``)."""
    from perception.gallery_pg import gallery_url

    store = getattr(args, "store", None)
    if not store or args.gallery == "demo":
        return args.gallery
    if not is_gallery_url(store):
        raise GalleryCommandError(
            f"--store {store}: galleries are kept in a PostgreSQL store (postgresql://...); "
            "an SQLite gallery is its own file: name the file instead"
        )
    return gallery_url(store, args.gallery)


def _list(args: argparse.Namespace) -> int:
    from perception.gallery_stats import page_bounds

    _, g = _open(args)
    th = g.thresholds
    total = len(g)
    print(f"{g.path}: {total} pallet sides, model {g.model_version}")
    print(f"unknown above mean distance {th.max_distance:.3f} or below margin {th.min_margin:.3f}")
    page, per_page = getattr(args, "page", None), getattr(args, "per_page", None)
    if page is None and per_page is None and total <= LIST_ALL_UP_TO:
        entries, footer = g.entries(), ""
    else:
        try:
            offset, count, pages = page_bounds(total, page or 1, per_page or PER_PAGE)
        except ValueError as exc:
            raise GalleryCommandError(str(exc)) from None
        entries = g.entries(limit=count, offset=offset)
        footer = f"sides {offset + 1}-{offset + count} of {total}, page {page or 1} of {pages}"
        if (page or 1) < pages:
            footer += f" (next: --page {(page or 1) + 1}; btrun gallery stats for the figures)"
    for e in entries:
        when = time.strftime("%Y-%m-%d %H:%M", time.localtime(e["created"]))
        views = f"  +{e['views']} views" if e["views"] else ""
        print(f"  {e['identity']:<12} {when}  {e['crops']} crops{views}  {e['source']}")
    if footer:
        print(footer)
    return 0


def _stats(args: argparse.Namespace) -> int:
    from perception.gallery_stats import gallery_stats

    _, g = _open(args)
    st = gallery_stats(g)
    size = st["size_bytes"]
    when = st["last_update"]
    build = st["build_seconds"]
    lines = [
        ("gallery", g.path),
        ("pallet sides", st["sides"]),
        ("pallets", st["pallets"]),
        ("added views", st["views"]),
        ("sides with crops", st["sides_with_crops"]),
        ("model", st["model_version"]),
        ("unknown above", f"mean distance {st['max_distance']:.3f}"),
        ("or below", f"margin {st['min_margin']:.3f}"),
        ("size on disk", "in memory" if size is None else f"{size / 1e6:.1f} MB"),
        (
            "last update",
            "never" if when is None else time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(when)),
        ),
        ("build time", "-" if build is None else f"{build:.0f} s (generated)"),
    ]
    for name, value in lines:
        print(f"{name + ':':<18} {value}")
    return 0


def _history(args: argparse.Namespace) -> int:
    if args.gallery == "demo":
        raise GalleryCommandError("the demo gallery is generated: it has no history")
    _, g = _open(args)
    if args.name is not None and args.name not in g.identities() and not g.history(args.name):
        raise GalleryCommandError(f"{args.name} was never enrolled in {g.path}")
    events = g.history(args.name)
    print(f"{g.path}: {len(events)} events" + (f" of {args.name}" if args.name else ""))
    for e in events:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(e["time"]))
        figures = ""
        if e["distance"] is not None:
            figures = f"  distance {e['distance']:.3f} margin {e['margin']:.3f}"
        view = ""
        if e["view"] is not None:
            view = f"{'' if 'view' in e['action'] else ' view'} {e['view']}"
        extra = "  " + "  ".join(x for x in (e["run"] and f"run {e['run']}", e["note"]) if x)
        print(
            f"  #{e['event']:<4} {when}  {e['identity']:<10} {e['action']}{view}{figures}{extra.rstrip()}"
        )
    if args.name and args.name in g.identities():
        active = [v["view_id"] for v in g.views(args.name)]
        print(f"active added views of {args.name}: {', '.join(map(str, active)) or 'none'}")
    return 0


def _rollback(args: argparse.Namespace) -> int:
    if args.gallery == "demo":
        raise GalleryCommandError("the demo gallery is generated: nothing to roll back")
    _, g = _open(args)
    if args.view is None and args.name in g.identities() and not g.views(args.name):
        enrolled = [e for e in g.history(args.name) if e["action"] in ("enrol", "re-enrol")]
        last = enrolled[-1] if enrolled else None
        if last and last["action"] == "enrol" and (last["run"] or "").startswith(REVIEW_RUN):
            g.remove(args.name)  # an operator's "new pallet" (btrun console): undone whole
            print(f"rolled back the review enrolment of {args.name}: removed from {g.path}")
            return 0
    view = g.rollback(args.name, args.view, run="btrun gallery rollback")
    left = len(g.views(args.name))
    print(f"rolled back view {view} of {args.name} in {g.path} ({left} added views active)")
    return 0


def _read_png(path: str) -> np.ndarray:
    import cv2

    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        raise GalleryCommandError(f"{path}: not a readable image")
    return img


def _crops_of_run(run_dir: str) -> list[np.ndarray]:
    """The three block crops of the run's last scan: ``perception/scan_<n>_block_1..3.png``
    of the report (the highest ``n`` with all three), or ``block_1..3.png`` of a run folder
    written before scans were numbered."""
    folder = os.path.join(run_dir, "perception")
    scans: dict[int, list[str]] = {}
    for path in glob.glob(os.path.join(folder, "scan_*_block_*.png")):
        m = re.fullmatch(r"scan_(\d+)_block_([123])\.png", os.path.basename(path))
        if m:
            scans.setdefault(int(m.group(1)), []).append(path)
    whole = [n for n, paths in scans.items() if len(paths) == 3]
    paths = sorted(scans[max(whole)]) if whole else []
    if not paths:
        paths = sorted(glob.glob(os.path.join(folder, "block_[123].png")))
    if len(paths) < 3:
        raise GalleryCommandError(
            f"{run_dir}: no scan with three blocks (expected perception/scan_N_block_1..3.png, "
            "written with the run's report)"
        )
    return [_read_png(p) for p in paths[-3:]]


def _enrol(args: argparse.Namespace) -> int:
    from nodes.gallery.enrol_scan import scan_blocks, scan_frames
    from perception.gallery import identity_problem
    from perception.gallery_views import png_bytes

    if args.gallery == "demo":
        raise GalleryCommandError("the demo gallery is generated: enrol into your own file")
    why = identity_problem(args.name)
    if why is not None:  # before the model loads or a file is made
        raise GalleryCommandError(f"enrol: {why}")
    s, g = _open(args, create=True)
    emb = s.embedder(args.embedder)
    if args.crops:
        crops, source = [_read_png(p) for p in args.crops], "crops " + " ".join(args.crops)
    elif args.run:
        crops, source = _crops_of_run(args.run), f"run {args.run}"
    else:
        world = s.world_path()
        if world is None:
            raise GalleryCommandError("--world-side needs a rig with a world")
        frames = scan_frames(world, args.world_side, s.camera, 0, s.rig.world_overrides)
        crops = scan_blocks(frames, s.detector(args.detector), s.factors)
        source = f"rendered scan of {args.world_side}"
        if len(crops) < 3:
            raise GalleryCommandError(
                f"the scan of {args.world_side} found {len(crops)} of 3 blocks"
            )
    desc = emb.describe(crops)
    vis = desc.visibility if emb.occlusion_aware else None
    g.enrol(
        args.name, desc.vectors, [png_bytes(c) for c in crops], source, not args.no_replace, vis
    )
    print(f"enrolled {args.name} in {g.path} ({plural(len(g), 'pallet side')})")
    return 0


def _remove(args: argparse.Namespace) -> int:
    _, g = _open(args)
    if not g.remove(args.name):
        raise GalleryCommandError(f"{args.name} is not enrolled in {g.path}")
    print(f"removed {args.name} from {g.path} ({len(g)} pallet sides left)")
    return 0


def _export(args: argparse.Namespace) -> int:
    _, g = _open(args)
    os.makedirs(args.out_dir, exist_ok=True)
    ids, matrix = g.matrix()
    np.save(os.path.join(args.out_dir, "embeddings.npy"), matrix)
    entries = g.entries()
    stems: set[str] = set()
    for e in entries:
        stem = crop_file_stem(e["identity"], stems)
        e["crop_files"] = []
        for i, png in enumerate(g.crops(e["identity"])):
            name = f"{stem}_block_{i + 1}.png"
            with open(os.path.join(args.out_dir, name), "wb") as f:
                f.write(png)
            e["crop_files"].append(name)
    meta = {
        "gallery": os.path.abspath(g.path),
        "model_version": g.model_version,
        "thresholds": {
            "max_distance": g.thresholds.max_distance,
            "min_margin": g.thresholds.min_margin,
        },
        "identities": ids,
        "entries": entries,
    }
    with open(os.path.join(args.out_dir, "entries.json"), "w") as f:
        json.dump(meta, f, indent=1, default=str)
    print(f"exported {len(ids)} pallet sides of {g.path} to {args.out_dir}")
    return 0


#: what an exported crop's file name keeps of an identity as it is
_SAFE_STEM = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def crop_file_stem(identity: str, taken: set[str]) -> str:
    """The file name ``btrun gallery export`` gives ``identity``'s crops (before
    ``_block_N.png``): the identity itself when it is plain (letters, digits, ``.``, ``_``,
    ``-``), else its characters with every other one made ``_`` and a short hash of the
    identity after them, so a name from before identities were checked (``../../etc``,
    ``PAL/2026/1``, a line break) never leaves the export folder and two identities never
    share a file, even where file names ignore case. ``taken`` (the stems given so far,
    lower-cased) is updated."""
    import hashlib

    stem = identity
    if not _SAFE_STEM.fullmatch(identity) or identity.lower() in taken:
        plain = re.sub(r"[^A-Za-z0-9._-]", "_", identity)[:40].lstrip(".") or "_"
        digest = hashlib.sha256(identity.encode("utf-8", "surrogatepass")).hexdigest()[:8]
        stem = f"{plain}-{digest}"
    taken.add(stem.lower())
    return stem


def _evaluate(args: argparse.Namespace) -> int:
    from perception.gallery import block_distances

    _, g = _open(args)
    ids, m = g.matrix()
    if len(ids) < 2:
        raise GalleryCommandError(f"{g.path}: needs at least two pallet sides to compare")
    th = g.thresholds
    print(
        f"{g.path}: {len(ids)} sides; unknown above {th.max_distance:.3f}, margin {th.min_margin:.3f}"
    )
    print(f"  {'side':<10} {'nearest other':<14} {'mean distance':>13}")
    worst = None
    for i, ident in enumerate(ids):
        d = block_distances(m[i], m).mean(axis=1)
        d[i] = np.inf
        j = int(np.argmin(d))
        flag = "  <- closer than the unknown threshold" if d[j] <= th.max_distance else ""
        print(f"  {ident:<10} {ids[j]:<14} {d[j]:>13.3f}{flag}")
        worst = d[j] if worst is None else min(worst, d[j])
    print(f"closest pair: {worst:.3f}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    args.gallery = "demo"
    return _list(args)


_COMMANDS = {
    "list": _list,
    "stats": _stats,
    "enrol": _enrol,
    "remove": _remove,
    "export": _export,
    "evaluate": _evaluate,
    "history": _history,
    "rollback": _rollback,
    "demo": _demo,
}
