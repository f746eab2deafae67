"""Matching a scanned side against a gallery: the ranking, the margin, "unknown".

The :class:`MatchingMixin` half of :class:`perception.gallery.Gallery`: every active view
of every side in memory, a fast float32 screen over all of them, exact distances for the
best candidates (:mod:`perception.gallery_math` has the maths), and the decision.

With the query's crops, the best candidates are also verified on the blocks' texture
against their enrolment crops (:mod:`perception.verify`): a candidate whose texture
matches far above every other pallet's is the answer even when the embedding distance
alone would say "unknown" (new stains, dust, a strap, a farther view), and an embedding
answer whose texture does not match is refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from perception import gallery_math as gm
from perception import verify as tv
from perception.errors import GalleryError
from perception.gallery_index import SearchIndex, TextureSides
from perception.gallery_math import BLOCKS, block_distances

#: embedding candidates verified on texture (best first)
VERIFY_CANDIDATES = 8
#: the texture may name only one of the embedding's this many best candidates (it confirms
#: or re-orders the closest few; the others are verified to scale the margin). A
#: never-enrolled side of the other face generator, sharing stamps at the same places with
#: an enrolled side the embedding ranked 6th or lower, scored z 3.45; every genuine side the
#: texture accepted under dark wood, plank faces and overhanging loads was the embedding's
#: first
TEXTURE_TOP_RANK = 3


@dataclass(frozen=True)
class Match:
    """The answer of :meth:`Gallery.match`.

    ``pallet_id`` is the best entry's identity, or ``"unknown"`` when a threshold failed;
    ``best_id`` is always the closest entry. ``ranking`` lists ``(identity, mean distance,
    per-block distances)`` best first. With texture verification: ``texture_id`` is the
    candidate whose blocks' texture matches best, ``texture_z`` its score and
    ``texture_margin`` its lead over the next candidate, ``texture_blocks`` its per-block
    ``z``; ``decided_by`` says which test gave the answer (``embedding``, ``texture``, or
    ``embedding+texture`` when both agree). ``expected``: the pallet the expected stock
    names for the place (:mod:`perception.expected`), ``verified_expected`` true when the
    scan verified 1:1 as that pallet (``decided_by`` ``verified``).
    """

    pallet_id: str
    best_id: str
    distance: float
    runner_up_id: str | None
    runner_up_distance: float | None
    margin: float
    known: bool
    reason: str
    ranking: list[tuple[str, float, tuple[float, ...]]] = field(default_factory=list)
    texture_id: str | None = None
    texture_z: float | None = None
    texture_margin: float | None = None
    texture_blocks: tuple[float, ...] | None = None
    decided_by: str = "embedding"
    expected: str | None = None
    verified_expected: bool = False


@dataclass(frozen=True)
class Thresholds:
    """When to answer "unknown": best mean distance above ``max_distance`` or a margin to the
    runner-up below ``min_margin``."""

    max_distance: float = float("inf")
    min_margin: float = 0.0


@dataclass
class _Rows:
    """Every active view in memory: identities, rows (m, 3, dim), owner index (m,),
    stripe visibilities (m, 3, parts) or None, and the screen over them
    (:class:`perception.gallery_index.SearchIndex`)."""

    ids: list[str]
    rows: np.ndarray
    owner: np.ndarray
    vis: np.ndarray | None
    index: SearchIndex | None = None


class MatchingMixin:
    """Matching for :class:`perception.gallery.Gallery` (it provides ``conn``, ``dim``,
    ``path``, ``thresholds``, ``matrix()``, ``_check_visibility()`` and ``_rows``)."""

    def _all_rows(self, parts: int) -> _Rows:
        """Every active view (enrolment views first per identity), cached per stripe count."""
        if parts in self._rows:
            return self._rows[parts]
        ids, enrol = self.matrix()
        index = {ident: i for i, ident in enumerate(ids)}
        vis_rows = dict(self.conn.execute("SELECT identity, stripes FROM visibility").fetchall())
        added = self.conn.execute(
            "SELECT identity, embeddings, stripes FROM views WHERE active ORDER BY view_id"
        ).fetchall()
        rows = [enrol] + [
            np.frombuffer(e, np.float32).reshape(1, BLOCKS, self.dim) for _, e, _ in added
        ]
        owner = np.concatenate(
            [np.arange(len(ids)), np.array([index[i] for i, _, _ in added], int)]
        ).astype(np.int64)
        blobs = [vis_rows.get(i) for i in ids] + [s for _, _, s in added]
        vis = None
        if any(b is not None for b in blobs):
            vis = np.ones((len(owner), BLOCKS, parts), np.float32)
            for k, b in enumerate(blobs):
                if b is not None:
                    v = np.frombuffer(b, np.float32)
                    if v.size == BLOCKS * parts:
                        vis[k] = v.reshape(BLOCKS, parts)
        all_rows = np.concatenate(rows) if len(rows) > 1 else enrol  # no copy without views
        index = SearchIndex.build(all_rows, owner, len(ids), vis, parts)
        self._rows[parts] = _Rows(ids, all_rows, owner, vis, index)
        return self._rows[parts]

    def prepare_search(self, parts: int = 1) -> None:
        """Read every view and build the search index now (before flight: 40,000 sides take
        seconds) for queries with ``parts`` stripe visibilities per block (1: none)."""
        self._check_changed()
        if self.matrix()[0]:
            self._all_rows(parts)

    def _check_changed(self) -> None:
        """Forget the vectors and crops in memory when another connection (another process:
        an enrolment, a flight adding a view) committed a change to the file since they
        were read (SQLite's ``data_version``; this connection's own writes invalidate them
        as they happen)."""
        version = self.conn.execute("PRAGMA data_version").fetchone()[0]
        if version != getattr(self, "_data_version", version):
            self._invalidate()
        self._data_version = version

    # -- matching --------------------------------------------------------------------------
    def match(
        self,
        query: np.ndarray,
        top_k: int = 5,
        thresholds: Thresholds | None = None,
        visibility: np.ndarray | None = None,
        crops: list[np.ndarray] | None = None,
        verify_thresholds: tv.VerifyThresholds | None = None,
    ) -> Match:
        """Match three block embeddings (left to right) against every entry.

        Distance between two blocks: Euclidean distance of the embeddings, stripes weighted
        by their visibility in both crops when known (``visibility``: (3, parts) of the
        query); per entry: the mean of the three block distances (the reference rule), each
        block taken from the entry's closest view. With the query's three BGR ``crops``, the
        best candidates are verified on texture (:meth:`_decide_with_texture`).
        """
        q = np.asarray(query, dtype=np.float32)
        if q.shape != (BLOCKS, self.dim):
            raise GalleryError(
                f"match: expected a query of shape {(BLOCKS, self.dim)}, got {q.shape}"
            )
        qvis = self._check_visibility("match", visibility)
        self._check_changed()
        ids, _ = self.matrix()
        if not ids:
            raise GalleryError(f"{self.path}: the gallery is empty: enrol pallets first")
        parts = qvis.shape[1] if qvis is not None else 1
        data = self._all_rows(parts)
        weights = gm.block_weights(qvis)
        cand = data.index.candidates(q, qvis, weights, max(top_k, 2) + 16)  # type: ignore[union-attr]
        exact = self._exact(q, qvis, data, cand)
        means = gm.side_distance(exact, weights)
        local = np.argsort(means, kind="stable")
        order, per_block, means = cand[local], exact[local], means[local]
        th = thresholds or self.thresholds
        best = int(order[0])
        second = int(order[1]) if len(order) > 1 else None
        d1 = float(means[0])
        d2 = float(means[1]) if second is not None else None
        margin = (d2 - d1) if d2 is not None else float("inf")
        reason = ""
        if d1 > th.max_distance:
            reason = f"best distance {d1:.3f} above the threshold {th.max_distance:.3f}"
        elif margin < th.min_margin:
            reason = f"margin {margin:.3f} to {ids[second]} below the threshold {th.min_margin:.3f}"
        ranking = [
            (ids[i], float(means[j]), tuple(float(x) for x in per_block[j]))
            for j, i in enumerate(order[:top_k])
        ]
        match = Match(
            pallet_id=ids[best] if not reason else "unknown",
            best_id=ids[best],
            distance=d1,
            runner_up_id=ids[second] if second is not None else None,
            runner_up_distance=d2,
            margin=margin,
            known=not reason,
            reason=reason,
            ranking=ranking,
        )
        if crops is None:
            return match
        candidates = [ids[int(i)] for i in order[:VERIFY_CANDIDATES]]
        return self._decide_with_texture(
            match, crops, candidates, weights, verify_thresholds or tv.VerifyThresholds()
        )

    # -- texture verification ---------------------------------------------------------------
    def _texture_sides(self) -> TextureSides:
        """Per side stored with its three crops, its views' grey crops: the enrolment's
        first, then every active added view's (decoded when first asked for, then kept)."""
        if self._grey is None:
            keys = [
                r[0]
                for r in self.conn.execute(
                    "SELECT identity FROM crops GROUP BY identity HAVING COUNT(*) >= ? "
                    "ORDER BY identity",
                    (BLOCKS,),
                )
            ]
            self._grey = TextureSides(keys, self._grey_side)
        return self._grey

    def _grey_side(self, identity: str) -> list[list[np.ndarray]] | None:
        """One side's views' grey crops (enrolment first), None if unreadable."""
        enrol = self.conn.execute(
            "SELECT identity, block, png FROM crops WHERE identity = ? ORDER BY block",
            (identity,),
        )
        first = _grey_views(enrol).get(identity)
        if first is None:
            return None
        added = self.conn.execute(
            "SELECT c.view_id, c.block, c.png FROM view_crops c JOIN views v "
            "ON v.view_id = c.view_id WHERE v.active AND v.identity = ? ORDER BY 1, 2",
            (identity,),
        )
        return [first, *_grey_views(added).values()]

    def _texture_cohort(self) -> list[tuple[str, list[np.ndarray]]]:
        """The verifier's cohort: up to :data:`perception.verify.COHORT_FROM_GALLERY` of the
        gallery's sides (each candidate's own is left out of its scale) and the shipped
        cohort."""
        sides = self._texture_sides()
        own = [(k, sides[k][0]) for k in sides.first(tv.COHORT_FROM_GALLERY)]
        return own + tv.shipped_cohort()

    def verify_sides(
        self,
        crops: list[np.ndarray],
        identities: list[str],
        visibility: np.ndarray | None = None,
        cohort_scores: np.ndarray | None = None,
    ) -> tv.Verification | None:
        """The texture ``z`` of the query's three BGR ``crops`` against these sides only
        (a 1:1 verification against an expected pallet's sides, :mod:`perception.expected`),
        scaled by the same cohort as :meth:`match`; None if none of them has stored crops.
        ``cohort_scores``: :meth:`texture_cohort_scores` of the same crops, reused."""
        if len(crops) != BLOCKS:
            raise GalleryError(f"verify: expected {BLOCKS} crops, got {len(crops)}")
        sides = self._texture_sides()
        cands = [(c, sides[c]) for c in identities if c in sides]
        if not cands:
            return None
        qvis = self._check_visibility("verify", visibility)
        weights = gm.block_weights(qvis)
        return tv.verify(crops, cands, self._texture_cohort(), weights, cohort_scores)

    def texture_cohort_scores(self, crops: list[np.ndarray]) -> np.ndarray:
        """The query's raw scores against the verifier's cohort (for :meth:`verify_sides`
        when one scan is verified against several pallets)."""
        return tv.cohort_scores(crops, self._texture_cohort())

    def _decide_with_texture(
        self,
        match: Match,
        crops: list[np.ndarray],
        candidates: list[str],
        weights: np.ndarray,
        th: tv.VerifyThresholds,
    ) -> Match:
        """The answer once the candidates' texture is known.

        * the texture's best candidate scores at least ``accept_z``, leads the next by
          ``margin_z``, its second-best block reaches ``block_z`` and it is among the
          embedding's :data:`TEXTURE_TOP_RANK` best: it is the answer (whatever the
          embedding distance says);
        * otherwise an embedding answer stands if its own texture score is at least
          ``veto_z``, and is refused ("unknown") if it is not;
        * candidates without stored crops are not verified (an embedding answer among them
          stands as it is).
        """
        if len(crops) != BLOCKS:
            raise GalleryError(f"match: expected {BLOCKS} crops, got {len(crops)}")
        sides = self._texture_sides()
        cands = [(c, sides[c]) for c in candidates if c in sides]
        if not cands:
            return match
        ver = tv.verify(crops, cands, self._texture_cohort(), weights)
        tid, tz = ver.best  # type: ignore[misc]
        tmargin = ver.margin()
        blocks = ver.blocks_of(tid)
        agree = tv.agreement(blocks)
        out = {
            "texture_id": tid,
            "texture_z": tz,
            "texture_margin": tmargin,
            "texture_blocks": blocks,
        }
        near = candidates.index(tid) < TEXTURE_TOP_RANK
        if tz >= th.accept_z and tmargin >= th.margin_z and agree >= th.block_z and near:
            if match.known and match.pallet_id != tid:
                reason = (
                    f"the embedding says {match.pallet_id}, the blocks' texture {tid} "
                    f"(score {tz:.2f}): they disagree"
                )
                return replace(match, pallet_id="unknown", known=False, reason=reason, **out)
            by = "embedding+texture" if match.known else "texture"
            return replace(match, pallet_id=tid, known=True, reason="", decided_by=by, **out)
        if match.known:
            z = ver.z_of(match.pallet_id)
            if z is not None and z < th.veto_z:
                reason = (
                    f"the blocks' texture does not match {match.pallet_id} "
                    f"(score {z:.2f} below {th.veto_z:.2f})"
                )
                return replace(match, pallet_id="unknown", known=False, reason=reason, **out)
            return replace(match, **out)
        reason = (
            f"{match.reason}; texture: {tid} scores {tz:.2f} (needs {th.accept_z:.2f}), "
            f"{tmargin:.2f} ahead (needs {th.margin_z:.2f}), second-best block {agree:.2f} "
            f"(needs {th.block_z:.2f}), embedding rank {candidates.index(tid) + 1} "
            f"(needs <= {TEXTURE_TOP_RANK})"
        )
        return replace(match, reason=reason, **out)

    def _exact(
        self, q: np.ndarray, qvis: np.ndarray | None, data: _Rows, cand: np.ndarray
    ) -> np.ndarray:
        """Exact block distances (len(cand), 3) of the candidate identities (float64)."""
        sel = np.flatnonzero(np.isin(data.owner, cand))
        rows = data.rows[sel].astype(np.float64)
        if qvis is None:
            per_row = block_distances(q.astype(np.float64), rows)
        else:
            rvis = data.vis[sel] if data.vis is not None else None
            per_row = block_distances(q, rows, qvis, rvis)
        return gm.closest_views(per_row, np.searchsorted(cand, data.owner[sel]), len(cand))


def _grey_views(rows) -> dict[str, list[np.ndarray]]:
    """Rows ``(key, block, png)`` in key and block order -> key: three grey crops (keys
    with fewer than three readable crops are left out)."""
    out: dict[str, list[np.ndarray]] = {}
    for key, _, png in rows:
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
        if img is not None and min(img.shape[:2]) >= 2:
            grey = img.astype(np.float32)
            grey.flags.writeable = False  # kept and shared: the verifier remembers its key
            out.setdefault(key, []).append(grey)
    return {k: v for k, v in out.items() if len(v) == BLOCKS}


__all__ = ["Match", "MatchingMixin", "Thresholds"]
