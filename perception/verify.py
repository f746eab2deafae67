"""Verifying a match on the blocks' own texture: normalised cross-correlation, cohort scaled.

The embedder ranks the gallery; a pallet side that aged since its enrolment (new stains,
dust, a strap across a block) or is seen from farther away can drift far enough in the
embedding space that the ranking is right but the distance no longer proves it. The
verifier looks at the pixels instead: the grain, knots and marks of a block face are a
fingerprint of that piece of wood, and the same face correlates with its enrolment crop
far above any other face, even through dirt, occlusion or a third of the resolution.

Score of a query block against an enrolled block: the largest normalised cross-correlation
of their band-passed grey images over small shifts and scales, leaving out what on the query
is not the block's own face (stains, a strap, a label): :mod:`perception.verify_correlation`,
whose names used elsewhere are importable from here too.

A raw score depends on the block (a plain face correlates less with everything), so it is
scaled by a *cohort*: the same query block's scores against other pallets' blocks (up to
:data:`COHORT_FROM_GALLERY` of the gallery's other sides, the shipped cohort of synthetic
blocks, and the candidates' other blocks) give, over the :data:`COHORT_TOP` best of them,
a mean and a spread, and ``z = (score - mean) / spread``. A side's ``z`` is the mean of
its three blocks' (weighted by how visible each block is, when the embedder says). In
calibration the best candidate of a never-enrolled side stayed below ``z`` 3; the same
side aged or seen from 1.2 m mostly scores above 4 (docs/perception.md, "Texture
verification").

Pure numpy and OpenCV; :class:`perception.gallery.Gallery` calls :func:`verify`.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# the raw scores; the names tests and benches take from here are re-exported (``as``)
from perception.verify_correlation import BORDER as BORDER
from perception.verify_correlation import SCALES as SCALES
from perception.verify_correlation import _band as _band
from perception.verify_correlation import _scores, grey
from perception.verify_correlation import _template as _template
from perception.verify_correlation import block_score as block_score
from perception.verify_correlation import block_scores as block_scores
from perception.verify_correlation import clear_band_cache as clear_band_cache
from perception.verify_correlation import work_size as work_size

#: a spread never below this (a cohort of identical scores would divide by zero)
MIN_SPREAD = 0.02
#: cohort sides taken from the gallery at most (the first ones, in a stable order)
COHORT_FROM_GALLERY = 64
#: a query block is scaled by its this many best cohort scores (its closest impostors)
COHORT_TOP = 16
#: the shipped cohort: grey block crops of synthetic pallets never in any gallery
COHORT_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "weights", "cohort.npz")


@dataclass(frozen=True)
class VerifyThresholds:
    """When the texture decides: a candidate whose side ``z`` is at least ``accept_z`` and
    ``margin_z`` above every other candidate's, and whose second-best block reaches
    ``block_z``, is the answer; an embedding answer whose side ``z`` is below ``veto_z`` is
    not (the texture says it is another pallet).

    ``block_z``: the three blocks of a side are one pallet's wood, so at least two must
    match. One block matching alone is a mark that pallets share (the same stamp at the
    same place, blocks sawn from one beam): on dark wood, where the grain is faint, a
    never-enrolled side scored block ``z`` 14 to 20 on one block and below 1.4 on both
    others, while a genuine side's second-best block was above 2.0 in every accepted scan
    (docs/perception.md)."""

    # calibrated by bench/texture_calibration.py (docs/perception.md): never-enrolled scans
    # reached z 2.85 at most (the grid chose 3.2; 3.3 keeps 0.45 above it); embedding answers
    # that were right, z 2.2 at least
    accept_z: float = 3.3
    margin_z: float = 3.0
    veto_z: float = 1.0
    block_z: float = 2.0


@dataclass(frozen=True)
class Verification:
    """Side ``z`` per candidate (best first) and each one's per-block ``z``."""

    ranking: list[tuple[str, float, tuple[float, ...]]]

    @property
    def best(self) -> tuple[str, float] | None:
        """The best candidate and its ``z`` (None without candidates)."""
        return (self.ranking[0][0], self.ranking[0][1]) if self.ranking else None

    def z_of(self, identity: str) -> float | None:
        """``z`` of one candidate (None if it was not verified)."""
        for ident, z, _ in self.ranking:
            if ident == identity:
                return z
        return None

    def blocks_of(self, identity: str) -> tuple[float, ...] | None:
        """Per-block ``z`` of one candidate (NaN for a block that could not be compared)."""
        for ident, _, blocks in self.ranking:
            if ident == identity:
                return blocks
        return None

    def margin(self) -> float:
        """Best ``z`` minus the runner-up's (infinite with one candidate)."""
        if len(self.ranking) < 2:
            return float("inf")
        return self.ranking[0][1] - self.ranking[1][1]


def agreement(blocks: Sequence[float] | None) -> float:
    """The second-best block ``z`` of a side (``-inf`` with fewer than two blocks
    compared): how well the side matches beyond its single best block."""
    z = sorted((float(v) for v in blocks or () if np.isfinite(v)), reverse=True)
    return z[1] if len(z) >= 2 else float("-inf")


