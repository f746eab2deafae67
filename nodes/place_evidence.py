"""What was seen at one pallet place: its block crops and the gallery's top candidates.

The run folder's ``perception/`` keeps every scan and query crop by number, but nothing there
says which place a crop belongs to. An inventory (``RecordPlace``, a sweep) writes, per place,
beside its rows::

    places/<place>/block_1.png .. block_3.png     the crops that were identified, left to right
    places/<place>/candidates.json                {"place", "candidates": [[identity, distance], ...]}

so the operator console (:mod:`nodes.console`) can show an exception with its photos and
the closest identities, and a review decision can enrol or confirm from the same crops. A
fleet's drones write into their own folders (``drones/<name>/places/...``).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil

import cv2
import numpy as np

from bt_engine.files import atomic_write_text

#: the folder of a run holding one sub-folder per place
PLACES_DIR = "places"
CANDIDATES_FILE = "candidates.json"
#: a place name usable as a folder name (rack-bay-level such as ``A-03-2``, or similar codes)
PLACE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
#: at most this many crops and candidates are kept per place
MAX_CROPS, MAX_CANDIDATES = 8, 20


class PlaceEvidenceError(ValueError):
    """A place name that cannot be a folder name."""


def place_dir(run_dir: str, place: str) -> str:
    """``run_dir/places/<place>``, or :class:`PlaceEvidenceError` if ``place`` could leave
    it (a separator, ``..``, an empty or overlong name)."""
    if not isinstance(place, str) or not PLACE_NAME.fullmatch(place) or ".." in place:
        raise PlaceEvidenceError(f"place {place!r:.80} cannot be a folder name")
    return os.path.join(run_dir, PLACES_DIR, place)


def write_place_evidence(
    run_dir: str,
    place: str,
    crops: list[np.ndarray] | None,
    candidates: list[tuple[str, float]] | None,
) -> None:
    """Write ``places/<place>/block_1.png ..`` (the BGR ``crops``, left to right) and
    ``places/<place>/candidates.json`` (identity and mean distance, best first) into
    ``run_dir``. A place seen again (a resumed or repeated scan) replaces its evidence.
    Raises :class:`PlaceEvidenceError` for a place name that cannot be a folder name."""
    folder = place_dir(run_dir, place)
    os.makedirs(folder, exist_ok=True)
    for name in os.listdir(folder):  # the previous scan's crops, if any
        if name.startswith("block_") and name.endswith(".png"):
            os.remove(os.path.join(folder, name))
    kept = 0
    for crop in list(crops or [])[:MAX_CROPS]:
        img = np.asarray(crop)
        if img.ndim not in (2, 3) or img.size == 0:
            continue
        ok, buf = cv2.imencode(".png", img)
        if ok:
            kept += 1
            with open(os.path.join(folder, f"block_{kept}.png"), "wb") as f:
                f.write(buf.tobytes())
    out = []
    for item in list(candidates or [])[:MAX_CANDIDATES]:
        ident, dist = str(item[0]), float(item[1])
        out.append([ident, round(dist, 4) if math.isfinite(dist) else None])
    doc = {"place": place, "crops": kept, "candidates": out}
    atomic_write_text(os.path.join(folder, CANDIDATES_FILE), json.dumps(doc, indent=1))


def carry_evidence(previous: str, run_dir: str, places: dict[str, str]) -> int:
    """Copy the evidence of the places a resumed run carries over (place -> the drone that
    answered it) from run folder ``previous`` into ``run_dir/places/<place>``, so the
    console shows a carried place's crops and candidates in the run that continues it.
    The previous run's own ``places/<place>`` is taken first (a solo run, or one that
    carried it already), else its drone's ``drones/<drone>/places/<place>``; a place with
    no evidence there, or already holding some here, is left. Symbolic links are not
    followed. Returns the number of places copied."""
    copied = 0
    for place, drone in places.items():
        try:
            target = place_dir(run_dir, place)
        except PlaceEvidenceError:
            continue
        sources = [os.path.join(previous, PLACES_DIR, place)]
        if drone and PLACE_NAME.fullmatch(drone) and ".." not in drone:
            sources.append(os.path.join(previous, "drones", drone, PLACES_DIR, place))
        source = next((s for s in sources if os.path.isdir(s) and not os.path.islink(s)), None)
        if source is None or os.path.exists(target):
            continue
        names = [
            n
            for n in os.listdir(source)
            if (re.fullmatch(r"block_\d+\.png", n) or n == CANDIDATES_FILE)
            and os.path.isfile(os.path.join(source, n))
            and not os.path.islink(os.path.join(source, n))
        ]
        if not names:
            continue
        os.makedirs(target, exist_ok=True)
        for n in names:
            shutil.copyfile(os.path.join(source, n), os.path.join(target, n))
        copied += 1
    return copied
