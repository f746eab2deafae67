"""Verification first, identification second: the answer for one scanned pallet side.

Where the expected stock names a pallet for the place (``InventoryLog.expected_at``), the
scan is first verified 1:1 against that pallet's enrolled sides with the calibrated
verification thresholds (:mod:`perception.expected`). Only if it does not verify is it
identified 1:N against the whole gallery, open set (``Gallery.match``: ``unknown`` when no
side is close and clear enough, texture-verified). The expectation only chooses which
pallet to compare first: a scan that does not match it well enough is never called it.

:func:`identify_scan` is the one place this decision is made; ``IdentifyPallet`` calls
it, and so can any leaf that has a place's three block crops.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from nodes.inventory_log import InventoryLog
from perception.expected import ExpectedThresholds, check_expected, load_thresholds, pallet_of
from perception.gallery import Match, Thresholds

#: ``decided_by`` of an answer verified 1:1 against the expected pallet
VERIFIED = "verified"


def expected_for(ctx: Any, place: str | None) -> str | None:
    """The pallet the run's expected stock names for ``place`` (None: no expected stock,
    the place is not listed, or it should be empty: nothing to verify against)."""
    if not place:
        return None
    log = ctx.resources.get("inventory")
    if not isinstance(log, InventoryLog):
        return None
    return log.expected_at(place.strip()) or None


def identify_scan(
    gallery: Any,
    embedder: Any,
    crops: list[np.ndarray],
    thresholds: Thresholds,
    *,
    expected: str | None,
    top_k: int = 5,
    verify_texture: bool = True,
    verify_thresholds: ExpectedThresholds | None = None,
) -> Match:
    """The answer for three BGR block crops (left to right): embed them, verify 1:1
    against ``expected`` (a pallet, ``103``, or a side, ``103A``; None: nothing expected),
    else identify 1:N (open set, ``thresholds``; texture-verified with ``verify_texture``).

    The result is a :class:`perception.gallery.Match`: ``pallet_id`` (a side or
    ``unknown``), ``best_id``, ``distance``, ``margin``, ``known``, ``reason``,
    ``decided_by`` (``verified`` when the expected pallet verified), ``expected`` and
    ``verified_expected``."""
    desc = embedder.describe(crops)
    vis = desc.visibility if embedder.occlusion_aware else None
    return identify_described(
        gallery,
        desc.vectors,
        vis,
        crops,
        thresholds,
        expected=expected,
        top_k=top_k,
        verify_texture=verify_texture,
        verify_thresholds=verify_thresholds,
    )


def identify_described(
    gallery: Any,
    vectors: np.ndarray,
    visibility: np.ndarray | None,
    crops: list[np.ndarray],
    thresholds: Thresholds,
    *,
    expected: str | None,
    top_k: int = 5,
    verify_texture: bool = True,
    verify_thresholds: ExpectedThresholds | None = None,
) -> Match:
    """:func:`identify_scan` on embeddings already computed (``vectors``, their stripe
    ``visibility``) and the crops they came from."""
    why = ""
    if expected and verify_texture:
        check = check_expected(
            gallery, vectors, visibility, crops, expected, verify_thresholds or load_thresholds()
        )
        if check.verified:
            ranked = gallery.match(
                vectors, top_k=top_k, thresholds=thresholds, visibility=visibility
            )
            return _verified(ranked, check)
        why = check.reason
    elif expected:
        why = "no 1:1 verification without the blocks' texture (verify_texture false)"
    match = gallery.match(
        vectors,
        top_k=top_k,
        thresholds=thresholds,
        visibility=visibility,
        crops=crops if verify_texture else None,
    )
    if not expected:
        return match
    reason = match.reason
    if not match.known and why:
        reason = f"{reason}; {why}" if reason else why
    return replace(match, expected=expected, reason=reason)


def _verified(ranked: Match, check: Any) -> Match:
    """The ranking's match turned into the verified answer ``check.side``: its own
    embedding distance, and its lead over the closest side of any other pallet."""
    mine = [d for ident, d, _ in ranked.ranking if ident == check.side]
    distance = mine[0] if mine else (check.distance if check.distance is not None else math.nan)
    others = [d for ident, d, _ in ranked.ranking if pallet_of(ident) != pallet_of(check.side)]
    margin = (others[0] - distance) if others else float("inf")
    return replace(
        ranked,
        pallet_id=check.side,
        distance=float(distance),
        margin=float(margin),
        known=True,
        reason="",
        decided_by=VERIFIED,
        texture_id=check.side,
        texture_z=check.z,
        texture_margin=None,
        texture_blocks=check.blocks,
        expected=check.expected,
        verified_expected=True,
    )


__all__ = ["VERIFIED", "expected_for", "identify_described", "identify_scan"]
