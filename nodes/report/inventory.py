"""The inventory section of the flight report: the racks drawn place by place, coloured by
how each answer compares with the simulator's ground truth, and the rows as a table.

Colours: right (green), a wrong identity accepted (red), unknown where an enrolled pallet
stands (amber), answered empty where a pallet stands (purple), not scanned (grey). Each cell
shows the answer and, where it differs, what stood there. Without ground truth (a real
flight) the cells are coloured by answer kind instead.
"""

from __future__ import annotations

import html
import os

from bt_engine.spec import plural

GRADE_COLOURS = {
    "right": "#4caf50",
    "wrong": "#e53935",
    "unknown": "#ffb300",
    "missed": "#8e24aa",
    "not_scanned": "#bdbdbd",
}
ANSWER_COLOURS = {"identified": "#64b5f6", "unknown": "#ffb300", "empty": "#e0e0e0"}


def plot_racks(run_dir: str, inv: dict, name: str = "inventory.png") -> str | None:
    """Draw every rack of ``inv`` (summary.json's ``inventory``) as a grid of places; return
    the PNG's file name (None when there is no layout)."""
    layout = inv.get("layout") or {}
    if not layout:
        return None
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch, Rectangle

    racks = sorted({v[0] for v in layout.values()})
    bays = {r: max(v[1] for v in layout.values() if v[0] == r) for r in racks}
    levels = {r: max(v[2] for v in layout.values() if v[0] == r) for r in racks}
    width = max(bays.values())
    fig = Figure(
        figsize=(max(6.0, 1.15 * width + 1.0), 1.0 + sum(1.0 * levels[r] + 0.6 for r in racks))
    )
    ax = fig.add_subplot(1, 1, 1)
    grades = inv.get("grades")
    truth = inv.get("truth") or {}
    rows = inv.get("rows") or {}
    y0 = 0.0
    for rack in racks:
        for place, (r, bay, level) in layout.items():
            if r != rack:
                continue
            row = rows.get(place) or {}
            answer = row.get("answer") or "-"
            x, y = bay - 1, y0 + level - 1
            if place not in rows:  # not in this run's plan
                ax.add_patch(Rectangle((x + 0.04, y + 0.06), 0.92, 0.88, fill=False, ec="#bbb"))
                ax.text(x + 0.5, y + 0.5, place, ha="center", va="center", fontsize=7, color="#999")
                continue
            if grades is not None:
                colour = GRADE_COLOURS.get(grades.get(place, "not_scanned"), "#bdbdbd")
            else:
                colour = ANSWER_COLOURS.get(row.get("status", ""), "#bdbdbd")
            ax.add_patch(Rectangle((x + 0.04, y + 0.06), 0.92, 0.88, color=colour))
            text = f"{place}\n{answer}"
            stood = truth.get(place, "?") if grades is not None else None
            if grades is not None and grades.get(place) != "right":
                text += f"\n(is {stood or 'empty'})"
            ax.text(x + 0.5, y + 0.5, text, ha="center", va="center", fontsize=7)
        ax.text(-0.15, y0 + levels[rack] / 2, f"rack {rack}", ha="right", va="center", fontsize=9)
        y0 += levels[rack] + 0.6
    ax.set_xlim(-1.0, width + 0.1)
    ax.set_ylim(-0.2, y0)
    ax.set_axis_off()
    if grades is not None:
        handles = [Patch(color=c, label=g.replace("_", " ")) for g, c in GRADE_COLOURS.items()]
        title = (
            f"{inv.get('right', 0)} of {inv.get('places', 0)} places right, "
            f"{inv.get('wrong', 0)} wrong (against the simulator's ground truth)"
        )
    else:
        handles = [Patch(color=c, label=g) for g, c in ANSWER_COLOURS.items()]
        title = plural(inv.get("places", 0), "place")
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=len(handles),
        fontsize=8,
        frameon=False,
    )
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(os.path.join(run_dir, name), dpi=110)
    return name


