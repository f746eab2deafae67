"""Run a mission XML in BehaviorTree.CPP itself (through ``behaviortreepy``) and record traces.

``run_btcpp(xml, ticks)`` builds the tree with BT.CPP's own factory, ticks it with
``Tree::tickOnce`` (the call that ``Mission.tick`` reproduces: it re-ticks the root at once
while the root is RUNNING and a node emitted a wake-up signal) and returns a :class:`Trace`:
the root status returned by every tick and every node's status after every tick, in
pre-order (SubTrees expanded in place, as BT.CPP numbers its nodes).

How the statuses are read: behaviortreepy exposes only the root node of a tree (no child
accessors), but it wraps BT.CPP's ``StdCoutLogger``, which prints every status transition
of every node (``[time]: <name> <PREV> -> <NEW>``) synchronously from ``setStatus``. We
redirect file descriptor 1 to a temporary file while ticking, write a marker line after each
tick, and replay the transitions per tick. Every node in a compared XML therefore needs a
unique ``name`` without spaces.

Endless ticks: some trees make ``tickOnce`` loop forever (e.g. ``Repeat num_cycles="-1"``
over ``AlwaysSuccess``: every cycle emits a wake-up, so tickOnce re-ticks without end). Such
a call never returns and cannot be interrupted from Python, so :class:`BtcppWorker` runs
BT.CPP in a child process and reports a tick that did not return within a time limit.

Test leaves: behaviortreepy's ``register_simple_*`` cannot declare ports (BT.CPP rejects an
undeclared XML attribute), so a scripted leaf reads its status sequence from its *name*:
``name="n7_RRS"`` returns RUNNING, RUNNING, SUCCESS, then cycles. :class:`StepScript` holds
that logic and is shared by both engines, so the leaves behave identically by construction.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import re
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import behaviortreepy as bt

#: a stateful action (``StatefulActionNode``) playing its name's sequence; halting it while
#: RUNNING restarts the sequence
SCRIPTED = "Scripted"
#: a synchronous action (``SyncActionNode``) playing its name's sequence (only S and F)
SCRIPTED_SYNC = "ScriptedSync"

LETTERS = {"R": "RUNNING", "S": "SUCCESS", "F": "FAILURE"}
_BT = {
    "RUNNING": bt.NodeStatus.RUNNING,
    "SUCCESS": bt.NodeStatus.SUCCESS,
    "FAILURE": bt.NodeStatus.FAILURE,
}
_LINE = re.compile(r"^\[[-\d.]+\]: (\S+)\s+(\w+) -> (\w+)\s*$")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_TICK = "@@btcpp-peer-tick"


class StepScript:
    """The status sequence of a scripted leaf, read from its name (``n3_RRSF``).

    ``next()`` returns the next status name and cycles at the end; ``restart()`` (called when
    a RUNNING node is halted) goes back to the first one.
    """

    def __init__(self, name: str) -> None:
        letters = name.rsplit("_", 1)[-1]
        if not letters or any(c not in LETTERS for c in letters):
            raise ValueError(f"scripted leaf name {name!r} must end in _<R|S|F letters>")
        self.seq = [LETTERS[c] for c in letters]
        self.index = 0

    def next(self) -> str:
        status = self.seq[self.index % len(self.seq)]
        self.index += 1
        return status

    def restart(self) -> None:
        self.index = 0


@dataclass
class Trace:
    """What one engine did: ``roots[i]`` is returned by tick i, ``statuses[i]`` are all
    nodes after tick i (pre-order, matching ``names``). ``error`` is set if tick
    ``len(roots)`` (or the tree's creation, when ``created`` is False) raised."""

    names: list[str]
    roots: list[str] = field(default_factory=list)
    statuses: list[list[str]] = field(default_factory=list)
    error: str | None = None
    created: bool = True
    #: integer blackboard entries after each tick
    blackboards: list[dict[str, int]] = field(default_factory=list)
    #: every status change during each tick, in order: ``(name, new_status)``
    transitions: list[list[tuple[str, str]]] = field(default_factory=list)
    #: entries named by ``outputs`` after each tick (None while unset)
    outputs: list[dict[str, Any]] = field(default_factory=list)


def preorder_names(xml: str) -> list[str]:
    """The ``name`` (or tag) of every node of the main tree, pre-order, SubTrees expanded."""
    root = ET.fromstring(xml)
    trees = {t.get("ID"): t for t in root.findall("BehaviorTree")}
    main = root.get("main_tree_to_execute") or next(iter(trees))
    out: list[str] = []

    def walk(el: ET.Element) -> None:
        out.append(el.get("name") or el.tag)
        if el.tag == "SubTree":
            walk(list(trees[el.get("ID")])[0])
        for child in el:
            walk(child)

    walk(list(trees[main])[0])
    return out


@contextlib.contextmanager
def _stdout_to(file) -> Iterator[None]:
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(file.fileno(), 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def make_factory(scripts: dict[int, StepScript]) -> bt.BehaviorTreeFactory:
    """A BT.CPP factory with the two scripted leaves registered (state kept in ``scripts``)."""
    factory = bt.BehaviorTreeFactory()

    def script(node) -> StepScript:
        s = scripts.get(node.uid())
        if s is None:
            s = scripts[node.uid()] = StepScript(node.name())
        return s

    def step(node):
        return _BT[script(node).next()]

    def sync_step(node):  # (behaviortreepy turns a Python exception into FAILURE)
        return _BT[script(node).next()]

    factory.register_simple_stateful_action(SCRIPTED, step, step, lambda n: script(n).restart())
    factory.register_simple_action(SCRIPTED_SYNC, sync_step)
    return factory


def run_btcpp(
    xml: str,
    ticks: int,
    blackboard: dict[str, int] | None = None,
    tick: str = "once",
    interval_s: float = 0.0,
    outputs: dict[str, str] | None = None,
) -> Trace:
    """Build ``xml`` in BT.CPP, tick it ``ticks`` times, return the :class:`Trace`.

    ``tick="once"`` uses ``tickOnce`` (re-ticks while woken up, like ``Mission.tick``);
    ``tick="exactly_once"`` uses ``tickExactlyOnce`` (for comparison only).
    Integer ``blackboard`` entries are set in the root blackboard before the tree is built,
    and read back after every tick. ``interval_s``: wall time slept between two ticks (for
    ``Timeout``/``Delay`` with real delays; BT.CPP's timers run on the wall clock).
    ``outputs`` maps entries to read after every tick to their type (``"string"``, ``"int"``,
    ``"double"`` or ``"bool"``), e.g. the ``value`` a ``LoopString`` writes.
    """
    names = preorder_names(xml)
    index = {n: i for i, n in enumerate(names)}
    if len(index) != len(names):
        raise ValueError("every node needs a unique name to be traced")
    trace = Trace(names)
    scripts: dict[int, StepScript] = {}
    factory = make_factory(scripts)
    bb = bt.Blackboard.create()
    for k, v in (blackboard or {}).items():
        bb.set_int(k, int(v))
    try:
        tree = factory.create_tree_from_text(xml, bb)
    except Exception as exc:  # BT.CPP rejected the file
        trace.created = False
        trace.error = f"{type(exc).__name__}: {exc}"
        return trace
    do_tick = tree.tick_once if tick == "once" else tree.tick_exactly_once
    with tempfile.TemporaryFile() as out:
        with _stdout_to(out):
            logger = bt.StdCoutLogger(tree)
            try:
                for i in range(ticks):
                    if i and interval_s:
                        time.sleep(interval_s)
                    try:
                        status = do_tick()
                    except Exception as exc:  # a BT.CPP exception: stop here
                        trace.error = f"{type(exc).__name__}: {exc}"
                        break
                    trace.roots.append(status.name)
                    os.write(1, f"\n{_TICK}\n".encode())
                    root_bb = tree.root_blackboard()
                    trace.blackboards.append(
                        {
                            k: root_bb.get_int(k)
                            for k in blackboard or {}
                            if root_bb.get_int(k) is not None
                        }
                    )
                    trace.outputs.append(
                        {k: _read(root_bb, k, kind) for k, kind in (outputs or {}).items()}
                    )
            finally:
                logger.flush()
                del logger
        out.seek(0)
        text = _ANSI.sub("", out.read().decode(errors="replace"))
    current = ["IDLE"] * len(names)
    changes: list[tuple[str, str]] = []
    for line in text.splitlines():
        if line == _TICK:
            trace.statuses.append(list(current))
            trace.transitions.append(changes)
            changes = []
            continue
        m = _LINE.match(line)
        if m is not None:
            name, prev, new = m.groups()
            i = index[name]
            if current[i] != prev:
                raise AssertionError(f"lost a transition of {name}: {current[i]} vs {prev}")
            current[i] = new
            changes.append((name, new))
    assert len(trace.statuses) == len(trace.roots), (trace.statuses, trace.roots)
    del tree
    return trace


def _read(bb: Any, key: str, kind: str) -> Any:
    """Entry ``key`` of a BT.CPP blackboard read as ``kind``; None if unset."""
    try:
        return getattr(bb, f"get_{kind}")(key)
    except Exception:  # an entry created for a port but never written: "Any is empty"
        return None


def _worker_main(conn) -> None:
    conn.send("ready")
    while True:
        try:
            args = conn.recv()
        except EOFError:
            return
        if args is None:
            return
        try:
            conn.send(run_btcpp(*args))
        except Exception as exc:  # report, keep serving
            conn.send(exc)


class BtcppWorker:
    """Runs :func:`run_btcpp` in a long-lived child process, with a time limit per run.

    ``run()`` returns None when BT.CPP did not finish in time (a ``tickOnce`` that never
    returns); the child is then killed and a fresh one started on the next call.
    """

    def __init__(self, timeout: float = 3.0, start_timeout: float = 60.0) -> None:
        self.timeout = timeout
        self.start_timeout = start_timeout
        self._ctx = multiprocessing.get_context("spawn")
        self._proc = None
        self._conn = None

    def _start(self) -> None:
        parent, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_worker_main, args=(child,), daemon=True)
        self._proc.start()
        child.close()
        self._conn = parent
        if not parent.poll(self.start_timeout) or parent.recv() != "ready":
            self.close(kill=True)
            raise RuntimeError("the BT.CPP worker process did not start")

    def run(
        self,
        xml: str,
        ticks: int,
        blackboard: dict[str, int] | None = None,
        tick: str = "once",
        interval_s: float = 0.0,
        timeout: float | None = None,
        outputs: dict[str, str] | None = None,
    ) -> Trace | None:
        if self._proc is None:
            self._start()
        self._conn.send((xml, ticks, blackboard, tick, interval_s, outputs))
        limit = (self.timeout if timeout is None else timeout) + ticks * interval_s
        if not self._conn.poll(limit):
            self.close(kill=True)
            return None
        result = self._conn.recv()
        if isinstance(result, Exception):
            raise result
        return result

    def close(self, kill: bool = False) -> None:
        if self._proc is None:
            return
        if kill:
            self._proc.kill()
        else:
            with contextlib.suppress(OSError):
                self._conn.send(None)
        self._proc.join(5)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()
        self._proc = self._conn = None