def load_cohort(path: str = COHORT_PATH) -> list[list[np.ndarray]]:
    """The shipped cohort: a list of sides, each three float32 grey block crops."""
    with np.load(path) as z:
        crops, shapes = z["crops"], z["shapes"]
    sides, k = [], 0
    for row in shapes.reshape(-1, 3, 2):
        side = []
        for h, w in row:
            side.append(crops[k : k + h * w].reshape(h, w).astype(np.float32))
            k += h * w
        sides.append(side)
    return sides


@functools.lru_cache(maxsize=1)
def _shipped() -> tuple[tuple[np.ndarray, ...], ...]:
    sides = load_cohort()
    for side in sides:
        for crop in side:
            crop.flags.writeable = False  # shared by every verification (keys remembered)
    return tuple(tuple(side) for side in sides)


def shipped_cohort() -> list[tuple[str, list[np.ndarray]]]:
    """The shipped cohort as ``(name, three grey crops)`` (loaded once)."""
    return [(f"cohort {i}", list(side)) for i, side in enumerate(_shipped())]


def save_cohort(path: str, sides: Sequence[Sequence[np.ndarray]]) -> None:
    """Write sides of three BGR or grey uint8 crops as a cohort file."""
    flat, shapes = [], []
    for side in sides:
        for c in side:
            g = np.clip(grey(c), 0, 255).astype(np.uint8)
            flat.append(g.ravel())
            shapes.append(g.shape[:2])
    np.savez_compressed(
        path, crops=np.concatenate(flat), shapes=np.array(shapes, np.int32).reshape(-1, 3, 2)
    )


def verify(
    query_crops: Sequence[np.ndarray],
    candidates: Sequence[tuple[str, Sequence[Sequence[np.ndarray]]]],
    cohort: Sequence[tuple[str, Sequence[np.ndarray]]],
    block_weights: np.ndarray | None = None,
    cohort_scores: np.ndarray | None = None,
) -> Verification:
    """Side ``z`` of each candidate ``(identity, views)`` (every view three grey crops; a
    candidate takes, block by block, its best view) against the query's three crops.

    Each query block's raw scores are scaled by its scores against ``cohort``
    (``(identity, three grey crops)`` of other pallets; a candidate's own identity there is
    left out of its scale) and against the candidates' *other* blocks (the same look and
    stamp style as the query, whatever the gallery holds): ``z = (score - mean) / std``
    over the :data:`COHORT_TOP` best of these scores, the query's closest impostors (so a
    query that looks like many pallets, painted or stamped alike, is scaled by those).
    ``cohort_scores``: :func:`cohort_scores` of the same query and cohort, computed once
    when one query is verified against several candidate sets (the expensive part)."""
    queries = [grey(c) for c in query_crops]
    colours = [np.asarray(c) if np.asarray(c).ndim == 3 else None for c in query_crops]
    names = [n for n, _ in cohort]
    # The candidates' other blocks are impostors of the query's look (same wood, paint,
    # face generator, stamp style): always in the cohort, whatever the gallery holds.
    cross = [
        [views[0][(b + k) % len(queries)] for b in range(len(queries))]
        for _, views in candidates
        if len(views)
        for k in range(1, len(queries))
    ]
    # Every side's scores in one pass (each query block's template made once per size);
    # the same figures as scoring the cohort, the cross blocks and each candidate apart.
    own = [] if cohort_scores is not None else [side for _, side in cohort]
    views_of = [list(views) for _, views in candidates]
    every = _scores(queries, own + cross + [v for views in views_of for v in views], colours)
    ref = cohort_scores if cohort_scores is not None else every[: len(own)]
    if cross:
        ref = np.concatenate([ref, every[len(own) : len(own) + len(cross)]])
        names = names + [""] * len(cross)
    at = len(own) + len(cross)
    w = np.ones(len(queries)) if block_weights is None else np.asarray(block_weights, float)
    ranking = []
    for (ident, _), views in zip(candidates, views_of, strict=True):
        keep = ref[[i for i, n in enumerate(names) if n != ident]]
        top = np.sort(np.where(np.isfinite(keep), keep, -np.inf), axis=0)[::-1][:COHORT_TOP]
        top = np.where(np.isfinite(top), top, np.nan)
        mean = np.nanmean(top, axis=0)
        spread = np.maximum(np.nanstd(top, axis=0), MIN_SPREAD)
        raw = np.nanmax(every[at : at + len(views)], axis=0) if views else np.full(3, np.nan)
        at += len(views)
        z = (raw - mean) / spread
        ok = np.isfinite(z)
        side = float((z[ok] * w[ok]).sum() / w[ok].sum()) if ok.any() else float("-inf")
        ranking.append((ident, side, tuple(float(v) for v in z)))
    ranking.sort(key=lambda r: -r[1])
    return Verification(ranking)


def cohort_scores(
    query_crops: Sequence[np.ndarray], cohort: Sequence[tuple[str, Sequence[np.ndarray]]]
) -> np.ndarray:
    """Raw scores (len(cohort), 3) of the query's blocks against the cohort's: what
    :func:`verify` scales every candidate by, reusable for one query."""
    queries = [grey(c) for c in query_crops]
    colours = [np.asarray(c) if np.asarray(c).ndim == 3 else None for c in query_crops]
    return _scores(queries, [side for _, side in cohort], colours)


__all__ = [
    "COHORT_PATH",
    "cohort_scores",
    "agreement",
    "VerifyThresholds",
    "Verification",
    "block_score",
    "work_size",
    "grey",
    "load_cohort",
    "save_cohort",
    "shipped_cohort",
    "verify",
]