def inventory_section(run_dir: str, summary: dict) -> str:
    """HTML of the inventory section ("" when the run kept no inventory)."""
    inv = (summary or {}).get("inventory")
    if not inv or not inv.get("places"):
        return ""
    esc = html.escape
    out = ["<h2>Inventory</h2>"] + discrepancy_part(inv) + pace_part(inv)
    png = plot_racks(run_dir, inv)
    if png:
        out.append(f'<img src="{esc(png, quote=True)}" alt="the racks, place by place">')
    grades = inv.get("grades") or {}
    truth = inv.get("truth") or {}
    head = ["place", "answer", "status", "distance", "margin", "time (s)", "drone"]
    if grades:
        head += ["ground truth", "grade"]
    cells = ["".join(f"<th>{h}</th>" for h in head)]
    for place, row in (inv.get("rows") or {}).items():
        row = row or {}
        vals = [place, row.get("answer") or "-", row.get("status") or "not scanned"]
        vals += [
            row.get("distance"),
            row.get("margin"),
            row.get("mission_time_s"),
            row.get("drone"),
        ]
        if grades:
            vals += [truth.get(place) or "empty", grades.get(place, "")]
        tds = "".join(f"<td class=l>{esc('' if v is None else str(v))}</td>" for v in vals)
        cells.append(tds)
    out.append(
        '<div class="wide"><table>' + "".join(f"<tr>{c}</tr>" for c in cells) + "</table></div>"
    )
    out.append(
        '<p class="note">inventory.csv and inventory.json in the run folder hold the same rows '
        "(written as each place was done).</p>"
    )
    return "\n".join(out)


def pace_part(inv: dict) -> list[str]:
    """The pace beside the commercial anchor's: places answered per hour of mission time
    (battery changes included), per drone in a fleet."""
    per_hour = inv.get("places_per_hour")
    if per_hour is None:
        return []
    anchor = inv.get("anchor_places_per_hour") or 1300
    rows = [("places answered in this run", f"{inv.get('places_answered', 0)}")]
    rows.append(("places per hour of mission time", f"{per_hour:,.0f}"))
    if inv.get("places_per_hour_per_drone") is not None:
        rows.append(("places per hour per drone", f"{inv['places_per_hour_per_drone']:,.0f}"))
    rows.append(("the commercial anchor (one drone reading labels)", f"{anchor:,}"))
    cells = "".join(
        f"<tr><td class=l>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows
    )
    return [f"<h3>Pace</h3><table>{cells}</table>"]


CATEGORY_COLOURS = {
    "confirmed": "#c8e6c9",
    "mismatch": "#ffcdd2",
    "missing": "#e1bee7",
    "unexpected": "#ffe0b2",
    "unverified": "#fff9c4",
    "not_scanned": "#eeeeee",
    "unlisted": "#eeeeee",
}


def discrepancy_part(inv: dict) -> list[str]:
    """With an expected stock: the counts per category first, then every place that
    disagrees (confirmed places are only counted), graded in simulation."""
    counts = inv.get("discrepancies")
    if not counts:
        return []
    esc = html.escape
    boxes = "".join(
        f'<span style="background:{CATEGORY_COLOURS.get(k, "#eee")};padding:2px 8px;'
        f'margin-right:6px">{n} {esc(k.replace("_", " "))}</span>'
        for k, n in counts.items()
    )
    out = [f"<h3>Discrepancies against the expected stock</h3><p>{boxes}</p>"]
    grades = (inv.get("discrepancy_grades") or {}).get("grades") or {}
    head = ["place", "expected", "found", "category", "moved from", "verified", "reason"]
    if grades:
        head.append("grade")
    body = []
    for r in inv.get("discrepancy_rows") or []:
        if r.get("category") == "confirmed" and grades.get(r["place"], "right") == "right":
            continue
        vals = [r.get(k) for k in ("place", "expected", "found", "category", "moved_from")]
        vals += ["yes" if r.get("verified") else "", r.get("reason")]
        if grades:
            vals.append(grades.get(r["place"], ""))
        colour = CATEGORY_COLOURS.get(r.get("category", ""), "#fff")
        tds = "".join(f"<td class=l>{esc('' if v is None else str(v))}</td>" for v in vals)
        body.append(f'<tr style="background:{colour}">{tds}</tr>')
    if body:
        th = "".join(f"<th>{h}</th>" for h in head)
        out.append(f'<div class="wide"><table><tr>{th}</tr>{"".join(body)}</table></div>')
    else:
        out.append("<p>Every place agrees with the expected stock.</p>")
    out.append(
        '<p class="note">discrepancies.csv and discrepancies.json in the run folder hold one '
        "row per place.</p>"
    )
    return out
