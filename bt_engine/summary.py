"""``summary.json``: how a run ended, built in one place, bounded in size.

:func:`build_summary` makes the dict that ``btrun`` writes (and tests and benches compare):
the engine's own keys (``status``, ``reason``, ``ticks``, ``mission_time_s``,
``wall_time_s``, ``mission``, ``seed``, ``rate_hz``, ``blackboard``), then the run target's
sections (``sim`` or ``vehicle``, ``safety``) and one section per mission resource that
reports on the run (:class:`~bt_engine.plugins.RunReporter`, e.g. ``perception``).
:func:`write_summary` writes it atomically.

A mission file decides what goes on the blackboard, so the file is bounded: each blackboard
value is summarised as the tick log summarises it (:func:`bt_engine.ticklog.summarise_value`:
past 16 kB as JSON, a note with its type, size and SHA-1), the values take at most
:data:`BLACKBOARD_LIMIT_BYTES` (the entries past it are listed by name only, in
``blackboard_omitted``), any other section at most :data:`SECTION_LIMIT_BYTES` and the whole
file about :data:`SUMMARY_LIMIT_BYTES` (a section past them is replaced by a note). A part
that cannot be built (it raises) is left out and named in ``errors``; :func:`write_summary`
falls back on the engine's keys alone (:func:`minimal_summary`) if the whole cannot be written,
and keeps :data:`RESERVE_FDS` file descriptors in reserve from import on, released just
before it writes, so a process out of descriptors still writes its summary.
"""

from __future__ import annotations

import contextlib
import json
import os
from typing import Any

from bt_engine.files import atomic_write_text
from bt_engine.mission import Mission
from bt_engine.plugins import RunReporter
from bt_engine.runner import RunResult
from bt_engine.ticklog import summarise_value, to_jsonable

#: bytes (as JSON) of blackboard values summary.json keeps; later entries: names only
BLACKBOARD_LIMIT_BYTES = 1_000_000
#: bytes of entry names listed in ``blackboard_omitted``; the rest are counted
OMITTED_NAMES_LIMIT_BYTES = 200_000
#: bytes (as JSON) one section (``sim``, ``motions``, ...) may take, else a note replaces it
SECTION_LIMIT_BYTES = 2_000_000
#: about the largest summary.json: past it the largest sections are replaced by notes
SUMMARY_LIMIT_BYTES = 8_000_000
#: entries of ``errors`` kept, and characters of each
ERRORS_LIMIT, ERROR_CHARS = 20, 500
#: file descriptors held in reserve for the final write (see :func:`reserve_descriptors`)
RESERVE_FDS = 4

#: the keys every summary has, built by :func:`minimal_summary`
CORE_KEYS = (
    "status",
    "reason",
    "ticks",
    "mission_time_s",
    "wall_time_s",
    "mission",
    "seed",
    "rate_hz",
)


def error_line(what: str, exc: BaseException) -> str:
    """``"<what>: <Type>: <message>"`` for ``errors`` (bounded; never a traceback)."""
    try:
        text = str(exc)
    except Exception:  # a forged exception whose str() raises
        text = "?"
    line = f"{what}: {type(exc).__name__}" + (f": {text}" if text else "")
    return line if len(line) <= ERROR_CHARS else line[: ERROR_CHARS - 3] + "..."


def add_error(summary: dict[str, Any], line: str) -> None:
    """Append ``line`` to ``summary["errors"]`` (at most :data:`ERRORS_LIMIT` lines)."""
    errors = summary.setdefault("errors", [])
    if len(errors) < ERRORS_LIMIT:
        errors.append(line[:ERROR_CHARS])
    elif len(errors) == ERRORS_LIMIT:
        errors.append("... more errors not kept")


