"""A gallery of thousands (issue 28): identification against gallery size, and search speed.

**Accuracy.** Galleries of 40, 400, 4,000 and 40,000 sides, nested (each holds the smaller
ones). The queried sides are the first ``--queries`` of every gallery; each row of
``ROWS`` (the operating distances and the robustness bench's hard rows) scans them, and
as many never-enrolled sides, once (the same scans against every size), through the
robustness bench's path (:class:`perception.robustness.Pipeline`: rendered views, the
detector, the crop nearest the centre, the embedder, :meth:`Gallery.match` with texture
verification). Per row and size: right / wrong / unknown, never-enrolled accepted, and the
embedding's rank-1. **With the prior** (``perception.expected.check_expected``, the
expected-stock 1:1 verification): each enrolled scan checked against its own pallet
(verified = right), each never-enrolled scan against the enrolled pallet the stock would
name there (verified = accepted).

What the galleries are, exactly:

* 40, 400 and 4,000: rendered sides (identities ``gs*``, texture seeds 200,000 and up:
  never used in training, in calibration (``vc*``, 30,000+) or by the robustness bench
  (``rb*``, 9,000+)), enrolled like the robustness bench's (three clean views at 0.4 m,
  square, nominal light, through the detector), built once into a cached SQLite file
  (``$BTRUN_CACHE_DIR/bench/``) over ``--workers`` processes;
* 40,000: the 4,000 rendered sides and 36,000 **composite** sides, each block taken from
  another of the 4,000 (same block position, its embedding, visibility and crop), never
  from a queried side. Rendering 36,000 more sides costs about 110 ms each (most of it
  the side's texture synthesis); a composite mixes three pallets' looks, so as an impostor
  it is likely easier than a real pallet: the 40,000 row bounds the cliff from below.

**Search speed** (``--speed``): :meth:`Gallery.match` without crops (embedding search) on
the same galleries, p50 / p95 wall and CPU per query, the exact float32 screen against
the reduced one (:mod:`perception.gallery_index`) at 4,000 and 40,000 sides, and the
reduced screen's recall (its answer and top-5 equal to the exact search's).

    .venv/bin/python bench/gallery_scale.py                  # default (about 15 min, 2 cores)
    .venv/bin/python bench/gallery_scale.py --quick          # fewer rows and scans
    .venv/bin/python bench/gallery_scale.py --speed          # search speed only
    .venv/bin/python bench/gallery_scale.py --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sqlite3
import statistics
import sys
import time
from collections.abc import Iterator

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np

from perception import gallery_index
from perception.gallery import Gallery
from perception.robustness import Condition, Pipeline, conditions
from perception.synth.appearance import SideStyle
from perception.synth.dataset import identity_names
from perception.synth.views import ViewConditions

PREFIX, SEED0 = "gs", 200_000  # held out: never trained on, calibrated on or benched
UNKNOWN_START = 60_000  # never-enrolled pallets: gs60000A ...
SIZES = (40, 400, 4000, 40_000)
RENDERED_MAX = 4000
ROWS = ("clean", "0.60 m", "0.80 m", "1.00 m", "1.20 m", "new stains 12%", "30 % occluded (strap)")
QUICK_ROWS = ("clean", "1.00 m", "1.20 m", "30 % occluded (strap)")


def side_style(index: int, cond: Condition, aged: bool) -> SideStyle:
    """The bench's style of side ``index`` under ``cond`` (as the robustness bench's)."""
    from dataclasses import replace

    style = SideStyle(texture_seed=SEED0 + index, **dict(cond.look))
    if aged and cond.ageing is not None:
        style = replace(style, ageing=replace(cond.ageing, seed=SEED0 + index))
    return style


# -- enrolment (worker processes) ------------------------------------------------------------
_PIPE: list[Pipeline] = []


def _init(texture: bool) -> None:
    import torch

    from perception.detector import BlockDetector
    from perception.embedder import BlockEmbedder

    torch.set_num_threads(1)
    _PIPE[:] = [
        Pipeline(BlockDetector.load(threads=1), BlockEmbedder.load(threads=1), texture=texture)
    ]


def _enrol_one(job: tuple[int, str]) -> tuple:
    from perception.gallery_views import png_bytes

    i, name = job
    pipe = _PIPE[0]
    cond = Condition("reference", "clean")
    rng = np.random.default_rng([SEED0, i])
    scan = pipe.scan(name, side_style(i, cond, False), rng, view=ViewConditions(), jitter=False)
    if not scan.complete:
        return name, None, None, None
    vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
    return name, vec, vis, [png_bytes(c) for c in scan.crops]  # type: ignore[arg-type]


def _scan_one(job: tuple[int, str, bool, str]) -> tuple:
    """One scan of a row: (name, enrolled, vectors, visibility, crops) or Nones."""
    idx, name, known, row = job
    pipe = _PIPE[0]
    cond = {c.name: c for c in conditions()}[row]
    rng = np.random.default_rng([SEED0, 7, idx, sum(map(ord, row))])
    view = cond.view if cond.view != ViewConditions() else None
    scan = pipe.scan(name, side_style(idx, cond, True), rng, cond.distance_m, cond.yaw_deg, view)
    if not scan.complete:
        return name, known, None, None, None
    vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
    return name, known, vec, vis, scan.crops


def _pool(workers: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init,
        initargs=(True,),
    )  # fmt: skip


def rendered_gallery(path: str, count: int, workers: int, log=print) -> float:
    """Build (once) the SQLite gallery of ``count`` rendered sides; return the seconds spent
    (0 when cached)."""
    if os.path.exists(path):
        return 0.0
    from perception.embedder import BlockEmbedder

    emb = BlockEmbedder.load(threads=1)
    tmp = path + ".building"
    if os.path.exists(tmp):
        os.unlink(tmp)
    start = time.perf_counter()
    names = identity_names(count, PREFIX)
    with Gallery.create(tmp, emb.model_version, emb.dim) as g, _pool(workers) as pool:
        g.set_thresholds(emb.thresholds)
        g.conn.execute("PRAGMA synchronous = OFF")
        for k, (name, vec, vis, pngs) in enumerate(
            pool.map(_enrol_one, enumerate(names), chunksize=8)
        ):
            if vec is not None:
                g.enrol(name, vec, pngs, source="bench/gallery_scale.py", visibility=vis)
            if (k + 1) % 250 == 0 or k + 1 == count:
                dt = time.perf_counter() - start
                log(f"  rendered and enrolled {k + 1}/{count} sides in {dt:.0f} s")
    os.replace(tmp, path)
    return time.perf_counter() - start


# -- galleries of each size ------------------------------------------------------------------
def _rows_of(src: sqlite3.Connection, names: list[str]) -> Iterator[tuple]:
    q = ",".join("?" * len(names))
    emb = dict(
        src.execute(f"SELECT identity, embeddings FROM entries WHERE identity IN ({q})", names)
    )
    vis = dict(
        src.execute(f"SELECT identity, stripes FROM visibility WHERE identity IN ({q})", names)
    )
    crops: dict[str, list[bytes]] = {}
    for ident, _, png in src.execute(
        f"SELECT identity, block, png FROM crops WHERE identity IN ({q}) ORDER BY 1, 2", names
    ):
        crops.setdefault(ident, []).append(png)
    for n in names:
        if n in emb:
            yield n, emb[n], vis.get(n), crops.get(n, [])


def sized_gallery(src_path: str, size: int, protected: int, seed: int = 0) -> Gallery:
    """An in-memory gallery of ``size`` sides: the first of the rendered gallery, then
    composite sides (each block from another rendered side, never one of the first
    ``protected``, the queried ones)."""
    src = sqlite3.connect(src_path)
    meta = dict(src.execute("SELECT key, value FROM meta"))
    g = Gallery.create(":memory:", meta["model_version"], int(meta["dim"]))
    g.conn.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)", [
        (k, meta[k]) for k in ("max_distance", "min_margin") if k in meta
    ])  # fmt: skip
    g.thresholds = g._load_thresholds()
    all_names = [r[0] for r in src.execute("SELECT identity FROM entries ORDER BY identity")]
    real = list(_rows_of(src, all_names[: min(size, len(all_names))]))
    dim = int(meta["dim"])
    with g.conn:
        for n, e, v, c in real:
            _insert(g, n, e, v, c)
        extra = size - len(real)
        if extra > 0:
            rng = np.random.default_rng(seed)
            pool = real[protected:]
            for k in range(extra):
                parts = [pool[j] for j in rng.choice(len(pool), 3, replace=False)]
                e = b"".join(
                    np.frombuffer(p[1], np.float32).reshape(3, dim)[b].tobytes()
                    for b, p in enumerate(parts)
                )
                v = None
                if all(p[2] is not None for p in parts):
                    v = b"".join(
                        np.frombuffer(p[2], np.float32).reshape(3, -1)[b].tobytes()
                        for b, p in enumerate(parts)
                    )
                c = (
                    [p[3][b] for b, p in enumerate(parts)]
                    if all(len(p[3]) == 3 for p in parts)
                    else []
                )
                _insert(g, f"gx{k:05d}A", e, v, c)
    g._invalidate()
    src.close()
    return g


def _insert(g: Gallery, name: str, emb: bytes, vis: bytes | None, crops: list[bytes]) -> None:
    g.conn.execute("INSERT INTO entries VALUES (?, ?, ?, ?)", (name, emb, 0.0, "bench"))
    if vis is not None:
        g.conn.execute("INSERT INTO visibility VALUES (?, ?)", (name, vis))
    for b, png in enumerate(crops):
        g.conn.execute("INSERT INTO crops VALUES (?, ?, ?)", (name, b, png))


# -- accuracy --------------------------------------------------------------------------------
def _expected_check():
    """``perception.expected.check_expected`` if it exists (the expected-stock 1:1
    verification), else None (the with-prior columns stay empty)."""
    try:
        from perception.expected import check_expected
    except ImportError:
        return None
    return check_expected


def score_row(g: Gallery, scans: list[tuple], texture: bool, prior) -> dict:
    """Right / wrong / unknown / accepted (and the with-prior figures) of one row's scans."""
    from perception.expected import pallet_of

    r = dict.fromkeys(("right", "wrong", "unknown", "rank1", "enrolled", "accepted",
                       "never", "incomplete", "prior_right", "prior_accepted", "emb_right",
                       "emb_wrong", "emb_accepted"), 0)  # fmt: skip
    in_gallery = set(g.identities())
    enrolled_names = [s[0] for s in scans if s[0] in in_gallery]
    for k, (name, _, vec, vis, crops) in enumerate(scans):
        known = name in in_gallery  # a queried side beyond a small gallery is never-enrolled
        r["enrolled" if known else "never"] += 1
        if vec is None:
            r["incomplete"] += 1
            r["unknown"] += int(known)
            continue
        m = g.match(vec, visibility=vis, crops=crops if texture else None)
        alone = g.match(vec, visibility=vis)  # the embedding alone decides
        if known:
            r["emb_right"] += int(alone.pallet_id == name)
            r["emb_wrong"] += int(alone.known and alone.pallet_id != name)
        else:
            r["emb_accepted"] += int(alone.known)
        if known:
            r["rank1"] += int(m.best_id == name)
            key = "right" if m.pallet_id == name else "unknown" if not m.known else "wrong"
            r[key] += 1
        else:
            r["accepted"] += int(m.known)
        if prior is not None and crops is not None:
            expected = pallet_of(name if known else enrolled_names[k % len(enrolled_names)])
            ok = prior(g, vec, vis, crops, expected).verified
            r["prior_right" if known else "prior_accepted"] += int(ok)
    return r


