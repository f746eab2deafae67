"""Enrolment scans without a flight, and the demo gallery built from them.

An enrolment scan renders what the AI-deck camera sees while it moves along a canonical scan
line in front of one pallet side (standing alone in a canonical slot), and runs it through
the same detector and block sequencer as a mission. The three committed
crops are embedded and enrolled.

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
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

ENROL_SPEED_MPS = 0.1  # camera speed along the scan line while enrolling
ENROL_RATE_HZ = 15.0
ENROL_VERSION = 5  # bump when enrolment or the renderer changes (invalidates cached galleries)


def cache_dir() -> str:
    """Where btrun keeps generated files (``$BTRUN_CACHE_DIR`` or ``~/.cache/btrun``)."""
    root = os.environ.get("BTRUN_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "btrun")
    return root


#: Where every side is enrolled, whatever the world's slots say: the face centre at
#: (9.30, 0.0), facing -x, the block row at 0.255 m (on a stand), seen from a line 0.40 m in
#: front of it from 0.75 m right of the centre to 0.65 m left (blocks enter left of the image
#: centre and leave right of it, as the block sequencer needs).
CANONICAL_SLOT = {"x_m": 9.30, "y_m": 0.0, "facing_deg": 180.0}
CANONICAL_ROW_Z_M = 0.255
CANONICAL_LINE = {"x_m": 8.90, "y_from_m": -0.75, "y_to_m": 0.65, "yaw_deg": 0.0}


def canonical_world_data(data: dict, identity: str) -> dict:
    """The world of an enrolment scan: ``identity`` alone in the canonical slot (the
    world's pallets, geometry, lighting and floor; no other pallet, no obstacle, no placement
    error), as it looked when enrolled (no ageing)."""
    import copy

    g = data["pallet_geometry"]
    out = copy.deepcopy(data)
    base_z = CANONICAL_ROW_Z_M - g["board_m"] - g["block_height_m"] / 2.0
    out["scan_slot"] = dict(CANONICAL_SLOT, z_m=base_z)
    out["scan_pallet"] = identity
    out["row_slots"] = []
    out["obstacles"] = []
    for key in ("placement_error", "placement_offset"):
        out[key] = {k: 0.0 for k in out.get(key, {})}
    out["scan_line"] = dict(CANONICAL_LINE, z_m=CANONICAL_ROW_Z_M)
    return unaged(out)


def unaged(data: dict) -> dict:
    """The world's pallets as they were enrolled: every ``age`` (since enrolment) at 0."""
    import copy

    out = copy.deepcopy(data)
    out["pallet_look"] = dict(out.get("pallet_look") or {}, age=0.0)
    for p in out.get("pallets") or []:
        for s in (p.get("sides") or {}).values():
            if isinstance(s, dict):
                s["age"] = 0.0
    return out


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


def look_overrides(overrides: dict[str, str] | None) -> dict[str, str]:
    """The ``--set world.KEY`` items that change how the pallets look (``pallet_look.*``):
    the demo gallery enrols the pallets as the flight will see them (ageing aside)."""
    return {k: v for k, v in (overrides or {}).items() if k.startswith("pallet_look.")}


def scan_frames(
    world_path: str,
    identity: str,
    camera: dict | None,
    seed: int = 0,
    overrides: dict[str, str] | None = None,
) -> Iterator[tuple[np.ndarray, float]]:
    """Raw frames (and their times) of a camera moving along the canonical scan line in front
    of ``identity`` standing alone in the canonical slot; motion blur from the scan speed."""
    from drivers.sim.renderers.pallet import PalletRenderer
    from drivers.sim.world import World, load_world
    from drivers.vehicle.types import Pose

    data = canonical_world_data(load_world(world_path, look_overrides(overrides)).data, identity)
    world = World(data, world_path)
    line = data["scan_line"]
    renderer = PalletRenderer(world, camera, np.random.default_rng(seed))
    yaw = math.radians(line["yaw_deg"])
    quaternion = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    y0, y1 = line["y_from_m"], line["y_to_m"]
    step = math.copysign(ENROL_SPEED_MPS / ENROL_RATE_HZ, y1 - y0)
    n = int(abs(y1 - y0) / abs(step)) + 1
    for k in range(n):
        t = k / ENROL_RATE_HZ
        pose = Pose(line["x_m"], y0 + k * step, line["z_m"], yaw, quaternion, t, "enrol")
        yield renderer(pose, t), t


def scan_blocks(
    frames: Iterator[tuple[np.ndarray, float]],
    detector: Any,
    factors: tuple[float, float, float],
    min_score: float | None = None,
) -> list[np.ndarray]:
    """The crops the block sequencer commits over a stream of raw frames (stops at three)."""
    from perception.sequencer import BlockSequencer
    from perception.white_balance import preprocess

    seq = BlockSequencer()
    for raw, t in frames:
        bgr = preprocess(raw, factors)
        seq.update(bgr, detector.detect(bgr, min_score=min_score), t)
        if seq.done:
            break
    return [b.crop for b in seq.blocks]


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
    h.update(appearance_key(load_world(world_path, look_overrides(overrides)).data))
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
) -> None:
    """Enrol ``identities`` of the world from rendered scans into a new gallery at ``path``
    (written to a temporary file first, then renamed over ``path``)."""
    from perception.gallery import Gallery, GalleryError
    from perception.gallery_views import png_bytes

    factors = tuple(float(f) for f in (camera or {}).get("white_balance", (1.0, 1.0, 1.0)))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".sqlite", dir=os.path.dirname(os.path.abspath(path)))
    os.close(fd)
    os.unlink(tmp)
    try:
        with Gallery.create(tmp, embedder.model_version, embedder.dim) as g:
            g.set_thresholds(embedder.thresholds)
            for i, identity in enumerate(identities):
                crops = scan_blocks(
                    scan_frames(world_path, identity, camera, 1000 + i, overrides),
                    detector,
                    factors,
                )
                if len(crops) < 3:
                    raise GalleryError(
                        f"enrolment scan of {identity} found {len(crops)} of 3 blocks"
                    )
                desc = embedder.describe(crops)
                g.enrol(
                    identity,
                    desc.vectors,
                    [png_bytes(c) for c in crops],
                    source=f"rendered scan of {os.path.basename(world_path)}",
                    visibility=desc.visibility if embedder.occlusion_aware else None,
                )
                log(f"  enrolled {identity} ({i + 1}/{len(identities)})")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


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
            identities = load_world(world_path).enrolled_identities()
            log(
                f"building the demo gallery ({len(identities)} pallet sides of "
                f"{os.path.basename(world_path)}) in {path}"
            )
            build_gallery(path, world_path, identities, detector, embedder, camera, log, overrides)
    return path
