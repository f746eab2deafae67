"""The operator's review of an inventory's exceptions, and what it changes.

An exception (an ``unknown``, ``unverified`` or ``mismatch`` place, :func:`needs_review`)
is decided one of three ways:

* ``identity``: the pallet is one the gallery knows. Its crops become an added view of that
  identity (:meth:`perception.gallery.Gallery.add_view`, history event ``operator view``);
* ``new_pallet``: a pallet the gallery does not know yet, enrolled under the name given
  (history event ``enrol``);
* ``leave_unknown``: nothing is learnt; the answer stays ``unknown``.

Every history event names the review (``run``: ``console review <run> <place> by <who>``)
and its reason (``note``); ``btrun gallery rollback GALLERY NAME`` undoes either change.
The corrected answer is appended to ``review.json`` (every decision, oldest first) and
``review.csv`` (the latest per place) beside the run's rows; ``inventory.csv`` and
``inventory.json`` are never rewritten.

The gallery written is the console's ``--gallery`` file, else the gallery file the run
used (``--set gallery=FILE``), else ``site-gallery.sqlite`` in the runs folder; a file that
does not exist yet starts as a copy of the demo gallery of the run's world, so the next
inventory flown with ``--set gallery=THAT_FILE`` knows everything the demo knew plus the
operator's decisions.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import sqlite3
import threading
import time
import unicodedata
from typing import Any

from bt_engine.ticklog import header_path
from nodes.console.files import ReviewFileError, read_header, read_review, write_review
from nodes.console.paths import RunsRoot
from nodes.console.runs import drone_dirs, evidence, needs_review, read_rows
from nodes.gallery.cli import REVIEW_RUN

DEFAULT_GALLERY = "site-gallery.sqlite"
DECISIONS = ("identity", "new_pallet", "leave_unknown")
IDENTITY = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_LOCK = threading.Lock()  # one decision at a time: the gallery and review files


class ReviewError(Exception):
    """A decision that cannot be taken, in one line (``status``: the HTTP status)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


def gallery_path(root: RunsRoot, run_dir: str, option: str | None) -> str:
    """The gallery file review decisions go to (see the module doc)."""
    if option:
        return option
    for d in drone_dirs(run_dir).values():
        header = read_header(os.path.join(run_dir, d, "ticks.jsonl"))
        for item in header.get("sets") or []:
            if isinstance(item, str) and item.startswith("gallery="):
                value = header_path(header, item.split("=", 1)[1])
                if value and item != "gallery=demo" and os.path.isfile(value):
                    return value
        break
    return os.path.join(root.root, DEFAULT_GALLERY)


class GalleryDesk:
    """The models and gallery a review needs, loaded on the first decision (the embedder
    takes a few seconds; pages never wait for it)."""

    def __init__(self) -> None:
        self._sessions: dict[str, Any] = {}

    def session(self, rig_path: str | None) -> Any:
        """A perception session of the run's rig (its world names the demo gallery)."""
        from drivers.rig.loader import load_rig
        from nodes.perception_session import PerceptionSession

        key = rig_path or ""
        if key not in self._sessions:
            rig = load_rig(rig_path if rig_path and os.path.isfile(rig_path) else None)
            self._sessions[key] = PerceptionSession(rig)
        return self._sessions[key]

    def open(self, path: str, rig_path: str | None) -> tuple[Any, Any]:
        """(embedder, gallery ``path``), the file first copied from the demo gallery of the
        rig's world when it does not exist (:class:`ReviewError` if that rig is not on
        this machine: another world's demo would know none of the run's pallets)."""
        from perception.gallery import Gallery

        if rig_path and not os.path.isfile(rig_path) and not os.path.exists(path):
            raise ReviewError(
                f"the run's rig {rig_path} is not on this machine: a new review gallery "
                "starts as the demo gallery of the run's world; start the console with "
                "--gallery FILE (a gallery that knows the run's pallets)",
                409,
            )
        s = self.session(rig_path)
        emb = s.embedder("")
        if not os.path.exists(path):
            demo = s.gallery("demo", emb)
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            tmp = f"{path}.tmp{os.getpid()}"
            with sqlite3.connect(tmp) as dst:
                demo.conn.backup(dst)
            os.replace(tmp, path)
        return emb, Gallery.open(path, emb.model_version)