def minimal_summary(
    result: RunResult, *, mission_path: str, seed: int, rate_hz: float
) -> dict[str, Any]:
    """The engine's keys of a finished run (:data:`CORE_KEYS`): what summary.json holds at
    least, whatever else failed."""
    reason = str(result.reason)
    return {
        "status": result.status,
        "reason": reason if len(reason) <= 20_000 else reason[:20_000] + "...",
        "ticks": result.ticks,
        "mission_time_s": round(result.mission_time_s, 4),
        "wall_time_s": round(result.wall_time_s, 4),
        "mission": os.path.abspath(mission_path),
        "seed": seed,
        "rate_hz": rate_hz,
    }


def _json_size(value: Any) -> int:
    return len(json.dumps(value, indent=2))


def bounded_blackboard(items: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The ``blackboard`` section from every entry, and ``blackboard_omitted`` (None if every
    entry fits): values summarised as the tick log does, in the blackboard's order, until
    they take :data:`BLACKBOARD_LIMIT_BYTES`; the later entries are listed by name only (up
    to :data:`OMITTED_NAMES_LIMIT_BYTES` of names, the rest counted)."""
    kept: dict[str, Any] = {}
    names: list[str] = []
    used = names_used = unlisted = 0
    # one summary per value object: entries sharing a value are summarised once
    done: dict[int, tuple[Any, Any, int]] = {}
    for key, value in items.items():
        name = str(key)
        if not names and not unlisted:
            hit = done.get(id(value))
            if hit is None:
                short = summarise_value(value)
                hit = done[id(value)] = (value, short, _json_size(short))
            size = hit[2] + len(name) + 8
            if used + size <= BLACKBOARD_LIMIT_BYTES:
                kept[name] = hit[1]
                used += size
                continue
        if not unlisted and names_used + len(name) + 8 <= OMITTED_NAMES_LIMIT_BYTES:
            names.append(name)
            names_used += len(name) + 8
        else:
            unlisted += 1
    if not names and not unlisted:
        return kept, None
    omitted: dict[str, Any] = {
        "why": f"blackboard values past {BLACKBOARD_LIMIT_BYTES} bytes are listed by name "
        "only (ticks.jsonl has every write, large values as notes)",
        "names": names,
    }
    if unlisted:
        omitted["unlisted"] = unlisted
    return kept, omitted


def _section_note(size: int, limit: int) -> str:
    return (
        f"<section of {size} bytes as JSON: over summary.json's limit of {limit} bytes, not kept>"
    )


def _cap_sections(summary: dict[str, Any], fixed: set[str]) -> None:
    """Replace sections (keys not in ``fixed``) past :data:`SECTION_LIMIT_BYTES` by a note,
    then the largest ones while the whole is past :data:`SUMMARY_LIMIT_BYTES`."""
    sizes: dict[str, int] = {}
    for key in list(summary):
        if key in fixed:
            continue
        size = _json_size(summary[key])
        if size > SECTION_LIMIT_BYTES:
            summary[key] = _section_note(size, SECTION_LIMIT_BYTES)
            add_error(summary, f"{key}: {size} bytes as JSON, over {SECTION_LIMIT_BYTES}: not kept")
            size = _json_size(summary[key])
        sizes[key] = size
    total = sum(sizes.values()) + sum(_json_size(summary[k]) for k in fixed if k in summary)
    for key in sorted(sizes, key=sizes.__getitem__, reverse=True):
        if total <= SUMMARY_LIMIT_BYTES:
            break
        if key in ("errors", "blackboard_omitted"):
            continue
        summary[key] = _section_note(sizes[key], SUMMARY_LIMIT_BYTES)
        add_error(summary, f"{key}: left out, summary.json past {SUMMARY_LIMIT_BYTES} bytes")
        total -= sizes[key] - _json_size(summary[key])


def build_summary(
    result: RunResult,
    mission: Mission,
    *,
    mission_path: str,
    seed: int,
    rate_hz: float,
    sections: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``summary.json`` dict of a finished run (bounded: see the module's notes).

    ``sections`` are the run target's parts (``{"sim": ..., "safety": ...}``); resources of
    the mission that implement :class:`RunReporter` add theirs under their resource names
    (never replacing a section already there). A part that raises is left out and named in
    ``errors``.
    """
    summary = minimal_summary(result, mission_path=mission_path, seed=seed, rate_hz=rate_hz)
    timing = tick_timing(result, rate_hz)
    if timing is not None:
        summary["timing"] = timing
    try:
        summary["blackboard"], omitted = bounded_blackboard(mission.scope.all_items())
        if omitted is not None:
            summary["blackboard_omitted"] = omitted
    except Exception as exc:  # e.g. MemoryError: the rest of the summary still goes out
        summary["blackboard"] = {}
        add_error(summary, error_line("blackboard", exc))
    try:
        if mission.leaf_failures:  # also those the tree handled (a Fallback, a retry)
            summary["leaf_failures"] = [
                {"failure": text, "times": n} for text, n in mission.leaf_failures.items()
            ]
    except Exception as exc:
        add_error(summary, error_line("leaf_failures", exc))
    for key, value in (sections or {}).items():
        try:
            summary[key] = to_jsonable(value)
        except Exception as exc:
            add_error(summary, error_line(f"section {key}", exc))
    for name, res in mission.ctx.resources.items():
        if name not in summary and isinstance(res, RunReporter):
            try:
                if hasattr(res, "mission_end_s"):  # this run's end (a fleet's drones share
                    res.mission_end_s = summary.get("mission_time_s")  # a clock running on)
                summary[name] = to_jsonable(res.run_summary())
            except Exception as exc:
                add_error(summary, error_line(f"section {name}", exc))
    _cap_sections(summary, set(CORE_KEYS) | {"blackboard"})
    return summary


def tick_timing(result: RunResult, rate_hz: float) -> dict[str, Any] | None:
    """Real time: the tick period's p50 / p99 / max (ms), the periods over twice the
    nominal one and the tick slots skipped after them (a busy or paused host: the tick log
    alone told it). None in lock-step."""
    periods = sorted(1000.0 * p for p in getattr(result, "tick_periods_s", None) or ())
    if not periods:
        return None
    factor = float(getattr(result, "clock_factor", 1.0) or 1.0)
    nominal = 1000.0 / (rate_hz * factor) if rate_hz else 0.0  # wall ms per tick
    pick = lambda q: round(periods[min(len(periods) - 1, int(q * (len(periods) - 1) + 0.5))], 1)  # noqa: E731
    return {
        "tick_period_ms": {
            "nominal": round(nominal, 1),
            "p50": pick(0.5),
            "p99": pick(0.99),
            "max": round(periods[-1], 1),
        },
        "late_ticks": sum(1 for p in periods if nominal and p > 2 * nominal),
        "slots_skipped": int(getattr(result, "slots_skipped", 0) or 0),
    }


def timing_line(summary: dict[str, Any]) -> str | None:
    """The console's word on a run whose ticks ran late (None when they kept time)."""
    t = summary.get("timing")
    if not isinstance(t, dict) or not (t.get("slots_skipped") or t.get("late_ticks")):
        return None
    p = t["tick_period_ms"]
    return (
        f"timing: the tick period reached {p['max']:g} ms (p99 {p['p99']:g} ms, nominal "
        f"{p['nominal']:g} ms); {t['late_ticks']} late ticks, {t['slots_skipped']} tick slots "
        "skipped (a busy or paused host)"
    )


def result_lines(mission: Mission) -> list[str]:
    """The run's headline lines from the mission's reporting resources (e.g. the pallet);
    a resource with a higher ``result_priority`` (default 0) comes first (an inventory's
    discrepancies lead)."""
    reporters = [r for r in mission.ctx.resources.values() if isinstance(r, RunReporter)]
    reporters.sort(key=lambda r: -int(getattr(r, "result_priority", 0) or 0))
    return [line for res in reporters for line in res.result_lines()]


def handled_failure_lines(mission: Mission, reason: str, limit: int = 10) -> list[str]:
    """Console lines for the leaf failures the run went on after (not the one that ended
    it): what a "continue anyway" branch swallowed."""
    items = [(t, n) for t, n in mission.leaf_failures.items() if t not in reason]
    lines = [f"handled: {t}" + (f" ({n} times)" if n > 1 else "") for t, n in items[:limit]]
    if len(items) > limit:
        lines.append(f"handled: ... and {len(items) - limit} more (summary.json leaf_failures)")
    return lines


def reserve_descriptors(n: int = RESERVE_FDS) -> None:
    """Hold ``n`` file descriptors (of ``os.devnull``) until :func:`write_summary` needs
    them: a run that exhausted the process's descriptors (a leak, a connection flood) can
    still write summary.json. Called at import; idempotent; silently fewer if none is free."""
    while len(_RESERVE) < n:
        try:
            _RESERVE.append(os.open(os.devnull, os.O_RDONLY))
        except OSError:
            return


#: the file a run folder keeps in reserve for its record (:func:`reserve_space`)
SPACE_RESERVE = ".btrun-reserve"
#: bytes kept in reserve: summary.json (at most about 8 MB, usually some kB) and the guard's
SPACE_RESERVE_BYTES = 512 * 1024


def reserve_space(run_dir: str, size: int = SPACE_RESERVE_BYTES) -> None:
    """Keep ``size`` bytes of the run folder's disk in reserve (:data:`SPACE_RESERVE`) for
    the record: a disk that fills in flight (the tick log, the camera's crops) left no room
    for summary.json. :func:`free_space` gives them back when the record is written; no
    reserve (no room even now) is no error."""
    path = os.path.join(run_dir, SPACE_RESERVE)
    try:
        with open(path, "wb") as f:
            f.write(b"\0" * size)
            f.flush()
            os.fsync(f.fileno())
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(path)


def free_space(run_dir: str) -> bool:
    """Give the run folder's reserve back (True if there was one)."""
    try:
        os.unlink(os.path.join(run_dir, SPACE_RESERVE))
    except OSError:
        return False
    return True


def _release_reserve() -> None:
    while _RESERVE:
        try:
            os.close(_RESERVE.pop())
        except OSError:
            pass


def write_summary(run_dir: str, summary: dict[str, Any]) -> str:
    """Write ``summary.json`` in ``run_dir`` atomically (a temporary file, then a rename).

    The descriptors held in reserve are released just before (and taken again after). If
    the whole summary cannot be written (no memory, a value JSON cannot hold, no
    descriptor), its engine keys (:data:`CORE_KEYS`) and ``errors`` are, with one more
    error naming why; if that fails too, the exception is raised.
    """
    path = os.path.join(run_dir, "summary.json")
    try:
        text = json.dumps(summary, indent=2)
    except Exception as exc:  # MemoryError, TypeError (a forged value), ValueError (a cycle)
        text = _minimal_text(summary, error_line("summary.json", exc))
    _release_reserve()
    try:
        try:
            atomic_write_text(path, text)
        except OSError as exc:  # a full disk: the reserve back, then the record
            if not free_space(run_dir):
                raise
            add_error(summary, error_line("disk", exc))
            atomic_write_text(path, json.dumps(summary, indent=2))
    except MemoryError as exc:
        del text
        atomic_write_text(path, _minimal_text(summary, error_line("summary.json", exc)))
    finally:
        reserve_descriptors()
        free_space(run_dir)  # written (or never will be): the reserve is not needed now
    return path


def _minimal_text(summary: dict[str, Any], why: str) -> str:
    """The JSON of ``summary``'s engine keys and errors, plus ``why``."""
    out: dict[str, Any] = {}
    for key in CORE_KEYS:
        value = summary.get(key)
        out[key] = value if isinstance(value, (str, int, float, type(None))) else repr(value)
    errors = summary.get("errors")
    out["errors"] = (
        [str(e)[:ERROR_CHARS] for e in errors[:ERRORS_LIMIT]] if isinstance(errors, list) else []
    )
    add_error(out, why)
    return json.dumps(out, indent=2)


_RESERVE: list[int] = []
reserve_descriptors()
