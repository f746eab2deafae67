"""Verifying a scan 1:1 against the pallet the expected stock names for its place.

A warehouse knows which pallet should stand in each place (its WMS). Where it expects
pallet ``P``, the question is not "which of all the enrolled pallets is this" (an open-set
1:N search, whose thresholds must keep every never-enrolled pallet out against every
enrolled one) but "is this ``P``": one comparison, with a calibrated bar. The bar is still
set so that neither a different enrolled pallet, nor a never-enrolled one, nor a
look-alike of ``P`` (same wood, stamp and wear, other grain) passes as ``P``: the
expected stock is a prior on *which* pallet to compare, never evidence that the scan *is*
it.

:func:`check_expected` compares a scan with ``P``'s enrolled sides (``103`` -> ``103A``,
``103B``; a side name ``103A`` -> that side) on

* the embedding: ``P``'s rank among the gallery's pallets (its best side against every
  other pallet's best side); ``P`` must be among the first :attr:`ExpectedThresholds.max_rank`;
* the blocks' texture (:mod:`perception.verify`): the best of ``P``'s sides must reach
  side ``z`` :attr:`ExpectedThresholds.verify_z` with its second-best block at
  :attr:`ExpectedThresholds.block_z` (two blocks of one pallet's wood must agree).

No margin to a runner-up is asked (that is the open-set test's guard against a
never-enrolled side near two enrolled ones). The thresholds are calibrated by
``bench/verification.py --calibrate`` on held-out generated pallets and stored in
``perception/weights/verification.json``; figures in docs/performance.md.
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from perception.verify import agreement

#: the calibrated thresholds, beside the weights
THRESHOLDS_PATH = os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "weights", "verification.json"
)


@dataclass(frozen=True)
class ExpectedThresholds:
    """When a scan verifies as the expected pallet: its best side's texture ``z`` at least
    ``verify_z``, that side's second-best block ``z`` at least ``block_z``, and the pallet
    among the embedding's ``max_rank`` closest pallets."""

    verify_z: float = 3.3
    block_z: float = 2.0
    max_rank: int = 3


@functools.lru_cache(maxsize=4)
def load_thresholds(path: str = THRESHOLDS_PATH) -> ExpectedThresholds:
    """The calibrated thresholds of ``path`` (the defaults when the file is missing)."""
    if not os.path.exists(path):
        return ExpectedThresholds()
    with open(path, encoding="utf-8") as f:
        data = json.load(f)
    names = {f.name for f in fields(ExpectedThresholds)}
    return ExpectedThresholds(
        **{k: v for k, v in (data.get("thresholds") or {}).items() if k in names}
    )


def pallet_of(identity: str) -> str:
    """The pallet of a side name: ``103B`` -> ``103``, ``7A`` -> ``7`` (a digit followed by
    one letter); any other name is its own pallet. A number is the pallet whatever zeros a
    WMS or a spreadsheet pads it with: ``0111`` and ``00111B`` -> ``111``."""
    s = str(identity).strip()
    if len(s) >= 2 and s[-1].isalpha() and s[-2].isdigit():
        s = s[:-1]
    if s.isascii() and s.isdigit():
        s = s.lstrip("0") or "0"
    return s


def pallet_key(identity: str) -> str:
    """What pallets are compared by: :func:`pallet_of` without case (``PAL-7``, ``pal-7``
    and ``Pal-7B`` are one pallet: a WMS may lower-case the licence plates a gallery holds
    as printed). Display keeps the written form; only comparisons use the key."""
    return pallet_of(identity).casefold()


def sides_of(identities: list[str], pallet: str) -> list[str]:
    """The enrolled sides of ``pallet`` (``103`` -> ``103A``, ``103B``; a side name is its
    own and its pallet's other sides), whatever the case of either."""
    want = pallet_key(pallet)
    return [i for i in identities if i == pallet or pallet_key(i) == want]