def accuracy(args, src_path: str, log=print) -> list[dict]:
    """Every row against every size."""
    rows = QUICK_ROWS if args.quick else ROWS
    known = identity_names(args.queries, PREFIX)
    never = identity_names(args.unknown, PREFIX, start=UNKNOWN_START)
    jobs = [(i, n, True) for i, n in enumerate(known)]
    jobs += [(UNKNOWN_START * 2 + i, n, False) for i, n in enumerate(never)]
    scans: dict[str, list[tuple]] = {}
    t = time.perf_counter()
    with _pool(args.workers) as pool:
        for row in rows:
            scans[row] = list(
                pool.map(_scan_one, [(i, n, kn, row) for i, n, kn in jobs], chunksize=4)
            )
            log(f"  scanned {row}: {len(jobs)} sides ({time.perf_counter() - t:.0f} s)")
    jobs = [
        (src_path, size, args.queries, scans, not args.no_texture, not args.no_prior)
        for size in sorted(args.sizes, reverse=True)  # the longest first
    ]
    out = []
    with _pool(args.workers) as pool:
        for rows_of_size in pool.map(_score_size, jobs):
            for r in rows_of_size:
                log(format_row(r))
            out += rows_of_size
    return sorted(out, key=lambda r: (r["size"], rows.index(r["row"])))


