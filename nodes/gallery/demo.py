"""The demo gallery, built from enrolment scans without a flight
(:mod:`nodes.gallery.enrol_scan`): the three committed crops of each side's scan are
embedded and enrolled.

The demo gallery holds every side of the world's pallets ("1A" .. "5B" in
``worlds/warehouse.yaml``: the reference study's five pallets; in a world with racks, every
side but those of ``stock.not_enrolled``), each enrolled from the same
canonical pose (alone in a canonical slot, seen from a canonical line), whatever slots the
world gives them: moving a pallet (``--set world.scan_slot.y_m=...``, a placement error)
neither rebuilds the gallery nor changes it. It is built on first use, in about ten
seconds, into a cache file whose name depends on the pallets' appearance (not their
places), the light, the camera and both model versions (``$BTRUN_CACHE_DIR``, default
``~/.cache/btrun``), so a new model or appearance never reuses a stale gallery. The file is written under a temporary name and renamed, so an
interrupted build leaves nothing half-made.

A pool of thousands of sides (``--set world.pallet_pool.count=2000``: 4,000 sides) is
enrolled from a few rendered views per side, not a whole scan flight: the frames of the
canonical scan in which a block crosses the block sequencer's window (plus the one that
commits it, and the auto-exposure's frames), through the same renderer, detector and
sequencer (:func:`enrolment_frames`), over two worker processes, with a progress line per
100 sides. Figures in docs/pallet-identification.md.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from bt_engine.interrupts import interrupt_pending
from nodes.gallery.enrol_scan import (
    CANONICAL_SLOT,
    _canonical_scan,
    clear_racks,
    enrolment_frames,
    enrolment_note,
    enrolment_slot,
    look_overrides,
    scan_blocks,
    unaged,
)

ENROL_VERSION = 5  # bump when enrolment or the renderer changes (invalidates cached galleries)
#: worker processes of a demo gallery build (the machine's two cores)
BUILD_WORKERS = 2
#: sides per progress line of a build
PROGRESS_EVERY = 100


def cache_dir() -> str:
    """Where btrun keeps generated files (``$BTRUN_CACHE_DIR`` or ``~/.cache/btrun``)."""
    root = os.environ.get("BTRUN_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "btrun")
    return root


def appearance_key(data: dict) -> bytes:
    """What a demo gallery depends on in a world: the pallets and their look, their
    geometry, the light and the floor; not where the world places them, nor how they aged
    since enrolment."""
    import json

    data = unaged(data)  # ageing since enrolment does not change what was enrolled
    keep = {
        k: data.get(k)
        for k in ("pallets", "pallet_pool", "pallet_look", "pallet_geometry", "lighting", "floor")
    }
    keep["not_enrolled"] = sorted((data.get("stock") or {}).get("not_enrolled") or [])
    return json.dumps(keep, sort_keys=True).encode()


def demo_gallery_path(
    world_path: str,
    detector: Any,
    embedder: Any,
    camera: dict | None,
    overrides: dict[str, str] | None = None,
) -> str:
    """The cache file of the demo gallery for this world, camera and pair of models."""
    from drivers.sim.world import load_world

    h = hashlib.sha256()
    data = load_world(world_path, look_overrides(overrides)).data
    h.update(appearance_key(data))
    racks = data.get("racks") or []
    slot = enrolment_slot(data)
    kept = clear_racks(racks, data["pallet_geometry"], slot)
    if len(kept) < len(racks):  # the racks left out of the enrolment scan (none: as before)
        h.update(repr(sorted(r["name"] for r in racks if r not in kept)).encode())
    if slot != CANONICAL_SLOT:  # a world's own enrolment slot (none: the keys as before)
        h.update(repr(sorted(slot.items())).encode())
    h.update(repr(sorted((camera or {}).items())).encode())
    h.update(f"{detector.model_version}|{embedder.model_version}|{ENROL_VERSION}".encode())
    return os.path.join(cache_dir(), "galleries", f"demo-{h.hexdigest()[:16]}.sqlite")


def build_gallery(
    path: str,
    world_path: str,
    identities: list[str],
    detector: Any,
    embedder: Any,
    camera: dict | None,
    log: Callable[[str], None] = print,
    overrides: dict[str, str] | None = None,
    workers: int | None = None,
) -> None:
    """Enrol ``identities`` of the world from rendered enrolment views
    (:func:`enrolment_frames`) into a new gallery at ``path`` (written to a temporary file
    first, then renamed over ``path``). ``workers``: processes rendering and embedding
    (default :data:`BUILD_WORKERS` from 50 sides on, else this process alone); a line of
    progress per :data:`PROGRESS_EVERY` sides (per side for small galleries)."""
    import time

    from perception.gallery import Gallery, GalleryError
    from perception.gallery_stats import BUILD_SECONDS_KEY

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".sqlite", dir=os.path.dirname(os.path.abspath(path)))
    os.close(fd)
    os.unlink(tmp)
    n, start = len(identities), time.perf_counter()
    every = 1 if n <= 50 else PROGRESS_EVERY
    # a generator: nothing starts before the loop below; closed in the end, whatever happens
    sides = _enrolled_sides(world_path, identities, detector, embedder, camera, overrides, workers)
    try:
        with Gallery.create(tmp, embedder.model_version, embedder.dim) as g:
            g.set_thresholds(embedder.thresholds)
            # A temporary file, renamed only once complete: no need to sync every side.
            g.conn.execute("PRAGMA synchronous = OFF")
            for i, (identity, found, vectors, vis, pngs) in enumerate(sides):
                if interrupt_pending():  # btrun run defers a Ctrl-C to its first tick
                    raise KeyboardInterrupt
                if found < 3:
                    raise GalleryError(f"enrolment scan of {identity} found {found} of 3 blocks")
                source = f"rendered scan of {os.path.basename(world_path)}"
                g.enrol(identity, vectors, pngs, source=source, visibility=vis)
                done = i + 1
                if done % every == 0 or done == n:
                    elapsed = time.perf_counter() - start
                    rate = done / max(elapsed, 1e-9)
                    if every == 1:
                        log(f"  enrolled {identity} ({done}/{n})")
                    else:
                        log(
                            f"  enrolled {done}/{n} sides in {elapsed:.0f} s "
                            f"({rate:.1f} sides/s, about {(n - done) / rate:.0f} s left)"
                        )
            with g.conn:  # what `btrun gallery stats` shows as the build time
                g.conn.execute(
                    "INSERT OR REPLACE INTO meta VALUES (?, ?)",
                    (BUILD_SECONDS_KEY, repr(time.perf_counter() - start)),
                )
        os.replace(tmp, path)
    except KeyboardInterrupt:
        log("  interrupted: the demo gallery was not built (nothing half-made is kept)")
        raise
    finally:
        sides.close()  # the worker processes: no side still queued is started
        if os.path.exists(tmp):
            os.unlink(tmp)
    log(f"  {n} sides enrolled in {time.perf_counter() - start:.1f} s")


#: what a build's worker process holds: the world's data, the models, the camera
_WORKER: dict[str, Any] = {}


def _enrolled_sides(
    world_path: str,
    identities: list[str],
    detector: Any,
    embedder: Any,
    camera: dict | None,
    overrides: dict[str, str] | None,
    workers: int | None,
) -> Iterator[tuple[str, int, np.ndarray | None, np.ndarray | None, list[bytes]]]:
    """Per identity, in order: (identity, blocks found, embeddings, visibilities, crops as
    PNG), computed here or in ``workers`` processes (each loads the models from their
    files: torch in a forked child is not safe)."""
    if workers is None:
        workers = BUILD_WORKERS if len(identities) >= 50 else 1
    paths = (getattr(detector, "path", None), getattr(embedder, "path", None))
    jobs = list(enumerate(identities))
    if workers <= 1 or not all(p and os.path.isfile(p) for p in paths):
        _init_worker(world_path, overrides, camera, (detector, embedder))
        try:
            yield from map(_enrol_side, jobs)
        finally:
            _WORKER.clear()
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(world_path, overrides, camera, paths),
    )
    try:
        for side in pool.map(_enrol_side, jobs, chunksize=4):
            versions = side[-1]
            if versions != (detector.model_version, embedder.model_version):
                raise RuntimeError(f"a build worker loaded other models: {versions}")
            yield side[:-1]
    finally:  # stopped early (an error, a Ctrl-C): the sides not started are dropped
        pool.shutdown(wait=True, cancel_futures=True)


def _init_worker(
    world_path: str, overrides: dict[str, str] | None, camera: dict | None, models: tuple
) -> None:
    """Load the world's data once, and the models (objects, or their weights files in a
    worker process, one torch thread each)."""
    from drivers.sim.world import load_world

    worker = isinstance(models[0], str)
    if worker:
        _die_with_parent()
        import cv2

        from perception.detector import BlockDetector

        # one of BUILD_WORKERS processes on as many cores, as torch below: OpenCV's own
        # thread pool would only oversubscribe them (the same pixels either way)
        cv2.setNumThreads(1)
        from perception.embedder import BlockEmbedder

        models = (
            BlockDetector.load(models[0], threads=1),
            BlockEmbedder.load(models[1], threads=1),
        )
    _WORKER.update(
        data=load_world(world_path, look_overrides(overrides)).data,
        world_path=world_path,
        camera=camera,
        detector=models[0],
        embedder=models[1],
        factors=tuple(float(f) for f in (camera or {}).get("white_balance", (1.0, 1.0, 1.0))),
        worker=worker,  # a worker process: say which models it loaded
    )


def _die_with_parent() -> None:
    """Linux: have the kernel kill this build worker when the process that started it dies.
    A killed btrun (SIGKILL, an OOM kill) would otherwise leave its workers waiting forever
    on their task queue, whose write end each of them holds open, with the models and the
    world in memory."""
    import multiprocessing
    import sys

    parent = multiprocessing.parent_process()
    if not sys.platform.startswith("linux") or parent is None:
        return
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent.pid:  # the parent died before the line above
        os._exit(1)


def _enrol_side(job: tuple[int, str]) -> tuple:
    """Render, detect and embed one side (in the process :func:`_init_worker` set up)."""
    from perception.gallery_views import png_bytes

    i, identity = job
    w = _WORKER
    frames = enrolment_frames(w["data"], w["world_path"], identity, w["camera"], 1000 + i)
    crops = scan_blocks(frames, w["detector"], w["factors"])
    if len(crops) < 3:  # the few views missed a block: the whole scan flight, as before
        renderer, poses = _canonical_scan(
            w["data"], w["world_path"], identity, w["camera"], 1000 + i
        )
        whole = ((renderer(pose, pose.t_s), pose.t_s) for pose in poses)
        crops = scan_blocks(whole, w["detector"], w["factors"])
    out: tuple = (identity, len(crops), None, None, [])
    if len(crops) >= 3:
        emb = w["embedder"]
        desc = emb.describe(crops)
        vis = desc.visibility if emb.occlusion_aware else None
        out = (identity, len(crops), desc.vectors, vis, [png_bytes(c) for c in crops])
    if w["worker"]:
        out += ((w["detector"].model_version, w["embedder"].model_version),)
    return out


def ensure_demo_gallery(
    world_path: str,
    detector: Any,
    embedder: Any,
    camera: dict | None,
    log: Callable[[str], None] = print,
    overrides: dict[str, str] | None = None,
) -> str:
    """The demo gallery's path, building it first if it does not exist yet; ``overrides``:
    the rig's ``--set world.KEY`` items (only the look ones count)."""
    from drivers.sim.world import load_world

    path = demo_gallery_path(world_path, detector, embedder, camera, overrides)
    if os.path.exists(path):
        return path
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    # One builder at a time (campaign workers start together): the others wait, then use it.
    with open(path + ".lock", "a") as lock:
        try:
            import fcntl

            fcntl.flock(lock, fcntl.LOCK_EX)
        except (ImportError, OSError):  # no flock here: each builds its own (still atomic)
            pass
        if not os.path.exists(path):
            world = load_world(world_path, look_overrides(overrides))
            identities = world.enrolled_identities()
            log(
                f"building the demo gallery ({len(identities)} pallet sides of "
                f"{os.path.basename(world_path)}) in {path}"
            )
            note = enrolment_note(world.data)
            if note:
                log(f"  note: {note}")
            build_gallery(path, world_path, identities, detector, embedder, camera, log, overrides)
    return path
