"""When a gallery may learn from an identification: the update rule.

Pallets age between enrolment and later scans (dirt, stains, dust, scratches, new stamps).
After an identification the gallery may add the scan as another *view* of the identified
side, so the next scan is compared with how the pallet looks now, too. A wrong update
would teach the gallery another pallet, and the next scans of that pallet would then be
answered as this one; so the rule accepts only answers that are confident by a wide
margin, and the views are bounded, recorded and reversible (``btrun gallery history`` /
``rollback``).

:func:`decide` is the whole rule, a pure function of the match, the thresholds and the
distance to the side's enrolment view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class UpdateRule:
    """How confident an identification must be to add its view, and how many views stay.

    Attributes:
        distance_fraction: the best distance must be at most this x ``max_distance``.
        margin_factor: the margin must be at least this x ``min_margin`` ...
        min_margin: ... and at least this much in absolute terms.
        anchor_factor: the scan may be at most this x ``max_distance`` from the side's
            enrolment view (the gallery never drifts step by step to another pallet).
        min_novelty: a scan this close to an existing view adds nothing new (skipped).
        max_views: added views kept per side (the enrolment view is always kept; the
            oldest added view is evicted).
        texture_z, texture_margin: an answer the texture verifier decided (``decided_by``
            ``texture`` or ``embedding+texture``) with at least this score and this lead
            over the next candidate (:mod:`perception.verify`) is confident whatever its
            embedding distance (a pallet that aged drifts in the embedding; its wood's
            texture still proves it).
    """

    distance_fraction: float = 0.75
    margin_factor: float = 2.0
    min_margin: float = 0.15
    anchor_factor: float = 1.25
    min_novelty: float = 0.03
    max_views: int = 4
    texture_z: float = 4.5
    texture_margin: float = 3.5

    def __post_init__(self) -> None:
        if not 0 < self.distance_fraction <= 1.0:
            raise ValueError("distance_fraction must be within (0, 1]: never above max_distance")
        if self.margin_factor < 1.0 or self.min_margin < 0:
            raise ValueError("margin_factor must be >= 1 and min_margin >= 0")
        if self.max_views < 1:
            raise ValueError("max_views must be >= 1")


@dataclass(frozen=True)
class UpdateDecision:
    """Whether to add the view, and why (or why not)."""

    update: bool
    reason: str


def decide(
    match: Any, thresholds: Any, rule: UpdateRule, enrolment_distance: float | None
) -> UpdateDecision:
    """Apply ``rule`` to a :class:`perception.gallery.Match` answered under ``thresholds``.

    Never updates from an answer that is ``unknown`` or only just confident: either the
    blocks' texture decided it by a wide margin (``texture_z``, ``texture_margin``), or the
    best distance is well inside ``max_distance`` (``distance_fraction``), each block too,
    the margin well above ``min_margin`` (``margin_factor``, and ``min_margin``), and the
    scan close enough to the side's enrolment view (``enrolment_distance``).
    """
    if not match.known or match.pallet_id == "unknown":
        return UpdateDecision(False, f"not confident: {match.reason or 'unknown'}")
    if match.distance < rule.min_novelty:
        return UpdateDecision(False, f"distance {match.distance:.3f}: nothing new to learn")
    tz, tm = getattr(match, "texture_z", None), getattr(match, "texture_margin", None)
    if (
        tz is not None
        and "texture" in getattr(match, "decided_by", "")
        and getattr(match, "texture_id", None) == match.pallet_id
        and tz >= rule.texture_z
        and (tm if tm is not None else 0.0) >= rule.texture_margin
    ):
        return UpdateDecision(True, f"texture confirmed: score {tz:.2f}, {tm:.2f} ahead")
    max_d = thresholds.max_distance
    if not math.isfinite(max_d):
        return UpdateDecision(
            False, "the gallery has no distance threshold to be confident against"
        )
    limit = rule.distance_fraction * max_d
    if match.distance > limit:
        return UpdateDecision(
            False, f"distance {match.distance:.3f} above {limit:.3f} for an update"
        )
    need = max(rule.margin_factor * thresholds.min_margin, rule.min_margin)
    if match.margin < need:
        return UpdateDecision(False, f"margin {match.margin:.3f} below {need:.3f} for an update")
    blocks = match.ranking[0][2] if match.ranking else ()
    if any(d > max_d for d in blocks):
        worst = max(blocks)
        return UpdateDecision(False, f"a block is {worst:.3f} away, above {max_d:.3f}")
    if enrolment_distance is not None and enrolment_distance > rule.anchor_factor * max_d:
        return UpdateDecision(
            False,
            f"{enrolment_distance:.3f} from the enrolment view, above "
            f"{rule.anchor_factor * max_d:.3f}",
        )
    if match.distance < rule.min_novelty:
        return UpdateDecision(False, f"distance {match.distance:.3f}: nothing new to learn")
    return UpdateDecision(
        True, f"confident: distance {match.distance:.3f}, margin {match.margin:.3f}"
    )


__all__ = ["UpdateDecision", "UpdateRule", "decide"]