def _score_size(job: tuple) -> list[dict]:
    """Every row against one size (in a worker process)."""
    src_path, size, protected, scans, texture, with_prior = job
    prior = _expected_check() if with_prior else None
    g = sized_gallery(src_path, size, protected)
    g.prepare_search()
    out = []
    for row, row_scans in scans.items():
        c = time.process_time()
        r = score_row(g, row_scans, texture, prior)
        r.update(size=size, row=row, cpu_s=time.process_time() - c, prior=prior is not None)
        out.append(r)
    g.close()
    return out


def format_row(r: dict) -> str:
    """One line of the accuracy table."""
    n, u = r["enrolled"], r["never"]
    prior = (
        f" | prior: right {r['prior_right']}/{n}, never-enrolled accepted {r['prior_accepted']}/{u}"
        if r.get("prior") else " | prior: (no perception.expected)"
    )  # fmt: skip
    return (
        f"{r['size']:>6} sides  {r['row']:<24} right {r['right']}/{n} ({100 * r['right'] / max(n, 1):.0f} %) "
        f"wrong {r['wrong']} unknown {r['unknown']}  never-enrolled accepted {r['accepted']}/{u}  "
        f"embedding rank-1 {r['rank1']}/{n}, alone right {r['emb_right']} wrong {r['emb_wrong']} "
        f"accepted {r['emb_accepted']}{prior}"
    )