def identities(desk: GalleryDesk, path: str, rig_path: str | None) -> list[str]:
    """The identities the review gallery knows (for the operator's choice)."""
    _, g = desk.open(path, rig_path)
    try:
        return g.identities()
    finally:
        g.close()


def _crops(run_dir: str, ev: dict | None) -> list:
    import cv2

    if not ev:
        return []
    out = []
    for rel in ev["crops"]:
        img = cv2.imread(os.path.join(run_dir, *rel.split("/")), cv2.IMREAD_COLOR)
        if img is not None:
            out.append(img)
    return out


def _text(value: Any, what: str, limit: int, required: bool = True) -> str:
    text = value.strip() if isinstance(value, str) else ""
    if required and not text:
        raise ReviewError(f"{what} is required")
    if len(text) > limit or any(unicodedata.category(c) in ("Cc", "Cf") for c in text):
        # control and format characters (a right-to-left override) could disguise who
        # decided what in the audit files
        raise ReviewError(f"{what}: at most {limit} printable characters")
    return text


def decide(
    root: RunsRoot,
    name: str,
    request: dict,
    gallery_option: str | None,
    desk: GalleryDesk,
) -> dict:
    """Take one decision (``request``: place, decision, identity or new name, reviewer,
    reason) on run ``name``; return the decision as recorded. :class:`ReviewError` for a
    decision that cannot be taken (nothing is written then)."""
    from perception.errors import GalleryError, ModelError

    run_dir = root.run_dir(name)
    place = _text(request.get("place"), "place", 64)
    kind = request.get("decision")
    if kind not in DECISIONS:
        raise ReviewError(
            "choose a decision: this pallet (identity), new pallet (new_pallet) "
            "or leave unknown (leave_unknown)"
        )
    reviewer = _text(request.get("reviewer"), "reviewer", 64)
    reason = _text(request.get("reason"), "reason", 500, required=False)
    rows, planned, error = read_rows(run_dir)
    if error:
        raise ReviewError(f"the run's rows cannot be read: {error}", 409)
    row = next((r for r in rows if r["place"] == place), None)
    if row is None and place in planned:
        raise ReviewError(
            f"{place} was not scanned: there is nothing to review (resume the run)", 409
        )
    if row is None:
        raise ReviewError(f"no row for place {place!r:.70}", 404)
    if not needs_review(row):
        raise ReviewError(f"{place} is not an exception ({row.get('status')})", 409)
    ident = ""
    if kind != "leave_unknown":
        field = "identity" if kind == "identity" else "new_name"
        ident = _text(request.get(field), "identity" if kind == "identity" else "new name", 64)
        if not IDENTITY.fullmatch(ident) or ident in ("unknown", "empty"):
            raise ReviewError(f"{ident!r:.70} cannot be a pallet identity")
    drones = drone_dirs(run_dir)
    rel = drones.get(row.get("drone") or "") or next(iter(drones.values()))
    gpath = gallery_path(root, run_dir, gallery_option)
    header = read_header(os.path.join(run_dir, rel, "ticks.jsonl"))
    rig = header_path(header, header.get("rig"))
    with _LOCK, _run_lock(run_dir):  # one decision at a time, in every console process
        try:  # before the gallery changes: a decision that cannot be recorded is not taken
            decisions = read_review(run_dir, strict=True)
        except ReviewFileError as exc:
            raise ReviewError(str(exc), 409) from None
        _not_decided_meanwhile(decisions, place, request)
        event = None
        if kind != "leave_unknown":
            crops = _crops(run_dir, evidence(run_dir, rel, place))
            if len(crops) != 3:
                raise ReviewError(
                    f"{place} has {len(crops)} block crops, a gallery change needs 3: "
                    "leave it unknown",
                    409,
                )
            try:
                event = _learn(desk, gpath, rig, kind, ident, crops, name, place, reviewer, reason)
            except (GalleryError, ModelError) as exc:
                raise ReviewError(str(exc), 409) from None
        record = {
            "seq": _next_seq(decisions),
            "place": place,
            "answer": ident if ident else "unknown",
            "decision": kind,
            "reviewer": reviewer,
            "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "reason": reason,
            "original_answer": row.get("answer"),
            "original_status": row.get("status"),
            "drone": row.get("drone"),
            "gallery": os.path.abspath(gpath) if event is not None else None,
            "gallery_event": event,
        }
        write_review(run_dir, decisions + [record])
    return record