@dataclass(frozen=True)
class ExpectedCheck:
    """What the 1:1 comparison with the expected pallet found.

    ``side``: the expected pallet's side that matched best (texture, else embedding);
    ``z``: its texture side ``z`` (None: no crops to compare), ``agreement``: its
    second-best block ``z``; ``distance``: the embedding distance of the pallet's closest
    side and ``rank`` the pallet's rank among the gallery's pallets (1: the closest; None:
    beyond the ranking looked at); ``verified`` and ``reason`` (why not)."""

    expected: str
    side: str | None
    verified: bool
    reason: str
    z: float | None = None
    agreement: float | None = None
    distance: float | None = None
    rank: int | None = None
    blocks: tuple[float, ...] | None = None


def pallet_rank(ranking: list[tuple[str, float, Any]], pallet: str) -> tuple[int | None, Any]:
    """(1-based rank of ``pallet`` among the distinct pallets of an embedding ranking, its
    best entry) or (None, None) when it is not in the ranking."""
    seen: list[str] = []
    want = pallet_key(pallet)
    for entry in ranking:
        p = pallet_key(entry[0])
        if p == want:
            return len(seen) + 1, entry
        if p not in seen:
            seen.append(p)
    return None, None


def check_expected(
    gallery: Any,
    vectors: np.ndarray,
    visibility: np.ndarray | None,
    crops: list[np.ndarray],
    expected: str,
    thresholds: ExpectedThresholds | None = None,
    cohort_scores: np.ndarray | None = None,
) -> ExpectedCheck:
    """Is the scan (three block embeddings, their stripe visibilities, the three BGR crops)
    the ``expected`` pallet? See the module doc; ``cohort_scores`` as in
    :meth:`perception.gallery.Gallery.verify_sides`."""
    th = thresholds or load_thresholds()
    sides = sides_of(gallery.identities(), expected)
    if not sides:
        return ExpectedCheck(expected, None, False, f"{expected} is not enrolled in the gallery")
    ranked = gallery.match(vectors, top_k=max(2 * th.max_rank + 2, 5), visibility=visibility)
    rank, entry = pallet_rank(ranked.ranking, expected)
    distance = float(entry[1]) if entry is not None else None
    ver = gallery.verify_sides(crops, sides, visibility, cohort_scores)
    if ver is None or ver.best is None:
        return ExpectedCheck(
            expected,
            entry[0] if entry else None,
            False,
            f"{expected}'s sides have no stored crops to verify against",
            distance=distance,
            rank=rank,
        )
    side, z = ver.best
    blocks = ver.blocks_of(side)
    agree = agreement(blocks)
    check = ExpectedCheck(
        expected, side, False, "", z, agree if math.isfinite(agree) else None, distance, rank,
        blocks,
    )  # fmt: skip
    why = []
    if z < th.verify_z:
        why.append(f"texture score {_below(z, th.verify_z)}")
    if not agree >= th.block_z:
        why.append(f"second-best block {_below(agree, th.block_z)}")
    if rank is None or rank > th.max_rank:
        where = "beyond" if rank is None else f"{rank},"
        why.append(f"embedding rank {where} needs <= {th.max_rank}")
    if why:
        return replace(check, reason=f"not {expected}: " + "; ".join(why))
    return replace(check, verified=True)


def _below(value: float, threshold: float) -> str:
    """``3.21 below 3.30``, with as many decimals as it takes for the two to differ
    (``3.296 below 3.30``, not ``3.30 below 3.30``)."""
    for digits in (2, 3, 4):
        shown = f"{value:.{digits}f}"
        if shown != f"{threshold:.{digits}f}":
            return f"{shown} below {threshold:.2f}"
    return f"{value:.6g} below {threshold:.6g}"


__all__ = [
    "THRESHOLDS_PATH",
    "ExpectedCheck",
    "ExpectedThresholds",
    "check_expected",
    "load_thresholds",
    "pallet_key",
    "pallet_of",
    "pallet_rank",
    "sides_of",
]