# -- search speed ----------------------------------------------------------------------------
def _cpu() -> float:
    return time.process_time()


def speed(args, src_path: str, log=print) -> list[dict]:
    """p50 / p95 of embedding search per size and screen; the reduced screen's recall."""
    from perception.embedder import BlockEmbedder  # noqa: F401  (models not needed)

    queries = []
    with _pool(1) as pool:
        jobs = [
            (i, n, True, "1.00 m") for i, n in enumerate(identity_names(args.speed_queries, PREFIX))
        ]
        queries = [s for s in pool.map(_scan_one, jobs) if s[2] is not None]
    out = []
    for size in args.sizes:
        g = sized_gallery(src_path, size, args.queries)
        results = {}
        for mode in ("exact", "reduced") if size >= 4000 else ("auto",):
            forced = {"exact": 10**9, "reduced": 0}.get(mode)
            saved = gallery_index.REDUCED_MIN_ROWS
            if forced is not None:
                gallery_index.REDUCED_MIN_ROWS = forced
            g._invalidate()
            t, c = time.perf_counter(), _cpu()
            g.match(queries[0][2], visibility=queries[0][3])  # loads the vectors, builds the index
            build = (time.perf_counter() - t, _cpu() - c)
            wall, cpu, answers = [], [], []
            for _ in range(args.repeats):
                for q in queries:
                    t, c = time.perf_counter(), _cpu()
                    m = g.match(q[2], visibility=q[3])
                    wall.append(1000 * (time.perf_counter() - t))
                    cpu.append(1000 * (_cpu() - c))
                    answers.append((m.pallet_id, [x[0] for x in m.ranking]))
            gallery_index.REDUCED_MIN_ROWS = saved
            results[mode] = answers
            row = {
                "size": size, "screen": mode if mode != "auto" else "exact (auto)",
                "p50_ms": statistics.median(wall), "p95_ms": _p95(wall),
                "cpu_p50_ms": statistics.median(cpu), "cpu_p95_ms": _p95(cpu),
                "load_s": build[0], "load_cpu_s": build[1], "queries": len(wall),
            }  # fmt: skip
            out.append(row)
            log(
                f"{size:>6} sides  {row['screen']:<13} p50 {row['p50_ms']:.1f} ms p95 "
                f"{row['p95_ms']:.1f} ms (CPU p50 {row['cpu_p50_ms']:.1f} p95 "
                f"{row['cpu_p95_ms']:.1f} ms), first match (read + index) {build[0]:.1f} s"
            )
        if "reduced" in results:
            same = sum(a == b for a, b in zip(results["exact"], results["reduced"], strict=True))
            top1 = sum(
                a[0] == b[0] for a, b in zip(results["exact"], results["reduced"], strict=True)
            )
            out[-1]["recall_same_top5"] = same / len(results["exact"])
            out[-1]["recall_same_answer"] = top1 / len(results["exact"])
            log(f"        reduced screen = exact search: answer {top1}/{len(results['exact'])}, "
                f"whole top-5 {same}/{len(results['exact'])}")  # fmt: skip
        g.close()
    return out


def _p95(xs: list[float]) -> float:
    return sorted(xs)[max(0, int(round(0.95 * len(xs))) - 1)]


def main(argv: list[str] | None = None) -> int:
    """Run the bench (see the module doc)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    ap.add_argument("--queries", type=int, default=50, help="enrolled sides scanned per row")
    ap.add_argument("--unknown", type=int, default=50, help="never-enrolled sides per row")
    ap.add_argument("--quick", action="store_true", help="4 rows, 30 + 30 scans")
    ap.add_argument("--speed", action="store_true", help="search speed only")
    ap.add_argument("--no-speed", action="store_true", help="accuracy only")
    ap.add_argument("--speed-queries", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-texture", action="store_true")
    ap.add_argument("--no-prior", action="store_true")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.quick:
        args.queries, args.unknown = min(args.queries, 30), min(args.unknown, 30)
    from nodes.gallery.demo import cache_dir

    folder = os.path.join(cache_dir(), "bench")
    os.makedirs(folder, exist_ok=True)
    rendered = min(RENDERED_MAX, max(args.sizes))
    src = os.path.join(folder, f"gallery_scale-{rendered}.sqlite")
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    built = rendered_gallery(src, rendered, args.workers)
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if built:
        print(f"rendered gallery of {rendered} sides built in {built:.0f} s "
              f"(workers' CPU {c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime:.0f} s)")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.1f}; gallery {src}")
    report: dict = {"sizes": args.sizes, "load_average": os.getloadavg()[0]}
    if not args.no_speed:
        report["speed"] = speed(args, src)
    if not args.speed:
        report["accuracy"] = accuracy(args, src)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1, default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
