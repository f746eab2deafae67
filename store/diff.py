"""Comparing the store's runs: what changed between two inventories, place by place, and
what flew a run (two runs of different rigs or fleets may be two sites)."""

from __future__ import annotations

import os


def diff_rows(rows_a: list[dict], rows_b: list[dict]) -> list[dict]:
    """What changed from the inventory rows ``rows_a`` to ``rows_b`` (see
    :meth:`store.inventory.InventoryStore.diff`), place by place; unchanged places are
    left out."""
    a = {r["place"]: r for r in rows_a}
    b = {r["place"]: r for r in rows_b}
    out = []
    for place in sorted(set(a) | set(b)):
        ra, rb = a.get(place), b.get(place)
        x, y = (ra or {}).get("answer") or "", (rb or {}).get("answer") or ""
        kx, ky = _key(x), _key(y)
        if kx == ky:  # the same answer, in another case or zero padding (pal-7A, PAL-7A)
            continue
        if not x:
            change = "only in B"
        elif not y:
            change = "only in A"
        elif x == "empty":
            change = "appeared"
        elif y == "empty":
            change = "disappeared"
        elif _side_of(kx) is not None and _side_of(kx) == _side_of(ky):
            change = "turned"
        else:
            change = "changed"
        out.append(
            {
                "place": place,
                "change": change,
                "a": x or None,
                "b": y or None,
                "a_status": (ra or {}).get("status"),
                "b_status": (rb or {}).get("status"),
            }
        )
    return out


def flown_by(run: dict) -> str | None:
    """What flew a run (a :meth:`InventoryStore.run` or history row): ``fleet NAME``, or
    ``rig NAME`` (the rig file's name without its folder and ``.yaml``), None if the store
    does not know."""
    if run.get("fleet"):
        return f"fleet {run['fleet']}"
    rig = run.get("rig")
    if not rig:
        return None
    name = os.path.basename(str(rig).replace("\\", "/"))
    return f"rig {os.path.splitext(name)[0] or name}"


def _key(answer: str) -> str:
    """An answer as pallets are told apart: in any case, without a pallet number's zero
    padding (``0115A`` is ``115a``; ``PAL-7A`` is ``pal-7a``)."""
    s = answer.strip().casefold()
    i = 0
    while i < len(s) - 1 and s[i] == "0" and s[i + 1].isdigit():
        i += 1
    return s[i:]


def _side_of(answer: str) -> str | None:
    """The pallet an answer names a side of (``109B`` -> ``109``: a digit and one letter, as
    :func:`perception.expected.pallet_of` reads it; the store imports nothing of the
    project), else None."""
    s = answer.strip()
    return s[:-1] if len(s) >= 2 and s[-1].isalpha() and s[-2].isdigit() else None


__all__ = ["diff_rows", "flown_by"]
