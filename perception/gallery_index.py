"""The search index of a gallery: which enrolled sides are worth an exact comparison.

:meth:`perception.gallery.Gallery.match` compares a scan with every active view in two
stages: a fast *screen* over all of them picks a few candidate sides, then the exact
distances (:mod:`perception.gallery_math`, float64) rank those. This module is the screen,
built once per gallery (and again after any change: enrolment, removal, an added view, a
rollback, or a write by another process) from the vectors in memory.

* **Exact screen** (galleries of fewer than :data:`REDUCED_MIN_ROWS` views): float32 dot
  products of the query with every view, every stripe (the same weighted distance as the
  exact stage, in single precision). About 4 ms for 4,000 sides on one core.
* **Reduced screen** (larger galleries): each of a block's stripes projected on the
  :data:`REDUCED_DIMS` principal directions of the gallery's own stripes at that position
  (uncentred PCA: dot products are approximated by dot products of the projections), so a
  query reads 32 numbers per stripe instead of 256. The screen keeps the
  :data:`REDUCED_CANDIDATES` closest sides (not just the few the answer needs) and the
  exact stage re-ranks them: what the projection misses only matters when the right side
  falls out of those. The reduced screen's recall against the exact one is measured on
  real embeddings by ``bench/gallery_scale.py`` (docs/performance.md, "Gallery at site
  scale").

A stripe-projected screen instead of an ANN library (faiss, hnswlib): the distance is not
a plain inner product (each stripe is weighted by its visibility in *both* crops, and a
side takes, block by block, its closest view), which an off-the-shelf index cannot apply
inside its search; and the projections are a vectorised scan that needs no build step
beyond one 256 x 256 eigen-decomposition per stripe position. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from perception.gallery_math import BLOCKS, MIN_STRIPE_WEIGHT, closest_views

#: galleries with at least this many views (enrolments + added views) use the reduced screen
REDUCED_MIN_ROWS = 10_000
#: principal directions kept per stripe position in the reduced screen
REDUCED_DIMS = 32
#: sides the reduced screen hands to the exact stage
REDUCED_CANDIDATES = 256
#: rows sampled to fit the projections (evenly spaced over the gallery)
FIT_ROWS = 4096


@dataclass
class SearchIndex:
    """The screen over ``m`` views of ``count`` sides: ``owner`` (m,) is each view's side
    index (the sides' enrolment views first, in order), ``vis`` (m, 3, parts) the views'
    stripe visibilities or None, ``sq`` (m, 3) the blocks' squared norms. Exact mode keeps
    the unit stripes ``unit`` (m, 3 * parts, dim / parts) and the rows; reduced mode the
    projections ``proj`` (3 * parts, m, r) of the stripes on ``basis`` (3 * parts,
    dim / parts, r) and the stripes' norms ``norms`` (m, 3 * parts)."""

    owner: np.ndarray
    count: int
    parts: int
    vis: np.ndarray | None
    sq: np.ndarray
    rows: np.ndarray | None = None
    unit: np.ndarray | None = None
    basis: np.ndarray | None = None
    proj: np.ndarray | None = None
    norms: np.ndarray | None = None

    @property
    def reduced(self) -> bool:
        """True when the screen uses the stripes' projections."""
        return self.proj is not None

    @classmethod
    def build(
        cls,
        rows: np.ndarray,
        owner: np.ndarray,
        count: int,
        vis: np.ndarray | None,
        parts: int,
        reduced: bool | None = None,
    ) -> SearchIndex:
        """The index of ``rows`` (m, 3, dim) float32; ``reduced`` forces a mode (default:
        reduced from :data:`REDUCED_MIN_ROWS` views on)."""
        m = len(owner)
        rows = np.asarray(rows, np.float32)
        vis32 = None if vis is None else np.asarray(vis, np.float32)
        sq = np.einsum("nbd,nbd->nb", rows, rows)
        stripes = rows.reshape(m, BLOCKS * parts, -1)
        if reduced is None:
            reduced = m >= REDUCED_MIN_ROWS
        if not reduced or stripes.shape[-1] <= REDUCED_DIMS:
            norms = _stripe_norms(stripes)[..., None]
            unit = np.ascontiguousarray(stripes / np.maximum(norms, 1e-12))
            return cls(owner, count, parts, vis32, sq, rows=rows, unit=unit)
        basis = fit_basis(stripes, REDUCED_DIMS)
        proj = np.stack([stripes[:, k, :] @ basis[k] for k in range(basis.shape[0])])
        norms = _stripe_norms(stripes)
        return cls(owner, count, parts, vis32, sq, basis=basis, proj=proj, norms=norms)

    def screen(self, query: np.ndarray, query_vis: np.ndarray | None) -> np.ndarray:
        """Approximate block distances (count, 3) of every side (its closest view per
        block) to ``query`` (3, dim), stripes weighted by ``query_vis`` (3, parts) and the
        views' visibilities when the query has them (:mod:`perception.gallery_math`)."""
        m, parts = len(self.owner), self.parts
        q = np.asarray(query, np.float32)
        qs = q.reshape(BLOCKS * parts, -1)
        qn = np.linalg.norm(qs, axis=-1)
        # einsum, not BLAS: OpenBLAS's threads stall for milliseconds per call when the
        # other core is busy (the mission shares the machine with the simulator).
        if self.proj is not None:
            dots = np.einsum("knr,kr->nk", self.proj, np.einsum("ks,ksr->kr", qs, self.basis))
            if query_vis is None:
                cos = None
                dot_blocks = dots.reshape(m, BLOCKS, parts).sum(-1)
            else:
                cos = dots / np.maximum(self.norms * qn[None, :], 1e-12)
        elif query_vis is None:
            cos = None
            dot_blocks = np.einsum("nbd,bd->nb", self.rows, q)
        else:
            qu = qs / np.maximum(qn[:, None], 1e-12)
            cos = np.einsum("nkd,kd->nk", self.unit, qu)
        if cos is None:
            qsq = np.einsum("bd,bd->b", q, q)
            per_row = np.sqrt(np.maximum(self.sq + qsq[None, :] - 2.0 * dot_blocks, 0.0))
        else:
            per_row = _weighted(cos.reshape(m, BLOCKS, parts), query_vis, self.vis)
        return closest_views(per_row, self.owner, self.count)

    def candidates(
        self, query: np.ndarray, query_vis: np.ndarray | None, weights: np.ndarray, k: int
    ) -> np.ndarray:
        """Sorted indices of the sides the exact stage compares: the screen's ``k`` closest
        by the blocks' weighted mean (``weights`` (3,)), at least
        :data:`REDUCED_CANDIDATES` in reduced mode; every side when there are no more."""
        if self.reduced:
            k = max(k, REDUCED_CANDIDATES)
        if k >= self.count:
            return np.arange(self.count)
        per_block = self.screen(query, query_vis)
        side = per_block @ (np.asarray(weights, np.float64) / float(np.sum(weights)))
        return np.sort(np.argpartition(side, k - 1)[:k])


def _weighted(cos: np.ndarray, query_vis: np.ndarray, rows_vis: np.ndarray | None) -> np.ndarray:
    """Block distances (m, 3) from stripe cosines (m, 3, parts), float32 (the rule of
    :func:`perception.gallery_math.weighted_block_distances`)."""
    w = np.asarray(query_vis, np.float32)[None, :, :]
    if rows_vis is not None:
        w = w * rows_vis
    w = np.maximum(w, np.float32(MIN_STRIPE_WEIGHT))
    w = np.broadcast_to(w, cos.shape)
    d2 = np.einsum("nbp,nbp->nb", w, 2.0 - 2.0 * cos) / w.sum(-1)
    return np.sqrt(np.maximum(d2, 0.0))


def _stripe_norms(stripes: np.ndarray) -> np.ndarray:
    """Norms (m, positions) of stripes (m, positions, s) (einsum: np.linalg.norm takes
    seconds on 40,000 sides)."""
    return np.sqrt(np.einsum("nks,nks->nk", stripes, stripes))


def fit_basis(stripes: np.ndarray, dims: int) -> np.ndarray:
    """Per stripe position, the ``dims`` leading directions (uncentred PCA) of the
    stripes (m, positions, s) of up to :data:`FIT_ROWS` evenly spaced rows:
    (positions, s, dims) float32."""
    m = stripes.shape[0]
    sample = stripes[:: max(1, m // FIT_ROWS)].astype(np.float64)
    basis = []
    for k in range(stripes.shape[1]):
        x = sample[:, k, :]
        _, vecs = np.linalg.eigh(x.T @ x)  # ascending eigenvalues
        basis.append(vecs[:, ::-1][:, :dims])
    return np.ascontiguousarray(np.stack(basis).astype(np.float32))


class TextureSides(Mapping):
    """The sides' grey crops for the texture verifier, decoded when first asked for.

    ``keys``: the identities stored with crops (sorted); ``load(identity)``: that side's
    views' grey crops (enrolment first) or None when they cannot be read. A gallery of
    40,000 sides holds 120,000 crops: decoding them all when the gallery opens took
    seconds and a gigabyte; a match verifies 8 candidates and the cohort's 64 sides, so
    only those are decoded (and kept: the cohort and the sides scanned again are asked
    for again). ``identity in sides`` decodes it (a side whose crops cannot be read is not
    in the mapping, as before)."""

    def __init__(
        self, keys: list[str], load: Callable[[str], list[list[np.ndarray]] | None]
    ) -> None:
        self._keys, self._known = keys, set(keys)
        self._load = load
        self._decoded: dict[str, list[list[np.ndarray]] | None] = {}

    def __getitem__(self, identity: str) -> list[list[np.ndarray]]:
        if identity not in self._known:
            raise KeyError(identity)
        if identity not in self._decoded:
            self._decoded[identity] = self._load(identity)
        views = self._decoded[identity]
        if views is None:
            raise KeyError(identity)
        return views

    def __contains__(self, identity: object) -> bool:
        try:
            self[identity]  # type: ignore[index]
        except KeyError:
            return False
        return True

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def first(self, count: int) -> list[str]:
        """The first ``count`` readable identities (in key order)."""
        out = []
        for k in self._keys:
            if len(out) >= count:
                break
            if k in self:
                out.append(k)
        return out


__all__ = [
    "FIT_ROWS",
    "REDUCED_CANDIDATES",
    "REDUCED_DIMS",
    "REDUCED_MIN_ROWS",
    "SearchIndex",
    "TextureSides",
    "fit_basis",
]
