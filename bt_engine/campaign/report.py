"""The campaign report: ``DIR/report.html`` with its plots in ``DIR/plots/``.

Sections: the outcome counts; the success rate per value of every setting that varies
(numbers with many values are binned), with the rate of each true/false metric beside it;
the failure reasons, most frequent first (numbers in reasons are folded so that "link lost
at 12.3 s" and "at 40.1 s" count together); each metric's distribution (a histogram per
numeric metric, split by outcome); the runs that did not succeed, linked to their own
flight reports. Links are relative: copy the folder, the report still works.
"""

from __future__ import annotations

import html
import math
import os
import re
import statistics
import sys
from collections import Counter, defaultdict
from typing import Any, TextIO

from bt_engine.campaign.results import ROW_STATUSES, table_columns
from bt_engine.campaign.rows import value_text
from bt_engine.campaign.spec import Campaign

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em auto;
max-width:1100px;padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
h3{font-size:1em;margin:1.2em 0 .3em}
table{border-collapse:collapse;font-size:.9em;margin:.5em 0}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right;white-space:nowrap}
td.l,th.l{text-align:left;white-space:normal}th{background:#f4f4f4}
tr:nth-child(even) td{background:#fafafa}
.SUCCESS{color:#1a7f37;font-weight:600}.FAILURE,.ABORTED,.CRASHED,.TIMEOUT{color:#c62828;font-weight:600}
.bar{display:inline-block;height:.7em;background:#2e7d32;vertical-align:middle}
.barbg{display:inline-block;width:80px;height:.7em;background:#f0c8c8;vertical-align:middle}
img{max-width:100%;border:1px solid #eee;margin:.4em 0}.note{color:#555;font-size:.9em}
"""
MAX_BINS = 5  # numeric settings with more distinct values than this are binned
MAX_FAILED_LISTED = 200
#: Statuses in the order the terminal summary shows them (others follow, by name).
STATUSES = ROW_STATUSES
#: The most metrics the terminal summary shows (the report shows every one).
MAX_SUMMARY_METRICS = 4
#: What a terminal summary line groups by (those that vary between the runs).
SUMMARY_GROUPS = ("mission", "rig", "world", "fault")
_NUMBER = re.compile(r"-?\d+(\.\d+)?")


def _num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _rate_cell(k: int, n: int) -> str:
    if not n:
        return "<td>\u2014</td>"
    width = round(80 * k / n)
    return (
        f'<td>{k}/{n} ({100 * k / n:.0f} %) <span class="barbg"><span class="bar" '
        f'style="width:{width}px"></span></span></td>'
    )


def _groups(values: list[Any]) -> tuple[list[str], list[str]]:
    """(label of each value, labels in display order): many numbers become bins; a setting a
    row does not have (another fault schedule's) is "(not set)"."""
    nums = [v for v in values if _num(v)]
    unset = "(not set)"
    if len({value_text(v) for v in nums}) > MAX_BINS and all(v is None or _num(v) for v in values):
        lo, hi = min(nums), max(nums)
        width = (hi - lo) / MAX_BINS or 1.0
        edges = [lo + i * width for i in range(MAX_BINS + 1)]
        order = [f"{edges[i]:.4g} .. {edges[i + 1]:.4g}" for i in range(MAX_BINS)]
        labels = [
            unset if v is None else order[min(int((v - lo) / width), MAX_BINS - 1)] for v in values
        ]
        return labels, [o for o in order if o in labels] + ([unset] if None in values else [])
    labels = [unset if v is None else value_text(v) for v in values]
    return labels, list(dict.fromkeys(labels))


def _per_value(c: Campaign, table: list[dict]) -> str:
    bool_metrics = [
        m.name
        for m in c.metrics
        if any(isinstance(r[m.name], bool) for r in table)
        and all(r[m.name] is None or isinstance(r[m.name], bool) for r in table)
    ]
    head = "<tr><th class=l>value</th><th>runs</th><th>SUCCESS</th>" + "".join(
        f"<th>{html.escape(n)} true</th>" for n in bool_metrics
    )
    out = []
    for col in ["mission", "rig", "world", "fault", *c.parameters()]:
        if col not in table[0]:
            continue
        labels, order = _groups([r[col] for r in table])
        if len(order) < 2:
            continue
        by: dict[str, list[dict]] = defaultdict(list)
        for label, r in zip(labels, table, strict=True):
            by[label].append(r)
        body = []
        for label in order:
            rs = by[label]
            cells = _rate_cell(sum(r["status"] == "SUCCESS" for r in rs), len(rs))
            for n in bool_metrics:
                known = [r[n] for r in rs if r[n] is not None]
                cells += _rate_cell(sum(known), len(known))
            body.append(f"<tr><td class=l>{html.escape(label)}</td><td>{len(rs)}</td>{cells}</tr>")
        out.append(f"<h3>{html.escape(col)}</h3><table>{head}</tr>{''.join(body)}</table>")
    return "".join(out) or "<p>No setting varies between the runs.</p>"


def _reasons(out_dir: str, table: list[dict]) -> str:
    failed = [r for r in table if r["status"] != "SUCCESS"]
    if not failed:
        return "<p>Every run succeeded.</p>"
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in failed:
        groups[(r["status"], _NUMBER.sub("#", str(r["reason"] or "")))].append(r)
    body = []
    for (status, _), rs in sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        rows = ", ".join(_row_link(r, out_dir) for r in rs[:8]) + (" ..." if len(rs) > 8 else "")
        body.append(
            f'<tr><td>{len(rs)}</td><td class="l {status}">{status}</td>'
            f"<td class=l>{html.escape(str(rs[0]['reason']))}</td><td class=l>{rows}</td></tr>"
        )
    return (
        '<p class="note">Reasons that differ only in their numbers are counted together; '
        "the example is the first such run.</p><table><tr><th>runs</th><th class=l>status</th>"
        f"<th class=l>reason (example)</th><th class=l>rows</th></tr>{''.join(body)}</table>"
    )


def _row_link(r: dict, out_dir: str) -> str:
    """The row's name, linked to its flight report (else its folder) when the folder was kept."""
    name = html.escape(r["row"])
    if not r.get("run_dir"):
        return name
    target = os.path.join(r["run_dir"], "report.html")
    if not os.path.exists(os.path.join(out_dir, target)):
        target = r["run_dir"] + "/"
    return f'<a href="{html.escape(target, quote=True)}">{name}</a>'


def _flat(v: Any) -> list[float]:
    if isinstance(v, list):
        return [x for x in v if _num(x)]
    return [v] if _num(v) else []


def _distributions(out_dir: str, c: Campaign, table: list[dict]) -> str:
    parts = []
    stats_rows = []
    for m in c.metrics:
        values = [r[m.name] for r in table]
        nums = [x for v in values for x in _flat(v)]
        if nums and not any(isinstance(v, bool) for v in values):
            ok = [x for r in table if r["status"] == "SUCCESS" for x in _flat(r[m.name])]
            bad = [x for r in table if r["status"] != "SUCCESS" for x in _flat(r[m.name])]
            q = _quantiles(nums)
            stats_rows.append(
                f"<tr><td class=l>{html.escape(m.name)}</td><td class=l>{html.escape(m.text)}</td>"
                f"<td>{len(nums)}</td>" + "".join(f"<td>{x:.4g}</td>" for x in q) + "</tr>"
            )
            png = _histogram(out_dir, m.name, ok, bad)
            if png:
                parts.append(
                    f"<h3>{html.escape(m.name)}</h3>"
                    f'<img src="{html.escape(png, quote=True)}" alt="{html.escape(m.name)}">'
                )
        elif values:
            counts = Counter(value_text(v) for v in values if v is not None)
            missing = sum(v is None for v in values)
            items = ", ".join(f"{html.escape(k)}: {n}" for k, n in counts.most_common(12))
            note = f"; missing in {missing} runs" if missing else ""
            parts.append(f"<p><b>{html.escape(m.name)}</b>: {items or '(no values)'}{note}</p>")
    head = (
        "<table><tr><th class=l>metric</th><th class=l>from summary.json</th><th>n</th>"
        "<th>min</th><th>median</th><th>p95</th><th>max</th><th>mean</th></tr>"
    )
    stats = head + "".join(stats_rows) + "</table>" if stats_rows else ""
    return stats + "".join(parts) if (stats or parts) else "<p>No metrics.</p>"


def _quantiles(v: list[float]) -> list[float]:
    s = sorted(v)

    def q(p: float) -> float:
        i = p * (len(s) - 1)
        lo = math.floor(i)
        hi = min(lo + 1, len(s) - 1)
        return s[lo] + (s[hi] - s[lo]) * (i - lo)

    return [s[0], q(0.5), q(0.95), s[-1], sum(s) / len(s)]


def _histogram(out_dir: str, name: str, ok: list[float], bad: list[float]) -> str | None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not ok and not bad:
        return None
    fig = Figure(figsize=(7.0, 2.6), dpi=90)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    allv = ok + bad
    bins = min(30, max(5, len(set(allv))))
    lo, hi = min(allv), max(allv)
    edges = bins if hi > lo else [lo - 0.5, hi + 0.5]
    ax.hist(
        [ok, bad],
        bins=edges,
        stacked=True,
        color=["#2e7d32", "#c62828"],
        label=["SUCCESS", "other"],
    )
    ax.set_xlabel(name)
    ax.set_ylabel("count")
    if bad:
        ax.legend(fontsize=8)
    fig.tight_layout()
    os.makedirs(os.path.join(out_dir, "plots"), exist_ok=True)
    rel = os.path.join("plots", re.sub(r"[^A-Za-z0-9_.-]", "_", name) + ".png")
    fig.savefig(os.path.join(out_dir, rel))
    return rel


def _failed_runs(out_dir: str, c: Campaign, table: list[dict]) -> str:
    failed = [r for r in table if r["status"] != "SUCCESS"]
    if not failed:
        return "<p>None.</p>"
    params = [
        p for p in ("mission", "rig", "world", "seed", "fault", *c.parameters()) if p in failed[0]
    ]
    head = "<tr><th class=l>row</th>" + "".join(
        f"<th class=l>{html.escape(p)}</th>" for p in params
    )
    body = []
    for r in failed[:MAX_FAILED_LISTED]:
        cells = "".join(f"<td class=l>{html.escape(value_text(r[p]))}</td>" for p in params)
        folder = (
            f' (<a href="{html.escape(r["run_dir"], quote=True)}/">folder</a>)'
            if r["run_dir"]
            else ""
        )
        body.append(
            f"<tr><td class=l>{_row_link(r, out_dir)}{folder}</td>{cells}"
            f'<td class="l {r["status"]}">{r["status"]}</td>'
            f"<td class=l>{html.escape(str(r['reason']))}</td></tr>"
        )
    more = (
        f"<p>... and {len(failed) - MAX_FAILED_LISTED} more (results.csv).</p>"
        if len(failed) > MAX_FAILED_LISTED
        else ""
    )
    return (
        f"<table>{head}<th class=l>status</th><th class=l>reason</th></tr>{''.join(body)}</table>"
        + more
    )


def write_report(out_dir: str, c: Campaign, table: list[dict]) -> str:
    """Write ``report.html`` (and ``plots/*.png``) for the finished rows; return its path."""
    esc = html.escape
    counts = Counter(r["status"] for r in table)
    outcome = ", ".join(
        f'<span class="{esc(s)}">{esc(s)}</span> {n}' for s, n in counts.most_common()
    )
    names = [col.name for col in table_columns(c)]
    out = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
        f"<title>btrun campaign: {esc(c.name)}</title><style>{_CSS}</style></head><body>",
        f"<h1>Campaign {esc(c.name)}</h1>",
        f"<p>{esc(c.description)}</p>" if c.description else "",
        f"<p>{len(table)} runs finished: {outcome or 'none'}. Tables: "
        '<a href="results.csv">results.csv</a>, <a href="results.parquet">results.parquet</a>.</p>',
    ]
    if table:
        out += [
            "<h2>Success rate per setting value</h2>",
            _per_value(c, table),
            "<h2>Failure reasons, most frequent first</h2>",
            _reasons(out_dir, table),
            "<h2>Metrics</h2>",
            _distributions(out_dir, c, table),
            "<h2>Runs that did not succeed</h2>",
            _failed_runs(out_dir, c, table),
        ]
    out.append(
        f'<p class="note">Written by btrun campaign (bt_engine/campaign/); columns: '
        f"{esc(', '.join(names))} (what each holds: columns.csv). "
        "See docs/campaigns.md.</p></body></html>"
    )
    path = os.path.join(out_dir, "report.html")
    with open(path + ".tmp", "w", encoding="utf-8") as f:
        f.write("\n".join(out))
    os.replace(path + ".tmp", path)
    return path


def _summary_metrics(c: Campaign, table: list[dict]) -> list[tuple[str, str]]:
    """(name, "median" or "true") of the metrics the terminal summary shows: deterministic
    ones whose values are all numbers or all true/false (lists and text are left to the
    report), the first :data:`MAX_SUMMARY_METRICS`."""
    out = []
    for m in c.metrics:
        values = [r[m.name] for r in table if r[m.name] is not None]
        if m.wall_clock or not values:
            continue
        if all(isinstance(v, bool) for v in values):
            out.append((m.name, "true"))
        elif all(_num(v) for v in values):
            out.append((m.name, "median"))
    return out[:MAX_SUMMARY_METRICS]


def summary_table(c: Campaign, table: list[dict]) -> Any:
    """The terminal summary (a ``rich.table.Table``): one line per group of runs (each
    combination of the mission, rig, world and fault schedule, those that vary; else one
    line, and a total line under several), with the runs, the count of each status, the
    success rate, the median of the numeric metrics and the true count of the true/false
    ones (the first :data:`MAX_SUMMARY_METRICS`), and the median wall time of a run.
    ``table`` is :attr:`CampaignRun.table <bt_engine.campaign.execution.CampaignRun.table>`."""
    from rich.table import Table

    keys = [k for k in SUMMARY_GROUPS if table and k in table[0]]
    keys = [k for k in keys if len({r[k] for r in table}) > 1]
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in table:  # row order: the groups in the campaign's order
        groups[tuple(r[k] for k in keys)].append(r)
    present = Counter(r["status"] for r in table)
    statuses = [s for s in STATUSES if s in present] + sorted(
        str(s) for s in present if s not in STATUSES
    )
    metrics = _summary_metrics(c, table)
    out = Table(title=f"campaign {c.name}: {len(table)} runs", title_justify="left")
    for k in keys or ["group"]:
        out.add_column(k, overflow="fold")
    out.add_column("runs", justify="right", no_wrap=True)
    for s in statuses:
        out.add_column(s, justify="right", style=_status_style(s), no_wrap=True)
    out.add_column("success", justify="right", no_wrap=True)
    for name, how in metrics:
        out.add_column(f"{name}\n{how}", justify="right", no_wrap=True)
    out.add_column("wall_s\nmedian", justify="right", no_wrap=True)

    def line(label: list[str], rs: list[dict]) -> list[str]:
        counts = Counter(str(r["status"]) for r in rs)
        cells = [*label, str(len(rs)), *(str(counts[s]) if counts[s] else "" for s in statuses)]
        cells.append(f"{100 * counts['SUCCESS'] / len(rs):.0f} %")
        for name, how in metrics:
            values = [r[name] for r in rs if r[name] is not None]
            if how == "true":
                cells.append(f"{sum(values)}/{len(values)}" if values else "")
            else:
                cells.append(f"{statistics.median(values):.4g}" if values else "")
        walls = [r["wall_s"] for r in rs if _num(r.get("wall_s"))]
        cells.append(f"{statistics.median(walls):.2f}" if walls else "")
        return cells

    for group, rs in groups.items():
        out.add_row(*line([value_text(v) if v != "" else "-" for v in group] or ["all"], rs))
    if len(groups) > 1:
        out.add_section()
        out.add_row(*line(["total"] + [""] * (len(keys) - 1), table), style="bold")
    return out


def _status_style(status: str) -> str:
    return "green" if status == "SUCCESS" else "red"


def print_summary(c: Campaign, table: list[dict], file: TextIO | None = None) -> None:
    """Print :func:`summary_table` (on ``file``, default standard output; colours only on a
    terminal; not on a terminal, as wide as the table needs: a log has no width)."""
    from rich.console import Console

    if not table:
        return
    console = Console(file=file or sys.stdout)
    summary = summary_table(c, table)
    if not console.is_terminal:
        wide = console.options.update_width(10_000)
        console.width = max(console.width, console.measure(summary, options=wide).maximum)
    console.print(summary)
