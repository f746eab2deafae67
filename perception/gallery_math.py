"""Distances between pallet sides: block by block, stripe visibility aware, over many views.

An embedding row is the concatenation of ``P`` L2-normalised PCB stripe vectors divided by
``sqrt(P)`` (unit norm). Two blocks are compared by the Euclidean distance of their rows,
which equals ``sqrt(mean_p (2 - 2 cos_p))`` over the stripes. When the embedder also says
how visible each stripe is (0 hidden .. 1 visible), a stripe counts with the weight
``w_p = vis_query_p * vis_entry_p``:

    d_block = sqrt( sum_p w_p (2 - 2 cos_p) / sum_p w_p )

so a stripe hidden behind a strap or film in either crop does not count, and with every
stripe visible this is the plain Euclidean distance. A side is compared with an enrolled
side by the mean of its three block distances (the reference rule); with visibilities, a
block counts with the mean visibility of its query stripes (a block mostly hidden counts
little). An identity with several views (a gallery that keeps up) takes, block by block,
its closest view.

Pure numpy; :class:`perception.gallery.Gallery` stores the vectors and calls these.
"""

from __future__ import annotations

import numpy as np

BLOCKS = 3
#: a stripe's weight never drops below this (a fully hidden stripe still divides by > 0)
MIN_STRIPE_WEIGHT = 0.001
#: a block's weight in the side's mean never drops below this
MIN_BLOCK_WEIGHT = 0.05


def stripe_cosines(query: np.ndarray, rows: np.ndarray, parts: int) -> np.ndarray:
    """Cosines (n, 3, parts) between the query's stripes (3, dim) and every row's
    (n, 3, dim); each stripe is renormalised, so rows need not have unit stripes."""
    n = rows.shape[0]
    q = query.reshape(BLOCKS, parts, -1).astype(np.float64)
    g = rows.reshape(n, BLOCKS, parts, -1).astype(np.float64)
    qn = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-12)
    gn = g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-12)
    return np.einsum("nbpd,bpd->nbp", gn, qn)


def stripe_weights(
    query_vis: np.ndarray | None, rows_vis: np.ndarray | None, n: int, parts: int
) -> np.ndarray:
    """Stripe weights (n, 3, parts): product of the two visibilities (1 where unknown)."""
    w = np.ones((n, BLOCKS, parts), np.float64)
    if query_vis is not None:
        w = w * np.asarray(query_vis, np.float64).reshape(1, BLOCKS, parts)
    if rows_vis is not None:
        w = w * np.asarray(rows_vis, np.float64).reshape(n, BLOCKS, parts)
    return np.maximum(w, MIN_STRIPE_WEIGHT)


def weighted_block_distances(cos: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Block distances (n, 3) from stripe cosines and weights (n, 3, parts)."""
    d2 = (weights * (2.0 - 2.0 * cos)).sum(-1) / weights.sum(-1)
    return np.sqrt(np.maximum(d2, 0.0))


def block_weights(query_vis: np.ndarray | None) -> np.ndarray:
    """Weights (3,) of the three blocks in a side's mean: the mean visibility of each query
    block's stripes (all 1 without visibilities)."""
    if query_vis is None:
        return np.ones(BLOCKS)
    return np.maximum(
        np.asarray(query_vis, np.float64).reshape(BLOCKS, -1).mean(1), MIN_BLOCK_WEIGHT
    )


def side_distance(per_block: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean over the last axis (3 blocks) of block distances."""
    return (per_block * weights).sum(-1) / weights.sum()


def closest_views(per_row: np.ndarray, owner: np.ndarray, count: int) -> np.ndarray:
    """Per identity and block, the smallest distance over its views: (count, 3) from
    per-row distances (m, 3) and the identity index of each row (m,). Fast when the first
    ``count`` rows are the identities' own rows in order (the gallery's layout)."""
    if len(owner) >= count and np.array_equal(owner[:count], np.arange(count)):
        out = np.array(per_row[:count], dtype=np.float64)
        rest = slice(count, None)
    else:
        out = np.full((count, per_row.shape[1]), np.inf)
        rest = slice(0, None)
    if len(owner[rest]):
        np.minimum.at(out, owner[rest], per_row[rest])
    return out


def block_distances(
    query: np.ndarray,
    gallery: np.ndarray,
    query_visibility: np.ndarray | None = None,
    gallery_visibility: np.ndarray | None = None,
) -> np.ndarray:
    """Distances of each query block to the same block of every entry: (n, 3).

    ``query`` (3, dim), ``gallery`` (n, 3, dim); the optional visibilities are (3, parts)
    and (n, 3, parts). Without them: plain Euclidean distances of the rows.
    """
    if query_visibility is None and gallery_visibility is None:
        diff = gallery - query[None, :, :]
        return np.sqrt(np.einsum("nbd,nbd->nb", diff, diff))
    vis = query_visibility if query_visibility is not None else gallery_visibility
    parts = int(np.asarray(vis).shape[-1])
    cos = stripe_cosines(query, gallery, parts)
    return weighted_block_distances(
        cos, stripe_weights(query_visibility, gallery_visibility, len(gallery), parts)
    )


__all__ = [
    "BLOCKS",
    "MIN_BLOCK_WEIGHT",
    "MIN_STRIPE_WEIGHT",
    "block_distances",
    "block_weights",
    "closest_views",
    "side_distance",
    "stripe_cosines",
    "stripe_weights",
    "weighted_block_distances",
]