def decision_seq(decisions: list[dict], index: int) -> int:
    """The number of decision ``index`` of a run (1, 2, ...: its ``seq``, or its place in
    ``review.json`` for one recorded before decisions were numbered)."""
    seq = decisions[index].get("seq")
    return seq if type(seq) is int else index + 1


def _next_seq(decisions: list[dict]) -> int:
    return max((decision_seq(decisions, i) for i in range(len(decisions))), default=0) + 1


def _not_decided_meanwhile(decisions: list[dict], place: str, request: dict) -> None:
    """A decision changes the place as its reviewer saw it: ``replaces`` names the place's
    decision it replaces (its ``seq``; none for a first decision). Another reviewer's
    decision since (in another tab, another console) refuses it, before the gallery is
    touched: both were recorded, the last won and both gallery changes stayed."""
    last = max((i for i, d in enumerate(decisions) if d.get("place") == place), default=None)
    current = decision_seq(decisions, last) if last is not None else None
    replaces = request.get("replaces")
    if isinstance(replaces, str):  # a form field
        replaces = int(replaces) if replaces.strip().isdigit() else (replaces.strip() or None)
    if replaces is None and current is None:
        return
    if type(replaces) is int and replaces == current:
        return
    if current is None:
        raise ReviewError(f"{place} has no decision {replaces!r:.20} to replace: reload", 409)
    d = decisions[last]
    raise ReviewError(
        f"{place} was decided by {d.get('reviewer')} at {d.get('time')} "
        f"({d.get('answer')}, decision {current}): reload to see it; to change it, decide "
        f'again from there ("replaces": {current})',
        409,
    )


@contextlib.contextmanager
def _run_lock(run_dir: str):
    """An exclusive lock on the run's review (``.review.lock`` in its folder): consoles in
    other processes over the same runs folder wait for it too (a thread lock alone lost
    decisions two consoles had both answered 200)."""
    fd = os.open(os.path.join(run_dir, ".review.lock"), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def _learn(
    desk: GalleryDesk,
    gpath: str,
    rig: str | None,
    kind: str,
    ident: str,
    crops: list,
    run: str,
    place: str,
    reviewer: str,
    reason: str,
) -> int:
    """Change the gallery; return the history event's number."""
    from perception.gallery_views import png_bytes

    emb, g = desk.open(gpath, rig)
    try:
        desc = emb.describe(crops)
        vis = desc.visibility if emb.occlusion_aware else None
        tag = f"{REVIEW_RUN} {run} {place} by {reviewer}"
        if kind == "identity":
            if ident not in g.identities():
                raise ReviewError(f"{ident} is not enrolled in {g.path}: choose new pallet", 409)
            g.add_view(ident, desc.vectors, vis, crops, run=tag, note=reason)
        else:
            if ident in g.identities():
                raise ReviewError(f"{ident} is enrolled already: choose it as the identity", 409)
            source = f"operator review of {run} {place}" + (f": {reason}" if reason else "")
            g.enrol(ident, desc.vectors, [png_bytes(c) for c in crops], source, False, vis, tag)
        events = g.history(ident)
        return int(events[-1]["event"]) if events else 0
    finally:
        g.close()
