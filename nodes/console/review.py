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
used (``--set gallery=FILE``), else the runs folder's review gallery of the run's world:
``site-gallery-<world>-<key>.sqlite`` (:func:`world_label`: the world file's name and a
short hash of what its demo gallery enrols), one per world, so that runs of several worlds
in one runs folder never share one. A file that does not exist yet starts as a copy of the
demo gallery of the run's world, so the next inventory flown with ``--set
gallery=THAT_FILE`` knows everything the demo knew plus the operator's decisions. A
gallery the console started records that world (:data:`WORLD_META` in its metadata), and a
decision of a run of another world into it is refused.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
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
from nodes.console.runs import drone_dirs, evidence_of, needs_review, read_rows
from nodes.gallery.cli import REVIEW_RUN
from perception.gallery import identity_problem

#: the default review gallery of a world: ``site-gallery-<world label>.sqlite``
DEFAULT_STEM = "site-gallery"
#: the gallery metadata key naming the world whose demo gallery the console copied
WORLD_META = "console_review_world"
DECISIONS = ("identity", "new_pallet", "leave_unknown")
_LOCK = threading.Lock()  # one decision at a time: the gallery and review files


class ReviewError(Exception):
    """A decision that cannot be taken, in one line (``status``: the HTTP status)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


def world_label(header: dict) -> tuple[str | None, str | None]:
    """(label, problem) of the run's world for its default review gallery: ``<world file
    name>-<8 hex digits>``, the digits a hash of what the world's demo gallery enrols
    (:func:`nodes.gallery.demo.appearance_key`, with the run's ``--set world.*`` look and
    stock items), so two worlds, or one world whose ``not_enrolled`` pallets differ, never
    share a gallery. (None, why) when the world cannot be read on this machine."""
    rig_path = header_path(header, header.get("rig") or header.get("rig_arg"))
    if not rig_path:
        return None, "the run's tick log names no rig"
    if not os.path.isfile(rig_path):
        return None, f"the run's rig {rig_path} is not on this machine"
    sets = tuple(
        s for s in header.get("sets") or [] if isinstance(s, str) and s.startswith("world.")
    )
    key = (rig_path, sets)
    if key not in _LABELS:
        _LABELS[key] = _world_label(rig_path, sets)
        if len(_LABELS) > 64:
            _LABELS.pop(next(iter(_LABELS)))
    return _LABELS[key]


_LABELS: dict[tuple, tuple[str | None, str | None]] = {}


def _world_label(rig_path: str, sets: tuple) -> tuple[str | None, str | None]:
    try:
        from drivers.rig.loader import load_rig
        from drivers.sim.world import load_world
        from nodes.gallery.demo import appearance_key
        from nodes.gallery.enrol_scan import look_overrides

        rig = load_rig(rig_path, dict(s.split("=", 1) for s in sets if "=" in s))
        if rig.kind != "sim":
            return None, f"the run's rig {rig_path} has no simulated world (no demo gallery)"
        data = load_world(rig.world_path, look_overrides(rig.world_overrides)).data
    except Exception as exc:  # noqa: BLE001 - said on the page, and a decision is refused
        return None, f"the world of the run's rig {rig_path} cannot be read ({exc})"[:300]
    digest = hashlib.sha256(appearance_key(data)).hexdigest()[:8]
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", os.path.splitext(os.path.basename(rig.world_path))[0])
    return f"{stem[:40]}-{digest}", None


def gallery_choice(root: RunsRoot, run_dir: str, option: str | None) -> dict:
    """Where the review decisions of the run in ``run_dir`` go (see the module doc):
    ``path`` (None: nowhere, ``problem`` says why), ``source`` (``option``: --gallery,
    ``run``: the run's own gallery file, ``world``: the runs folder's gallery of the run's
    world), ``world`` (the run's world label, None if not known) and ``problem``."""
    drones = drone_dirs(run_dir)
    header = read_header(os.path.join(run_dir, next(iter(drones.values())), "ticks.jsonl"))
    label, why = world_label(header) if header else (None, "the run has no tick log header")
    out = {"path": None, "source": None, "world": label, "problem": None}
    if option:
        return {**out, "path": os.path.abspath(option), "source": "option"}
    for item in header.get("sets") or []:
        if isinstance(item, str) and item.startswith("gallery="):
            value = header_path(header, item.split("=", 1)[1])
            if value and item != "gallery=demo" and os.path.isfile(value):
                return {**out, "path": os.path.abspath(value), "source": "run"}
    if label is None:
        return {
            **out,
            "problem": f"{why}: the console cannot tell which world's demo gallery a "
            "review gallery of this run starts from; start the console with --gallery FILE "
            "(a gallery that knows the run's pallets) to teach it",
        }
    path = os.path.join(root.root, f"{DEFAULT_STEM}-{label}.sqlite")
    return {**out, "path": path, "source": "world"}


def gallery_path(root: RunsRoot, run_dir: str, option: str | None) -> str | None:
    """The gallery file review decisions of the run go to (None: none, see
    :func:`gallery_choice`)."""
    return gallery_choice(root, run_dir, option)["path"]


def gallery_world(path: str) -> str | None:
    """The world a gallery the console started was copied for (:data:`WORLD_META`), None
    for any other gallery (or no file)."""
    if not os.path.isfile(path):
        return None
    try:
        conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            row = conn.execute("SELECT value FROM meta WHERE key = ?", (WORLD_META,)).fetchone()
        finally:
            conn.close()
    except sqlite3.Error:
        return None
    return str(row[0]) if row else None


def check_world(choice: dict) -> None:
    """:class:`ReviewError` (409) when the chosen gallery was started by the console for
    another world than the run's: its pallets are not the run's."""
    path, world = choice.get("path"), choice.get("world")
    if not path or choice.get("source") == "run":
        return
    seeded = gallery_world(path)
    if seeded is not None and world is not None and seeded != world:
        raise ReviewError(
            f"{path} was started from the demo gallery of world {seeded}, this run flew "
            f"world {world}: its pallets are not this run's; start the console without "
            "--gallery (a review gallery per world), or with the gallery of this world",
            409,
        )


class GalleryDesk:
    """The models and gallery a review needs, loaded on the first decision (the embedder
    takes a few seconds; pages never wait for it)."""

    def __init__(self) -> None:
        self._sessions: dict[Any, Any] = {}

    def session(self, rig_path: str | None, sets: tuple = ()) -> Any:
        """A perception session of the run's rig with its ``--set world.*`` items (its world
        names the demo gallery: the one the run flew with)."""
        from drivers.rig.loader import load_rig
        from nodes.perception_session import PerceptionSession

        key = (rig_path or "", tuple(sets))
        if key not in self._sessions:
            found = rig_path if rig_path and os.path.isfile(rig_path) else None
            overrides = dict(s.split("=", 1) for s in sets if "=" in s) if found else None
            rig = load_rig(found, overrides)
            self._sessions[key] = PerceptionSession(rig)
        return self._sessions[key]

    def open(
        self, path: str, rig_path: str | None, sets: tuple = (), world: str | None = None
    ) -> tuple[Any, Any]:
        """(embedder, gallery ``path``), the file first copied from the demo gallery of the
        rig's world when it does not exist (recording ``world``, the run's world label, in
        its metadata; :class:`ReviewError` if that rig is not on this machine: another
        world's demo would know none of the run's pallets)."""
        from nodes.perception_session import PerceptionError
        from perception.gallery import Gallery

        if not os.path.exists(path) and (not rig_path or not os.path.isfile(rig_path)):
            raise ReviewError(
                f"the run's rig {rig_path} is not on this machine: a new review gallery "
                "starts as the demo gallery of the run's world; start the console with "
                "--gallery FILE (a gallery that knows the run's pallets)",
                409,
            )
        s = self.session(rig_path, sets)
        emb = s.embedder("")
        if not os.path.exists(path):
            try:
                demo = s.gallery("demo", emb)
            except PerceptionError as exc:
                raise ReviewError(f"no demo gallery to start {path} from: {exc}", 409) from None
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            tmp = f"{path}.tmp{os.getpid()}"
            with sqlite3.connect(tmp) as dst:
                demo.conn.backup(dst)
                if world:
                    dst.execute(
                        "INSERT INTO meta VALUES (?, ?) ON CONFLICT (key) DO UPDATE "
                        "SET value = excluded.value",
                        (WORLD_META, world),
                    )
            dst.close()
            os.replace(tmp, path)
        return emb, Gallery.open(path, emb.model_version)


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
        why = identity_problem(ident)  # a WMS's own ids (PAL/2026/0001) as a gallery's
        if why is not None or ident.lower() in ("unknown", "empty", "not_scanned"):
            raise ReviewError(
                f"{ident!r:.70} cannot be a pallet identity" + (f": {why}" if why else "")
            )
    drones = drone_dirs(run_dir)
    rel = drones.get(row.get("drone") or "") or next(iter(drones.values()))
    choice = gallery_choice(root, run_dir, gallery_option)
    gpath = choice["path"]
    if kind != "leave_unknown":
        if gpath is None:
            raise ReviewError(choice["problem"] or "no review gallery for this run", 409)
        check_world(choice)
    header = read_header(os.path.join(run_dir, rel, "ticks.jsonl"))
    rig = header_path(header, header.get("rig"))
    sets = tuple(
        s for s in header.get("sets") or [] if isinstance(s, str) and s.startswith("world.")
    )
    with _LOCK, _run_lock(run_dir):  # one decision at a time, in every console process
        try:  # before the gallery changes: a decision that cannot be recorded is not taken
            decisions = read_review(run_dir, strict=True)
        except ReviewFileError as exc:
            raise ReviewError(str(exc), 409) from None
        same = _same_as_latest(decisions, place, kind, ident, reviewer, reason)
        if same is not None:  # a double click, a retry: recorded once
            return {**same, "already_recorded": True}
        _not_decided_meanwhile(decisions, place, request)
        event = None
        if kind != "leave_unknown":
            crops = _crops(run_dir, evidence_of(run_dir, rel, place))
            if len(crops) != 3:
                raise ReviewError(
                    f"{place} has {len(crops)} block crops, a gallery change needs 3: "
                    "leave it unknown",
                    409,
                )
            try:
                event = _learn(
                    desk,
                    (gpath, rig, sets, choice["world"]),
                    kind,
                    ident,
                    crops,
                    name,
                    place,
                    reviewer,
                    reason,
                )
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


def _same_as_latest(
    decisions: list[dict], place: str, kind: str, answer: str, reviewer: str, reason: str
) -> dict | None:
    """The place's latest decision when the one asked is the same (decision, answer,
    reviewer and reason): a second click on "Decide", or a retry after a lost answer,
    records nothing again (nor teaches the gallery the same view twice)."""
    last = next((d for d in reversed(decisions) if d.get("place") == place), None)
    if last is None:
        return None
    asked = (kind, answer or "unknown", reviewer, reason)
    had = (last.get("decision"), last.get("answer"), last.get("reviewer"), last.get("reason") or "")
    if asked != had:
        return None
    return {**last, "seq": decision_seq(decisions, decisions.index(last))}


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
    where: tuple,
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

    emb, g = desk.open(*where)
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
