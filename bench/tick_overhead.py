"""Per-tick cost of btrun's engine next to raw py_trees and BehaviorTree.CPP (behaviortreepy).

One generator describes each tree; the same description is built in all three engines:

* ``mission``: a mission-like tree. ``Parallel(success_count=1)`` of a telemetry branch
  (``ReactiveSequence[link_ok, stream]``, RUNNING forever) then the mission
  ``Sequence[ReactiveSequence guard[3 checks, Sequence legs], land]``; each leg is
  ``Fallback[reached_i (FAILURE), ReactiveSequence[path_clear_i, healthy_i, goto_i]]`` and
  every action runs for ``--action-ticks`` ticks. A tick visits ~15 nodes whatever the size.
* ``worst``: every node is visited every tick: ``ReactiveSequence`` of k groups
  ``Sequence[m always-succeeding conditions]`` and one action that stays RUNNING.

Engines and what is compared (leaves do the same work in each; a first pass checks that the
three engines return the same root status and tick the same number of leaves):

* btrun: nodes built by ``Mission`` from XML; leaves are ``ConditionNode.check`` /
  ``StatefulActionNode.on_start/on_running``. Timed as bare ``Mission.tick()`` and as
  ``Runner.step()`` on a SimClock with the trace on, off, and trace + tick log (``btrun run``).
* py_trees: ``Sequence(memory=True)`` for Sequence, ``Sequence(memory=False)`` for
  ReactiveSequence, ``Selector(memory=True)`` for Fallback, ``Parallel(SuccessOnOne)``;
  leaves implement ``update()``. Timed as ``root.tick_once()``.
* BT.CPP: the XML built by BT.CPP's own factory. Leaves are Python callbacks
  (``register_simple_condition`` / ``register_simple_stateful_action``), or the C++
  ``AlwaysSuccess``/``AlwaysFailure`` for the conditions. Timed as ``Tree.tick_once()`` (the
  call ``Mission.tick`` reproduces) and as ``tick_exactly_once()``: ``tick_once`` also polls
  the wake-up signal with a zero timeout, which costs ~50-75 us of wall time per tick (a
  timed futex wait, mostly asleep) and ~20 us of CPU. No node here emits a wake-up, so both
  tick the same nodes (checked).

Columns: median/p95/mean wall time of one tick (``perf_counter_ns``), and the mean CPU time
of this thread per tick (``thread_time_ns``), which other processes do not inflate.

Then the CPU share of the 1,000-node trees at 100 Hz and the tick-period jitter of a small
mission run by ``Runner`` on a ``WallClock`` at 50 Hz. It prints figures; it is not a test::

    .venv/bin/python bench/tick_overhead.py            # full run (3.5-4.5 min on the shared 2-core machine)
    .venv/bin/python bench/tick_overhead.py --quick    # seconds
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import py_trees
from py_trees.common import ParallelPolicy
from py_trees.common import Status as PT

from bt_engine import REGISTRY, RUNNING, SUCCESS, Mission, Runner, SimClock, WallClock
from bt_engine.loading import load_xml
from bt_engine.node import ConditionNode, StatefulActionNode
from bt_engine.registry import Registry
from bt_engine.ticklog import TickLog

try:
    import behaviortreepy as bt
except ImportError:  # pragma: no cover - optional dev dependency
    bt = None

#: an action that never finishes within a benchmark
FOREVER = 10**12


# ------------------------------------------------------------------ one tree description
@dataclass
class Spec:
    """One node: ``kind`` is a control ID or a leaf (``Pass``, ``Fail``, ``Work``)."""

    kind: str
    children: list[Spec] = field(default_factory=list)
    attrs: dict[str, str] = field(default_factory=dict)
    #: ticks a ``Work`` action stays busy (RUNNING for ticks-1 ticks, then SUCCESS)
    ticks: int = 0

    def count(self) -> int:
        return 1 + sum(c.count() for c in self.children)


def P() -> Spec:
    return Spec("Pass")


def F() -> Spec:
    return Spec("Fail")


def W(ticks: int) -> Spec:
    return Spec("Work", ticks=ticks)


def mission_tree(target: int, action_ticks: int = 25) -> Spec:
    """A mission-like tree of about ``target`` nodes (11 fixed + 6 per leg)."""
    legs = max(1, round((target - 11) / 6))
    leg_nodes = [
        Spec("Fallback", [F(), Spec("ReactiveSequence", [P(), P(), W(action_ticks)])])
        for _ in range(legs)
    ]
    guard = Spec("ReactiveSequence", [P(), P(), P(), Spec("Sequence", leg_nodes)])
    body = Spec("Sequence", [guard, W(action_ticks)])
    telemetry = Spec("ReactiveSequence", [P(), W(FOREVER)])
    # telemetry first: BT.CPP's Parallel returns as soon as the mission child succeeds, while
    # py_trees' Parallel ticks every child before applying its policy
    return Spec("Parallel", [telemetry, body], {"success_count": "1", "failure_count": "1"})


def worst_tree(target: int) -> Spec:
    """About ``target`` nodes, all visited every tick: k groups of m conditions, one action."""
    k = max(1, round(math.sqrt(max(target - 2, 1))))
    m = max(1, round((target - 2) / k) - 1)
    groups = [Spec("Sequence", [P() for _ in range(m)]) for _ in range(k)]
    return Spec("ReactiveSequence", [*groups, W(FOREVER)])


def work_ticks(spec: Spec) -> dict[int, int]:
    """Pre-order index of each ``Work`` leaf -> its duration (for BT.CPP, which has no ports)."""
    out: dict[int, int] = {}
    index = 0

    def walk(s: Spec) -> None:
        nonlocal index
        if s.kind == "Work":
            out[index] = s.ticks
        index += 1
        for c in s.children:
            walk(c)

    walk(spec)
    return out


# ------------------------------------------------------------------ XML (btrun and BT.CPP)
def to_xml(spec: Spec, leaf_ids: dict[str, str] | None = None, names: bool = True) -> str:
    """BT.CPP v4 XML of ``spec``. ``Work`` leaves are named ``w<preorder>`` (BT.CPP finds its
    duration by that name); ``leaf_ids`` renames leaf types (e.g. ``Pass`` -> AlwaysSuccess)."""
    ids = {"Pass": "BenchPass", "Fail": "BenchFail", "Work": "BenchWork", **(leaf_ids or {})}
    lines: list[str] = []
    index = 0

    def walk(s: Spec, depth: int) -> None:
        nonlocal index
        tag = ids.get(s.kind, s.kind)
        attrs = dict(s.attrs)
        if s.kind == "Work":
            attrs["name"] = f"w{index}"
            if tag == "BenchWork" and names:
                attrs["ticks"] = str(s.ticks)
        index += 1
        text = "".join(f' {k}="{v}"' for k, v in attrs.items())
        pad = "  " * depth
        if s.children:
            lines.append(f"{pad}<{tag}{text}>")
            for c in s.children:
                walk(c, depth + 1)
            lines.append(f"{pad}</{tag}>")
        else:
            lines.append(f"{pad}<{tag}{text}/>")

    walk(spec, 2)
    body = "\n".join(lines)
    return (
        '<root BTCPP_format="4" main_tree_to_execute="Main">\n'
        f'  <BehaviorTree ID="Main">\n{body}\n  </BehaviorTree>\n</root>\n'
    )


# ------------------------------------------------------------------ btrun
def btrun_registry(counter: list[int] | None = None) -> Registry:
    """A copy of the default registry with the three bench leaves (counting if asked)."""
    from bt_engine.ports import INT, input_port

    class BenchPass(ConditionNode):
        """Always true."""

        bt_id = "BenchPass"

        def check(self) -> bool:
            return True

    class BenchFail(ConditionNode):
        """Always false."""

        bt_id = "BenchFail"

        def check(self) -> bool:
            return False

    class BenchWork(StatefulActionNode):
        """RUNNING for ``ticks`` - 1 ticks, then SUCCESS."""

        bt_id = "BenchWork"
        ports = (input_port("ticks", INT, 1, "ticks until SUCCESS"),)

        def on_start(self) -> object:
            self.n = 1
            self.limit = self.get_input("ticks")
            return SUCCESS if self.n >= self.limit else RUNNING

        def on_running(self) -> object:
            self.n += 1
            return SUCCESS if self.n >= self.limit else RUNNING

    classes: list[type] = [BenchPass, BenchFail, BenchWork]
    if counter is not None:

        def counting(cls: type) -> type:
            def tick_impl(self, _base=cls.tick_impl):
                counter[0] += 1
                return _base(self)

            return type(cls.__name__, (cls,), {"tick_impl": tick_impl, "__doc__": cls.__doc__})

        classes = [counting(c) for c in classes]
    reg = REGISTRY.copy()
    for cls in classes:
        reg.register(cls, replace=True)
    return reg


def build_btrun(spec: Spec, counter: list[int] | None = None, clock=None) -> Mission:
    """Build ``spec`` as a btrun Mission (SimClock unless ``clock`` is given)."""
    return Mission(
        load_xml("bench.xml", text=to_xml(spec)),
        clock=clock or SimClock(),
        registry=btrun_registry(counter),
    )


# ------------------------------------------------------------------ py_trees
class _PtPass(py_trees.behaviour.Behaviour):
    def update(self) -> PT:
        return PT.SUCCESS


class _PtFail(py_trees.behaviour.Behaviour):
    def update(self) -> PT:
        return PT.FAILURE


class _PtWork(py_trees.behaviour.Behaviour):
    def __init__(self, name: str, ticks: int) -> None:
        super().__init__(name)
        self.limit = ticks
        self.n = 0

    def initialise(self) -> None:
        self.n = 0

    def update(self) -> PT:
        self.n += 1
        return PT.SUCCESS if self.n >= self.limit else PT.RUNNING


def _pt_counting(cls: type, counter: list[int]) -> type:
    def update(self, _base=cls.update):
        counter[0] += 1
        return _base(self)

    return type(cls.__name__, (cls,), {"update": update})


def build_py_trees(spec: Spec, counter: list[int] | None = None) -> py_trees.behaviour.Behaviour:
    """Build ``spec`` from py_trees' own composites and plain behaviours."""
    leaves = {"Pass": _PtPass, "Fail": _PtFail, "Work": _PtWork}
    if counter is not None:
        leaves = {k: _pt_counting(v, counter) for k, v in leaves.items()}
    index = 0

    def make(s: Spec) -> py_trees.behaviour.Behaviour:
        nonlocal index
        name = f"{s.kind}{index}"
        index += 1
        kids = [make(c) for c in s.children]
        if s.kind == "Pass" or s.kind == "Fail":
            return leaves[s.kind](name)
        if s.kind == "Work":
            return leaves["Work"](name, s.ticks)
        if s.kind == "Sequence":
            return py_trees.composites.Sequence(name, memory=True, children=kids)
        if s.kind == "ReactiveSequence":
            return py_trees.composites.Sequence(name, memory=False, children=kids)
        if s.kind == "Fallback":
            return py_trees.composites.Selector(name, memory=True, children=kids)
        if s.kind == "Parallel":
            if s.attrs.get("success_count") != "1":
                raise ValueError("only Parallel success_count=1 is mapped to py_trees")
            return py_trees.composites.Parallel(name, ParallelPolicy.SuccessOnOne(), kids)
        raise ValueError(f"no py_trees mapping for {s.kind}")

    return make(spec)


# ------------------------------------------------------------------ BehaviorTree.CPP
def build_btcpp(spec: Spec, builtin_conditions: bool = False, counter: list[int] | None = None):
    """Build ``spec`` in BT.CPP through behaviortreepy; return the ``Tree`` (None if missing).

    ``builtin_conditions`` uses C++ AlwaysSuccess/AlwaysFailure for the conditions.
    """
    if bt is None:
        return None
    durations = {f"w{i}": t for i, t in work_ticks(spec).items()}
    factory = bt.BehaviorTreeFactory()
    ok, bad, running = bt.NodeStatus.SUCCESS, bt.NodeStatus.FAILURE, bt.NodeStatus.RUNNING
    state: dict[int, list[int]] = {}

    if counter is None:

        def passes(node):
            return ok

        def fails(node):
            return bad

        def start(node):
            # [ticks done, limit]
            s = state[node.uid()] = [1, durations[node.name()]]
            return ok if s[0] >= s[1] else running

        def keep_on(node):
            s = state[node.uid()]
            s[0] += 1
            return ok if s[0] >= s[1] else running
    else:

        def passes(node):
            counter[0] += 1
            return ok

        def fails(node):
            counter[0] += 1
            return bad

        def start(node):
            counter[0] += 1
            s = state[node.uid()] = [1, durations[node.name()]]
            return ok if s[0] >= s[1] else running

        def keep_on(node):
            counter[0] += 1
            s = state[node.uid()]
            s[0] += 1
            return ok if s[0] >= s[1] else running

    factory.register_simple_condition("BenchPass", passes)
    factory.register_simple_condition("BenchFail", fails)
    factory.register_simple_stateful_action("BenchWork", start, keep_on)
    ids = {"Pass": "AlwaysSuccess", "Fail": "AlwaysFailure"} if builtin_conditions else None
    tree = factory.create_tree_from_text(to_xml(spec, ids, names=False), bt.Blackboard.create())
    return BtcppTree(tree, factory, state)


@dataclass
class BtcppTree:
    """A BT.CPP tree with the factory and leaf state its Python callbacks need alive."""

    tree: object
    factory: object
    state: dict

    def tick_once(self):
        return self.tree.tick_once()


# ------------------------------------------------------------------ engines as tick callables
@dataclass
class Engine:
    label: str
    make: Callable[[Spec], Callable[[], object] | None]


def _btrun_tick(spec: Spec) -> Callable[[], object]:
    return build_btrun(spec).tick


def _runner_step(keep_trace: bool, log: bool = False) -> Callable[[Spec], Callable[[], object]]:
    def make(spec: Spec) -> Callable[[], object]:
        tick_log = None
        if log:
            fd, path = tempfile.mkstemp(suffix=".jsonl", prefix="btrun-bench-")
            os.close(fd)
            tick_log = TickLog(path, {"bench": True})
            _TEMP_FILES.append((tick_log, path))
        runner = Runner(build_btrun(spec), rate_hz=100.0, log=tick_log)
        runner.keep_trace = keep_trace
        return runner.step

    return make


_TEMP_FILES: list[tuple[TickLog, str]] = []


def _cleanup_temp() -> None:
    while _TEMP_FILES:
        log, path = _TEMP_FILES.pop()
        log.close()
        try:
            os.unlink(path)
        except OSError:
            pass


def _py_trees_tick(spec: Spec) -> Callable[[], object]:
    return build_py_trees(spec).tick_once


def _btcpp_tick(
    builtin: bool, method: str = "tick_once"
) -> Callable[[Spec], Callable[[], object] | None]:
    def make(spec: Spec):
        holder = build_btcpp(spec, builtin_conditions=builtin)
        if holder is None:
            return None

        call = getattr(holder.tree, method)

        def tick():
            return call()

        tick.holder = holder  # the factory and leaf state must outlive the tree

        return tick

    return make


BTRUN = "btrun Mission.tick()"
PYTREES = "py_trees root.tick_once()"
BTCPP_PY = "BT.CPP tick_once(), Python leaves"
BTCPP_CPP = "BT.CPP tick_once(), C++ conditions"
BTCPP_PY_X = "BT.CPP tick_exactly_once(), Python leaves"
BTCPP_CPP_X = "BT.CPP tick_exactly_once(), C++ conds"
RUN_TRACE = "btrun Runner.step(), trace on"
RUN_NOTRACE = "btrun Runner.step(), trace off"
RUN_LOG = "btrun Runner.step(), trace + tick log"

ENGINES = [
    Engine(BTRUN, _btrun_tick),
    Engine(RUN_TRACE, _runner_step(True)),
    Engine(RUN_NOTRACE, _runner_step(False)),
    Engine(RUN_LOG, _runner_step(True, log=True)),
    Engine(PYTREES, _py_trees_tick),
    Engine(BTCPP_PY, _btcpp_tick(False)),
    Engine(BTCPP_CPP, _btcpp_tick(True)),
    Engine(BTCPP_PY_X, _btcpp_tick(False, "tick_exactly_once")),
    Engine(BTCPP_CPP_X, _btcpp_tick(True, "tick_exactly_once")),
]


# ------------------------------------------------------------------ equivalence check
def _pt_root_status(root) -> str:
    return {PT.SUCCESS: "SUCCESS", PT.FAILURE: "FAILURE", PT.RUNNING: "RUNNING"}.get(
        root.status, "IDLE"
    )


def check_equivalent(spec: Spec, ticks: int) -> dict[str, float]:
    """Tick ``spec`` ``ticks`` times in each engine; assert they agree; return leaf ticks/tick.

    Compared per tick: the root status, and the total number of leaf ticks so far.
    """
    results: dict[str, tuple[list[str], list[int]]] = {}

    c = [0]
    m = build_btrun(spec, counter=c)
    roots, counts = [], []
    for _ in range(ticks):
        roots.append(m.tick().value)
        counts.append(c[0])
    results["btrun"] = (roots, counts)

    c = [0]
    root = build_py_trees(spec, counter=c)
    roots, counts = [], []
    for _ in range(ticks):
        root.tick_once()
        roots.append(_pt_root_status(root))
        counts.append(c[0])
    results["py_trees"] = (roots, counts)

    if bt is not None:
        # no node of these trees emits a wake-up, so tick_exactly_once must agree too
        for method in ("tick_once", "tick_exactly_once"):
            c = [0]
            tick = getattr(build_btcpp(spec, counter=c).tree, method)
            roots, counts = [], []
            for _ in range(ticks):
                roots.append(tick().name)
                counts.append(c[0])
            results[f"BT.CPP {method}"] = (roots, counts)

    ref_roots, ref_counts = results["btrun"]
    for name, (roots, counts) in results.items():
        for i in range(ticks):
            if roots[i] != ref_roots[i] or counts[i] != ref_counts[i]:
                raise AssertionError(
                    f"{name} differs from btrun at tick {i + 1}: root {roots[i]} vs "
                    f"{ref_roots[i]}, leaf ticks {counts[i]} vs {ref_counts[i]}"
                )
    return {name: counts[-1] / ticks for name, (_, counts) in results.items()}


# ------------------------------------------------------------------ timing
def time_ticks(tick: Callable[[], object], n: int, warmup: int = 20) -> tuple[list[int], int]:
    """Wall nanoseconds of each of ``n`` calls of ``tick`` (after ``warmup`` untimed calls),
    and the CPU nanoseconds this thread spent on all ``n`` (immune to other processes)."""
    for _ in range(warmup):
        tick()
    pc = time.perf_counter_ns
    out = [0] * n
    cpu0 = time.thread_time_ns()
    for i in range(n):
        t0 = pc()
        tick()
        out[i] = pc() - t0
    return out, time.thread_time_ns() - cpu0


def pct(samples: list[int], q: float) -> float:
    """The ``q`` quantile (0..1) of ``samples`` (nearest rank)."""
    s = sorted(samples)
    return float(s[min(len(s) - 1, max(0, math.ceil(q * len(s)) - 1))])


@dataclass
class Row:
    shape: str
    nodes: int
    engine: str
    samples: list[int]
    cpu_ns: int = 0

    @property
    def cpu_us(self) -> float:
        """Mean CPU time per tick (thread time), in microseconds."""
        return self.cpu_ns / len(self.samples) / 1000

    @property
    def median_us(self) -> float:
        return statistics.median(self.samples) / 1000

    @property
    def p95_us(self) -> float:
        return pct(self.samples, 0.95) / 1000

    @property
    def mean_us(self) -> float:
        return statistics.fmean(self.samples) / 1000


def calibrate(spec: Spec, budget_s: float, min_ticks: int, max_ticks: int) -> int:
    """Ticks to time per engine so btrun's bare tick uses about ``budget_s`` seconds."""
    tick = _btrun_tick(spec)
    per = statistics.median(time_ticks(tick, 30, warmup=5)[0]) / 1e9
    return int(min(max_ticks, max(min_ticks, budget_s / max(per, 1e-7))))


def measure(
    shapes: list[tuple[str, Spec]],
    engines: list[Engine],
    budget_s: float,
    rounds: int,
    min_ticks: int,
    max_ticks: int,
) -> list[Row]:
    """Time every engine on every shape; ``rounds`` interleaved rounds, samples pooled.

    Every engine starts from a fresh tree and is timed over the same ticks, so the mission
    phases (leg changes, restarts) are the same for all.
    """
    rows: dict[tuple[str, str], Row] = {}
    plan = [
        (label, spec, calibrate(spec, budget_s, min_ticks, max_ticks)) for label, spec in shapes
    ]
    try:
        for _ in range(rounds):
            for label, spec, n in plan:
                for engine in engines:
                    tick = engine.make(spec)
                    if tick is None:
                        continue
                    gc.collect()
                    samples, cpu_ns = time_ticks(tick, n)
                    row = rows.setdefault(
                        (label, engine.label), Row(label, spec.count(), engine.label, [])
                    )
                    row.samples.extend(samples)
                    row.cpu_ns += cpu_ns
                    del tick
                _cleanup_temp()
    finally:
        _cleanup_temp()
    return list(rows.values())


# ------------------------------------------------------------------ wall-clock jitter
class _BusyTimer:
    """Runner hook: how long each tick's work took (hooks + tree), apart from the sleep."""

    def __init__(self) -> None:
        self.busy_s: list[float] = []
        self._t = 0.0

    def before_tick(self, t_s: float) -> None:
        self._t = time.perf_counter()

    def after_tick(self, t_s: float) -> None:
        self.busy_s.append(time.perf_counter() - self._t)


def jitter(
    seconds: float, rate_hz: float = 50.0, nodes: int = 100, fifo: bool = False
) -> dict[str, float] | None:
    """Run a ~``nodes``-node mission with ``Runner`` on a WallClock for ``seconds``.

    Returns p50/p99/max of |tick period - 1/rate| (from ``runner.tick_periods_s``) and of
    the tick's own work, in ms. ``fifo`` runs under SCHED_FIFO priority 10 (None if the OS
    refuses), then restores the normal policy.
    """
    old = None
    if fifo:
        try:
            old = (os.sched_getscheduler(0), os.sched_getparam(0))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        except (AttributeError, OSError):
            return None
    try:
        spec = mission_tree(nodes, action_ticks=FOREVER)
        busy = _BusyTimer()
        runner = Runner(build_btrun(spec, clock=WallClock()), rate_hz=rate_hz, hooks=[busy])
        result = runner.run(max_time_s=seconds)
    finally:
        if old is not None:
            os.sched_setscheduler(0, old[0], old[1])
    period = 1.0 / rate_hz
    dev = [abs(p - period) * 1000 for p in runner.tick_periods_s] or [math.nan]
    work = [b * 1000 for b in busy.busy_s] or [math.nan]
    return {
        "ticks": result.ticks,
        "p50_ms": statistics.median(dev),
        "p99_ms": pct(dev, 0.99),
        "max_ms": max(dev),
        "work_p99_ms": pct(work, 0.99),
        "work_max_ms": max(work),
    }


# ------------------------------------------------------------------ report
def ratio(rows: list[Row], shape: str, a: str, b: str) -> float | None:
    """Median tick time of engine ``a`` over engine ``b`` on ``shape``."""
    ra = next((r for r in rows if r.shape == shape and r.engine == a), None)
    rb = next((r for r in rows if r.shape == shape and r.engine == b), None)
    if ra is None or rb is None:
        return None
    return ra.median_us / rb.median_us


def report(rows: list[Row], leaf_rates: dict[str, dict[str, float]], rate_hz: float) -> dict:
    """Print the table, ratios and CPU share; return the figures."""
    print(
        f"\n{'shape':<13}{'nodes':>6}{'leaves/tick':>12}  {'engine':<38}"
        f"{'median us':>10}{'p95 us':>9}{'mean us':>9}{'cpu us':>9}{'ticks':>8}"
    )
    for r in rows:
        leaves = leaf_rates.get(r.shape, {}).get("btrun", math.nan)
        print(
            f"{r.shape:<13}{r.nodes:>6}{leaves:>12.1f}  {r.engine:<38}"
            f"{r.median_us:>10.1f}{r.p95_us:>9.1f}{r.mean_us:>9.1f}{r.cpu_us:>9.1f}"
            f"{len(r.samples):>8}"
        )
    figures: dict = {"ratios": {}, "cpu": {}}
    print("\nratios of median tick time (btrun Mission.tick() / other; < 1: btrun is faster)")
    others = (
        (PYTREES, "py_trees"),
        (BTCPP_PY, "BT.CPP once py"),
        (BTCPP_CPP, "BT.CPP once C++"),
        (BTCPP_PY_X, "BT.CPP exactly py"),
        (BTCPP_CPP_X, "BT.CPP exactly C++"),
    )
    for shape in dict.fromkeys(r.shape for r in rows):
        parts = []
        for other, tag in others:
            v = ratio(rows, shape, BTRUN, other)
            if v is not None:
                parts.append(f"/{tag} {v:.2f}x")
                figures["ratios"][(shape, tag)] = v
        for runner_row in (RUN_TRACE, RUN_LOG):
            v = ratio(rows, shape, runner_row, BTRUN)
            if v is not None:
                parts.append(f"{runner_row.split(', ')[1]}/bare {v:.2f}x")
        print(f"  {shape:<13}" + "   ".join(parts))
    print(f"\nCPU share of one core at {rate_hz:g} Hz = CPU time per tick x {rate_hz:g} / 1 s")
    for r in rows:
        if r.nodes >= 900 and r.engine in (BTRUN, RUN_TRACE, RUN_LOG, PYTREES):
            share = r.cpu_us * 1e-6 * rate_hz * 100
            figures["cpu"][(r.shape, r.engine)] = share
            print(f"  {r.shape:<13}{r.engine:<38}{share:6.2f} %  (target < 25 %)")
    return figures


def _print_jitter(j: dict | None, what: str, rate_hz: float, seconds: float) -> None:
    if j is None:
        print(f"  {what}: not permitted here")
        return
    print(
        f"  {what}: {j['ticks']} ticks in {seconds:g} s; |period - {1000 / rate_hz:g} ms| "
        f"p50 {j['p50_ms']:.3f} ms, p99 {j['p99_ms']:.3f} ms, max {j['max_ms']:.3f} ms "
        f"(target p99 < 2 ms); tick work p99 {j['work_p99_ms']:.3f} ms, "
        f"max {j['work_max_ms']:.3f} ms"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short run (a few seconds)")
    ap.add_argument(
        "--sizes",
        default="100,1000",
        help="tree sizes in nodes (default 100,1000; '' = jitter only)",
    )
    ap.add_argument(
        "--budget",
        type=float,
        default=None,
        help="seconds of bare btrun ticking per engine, shape and round (default 0.5)",
    )
    ap.add_argument("--rounds", type=int, default=None, help="interleaved rounds (default 3)")
    ap.add_argument(
        "--action-ticks", type=int, default=25, help="ticks each mission action runs (default 25)"
    )
    ap.add_argument(
        "--jitter-seconds",
        type=float,
        default=None,
        help="length of the wall-clock jitter run (default 10, --quick 1; 0 skips it)",
    )
    ap.add_argument("--jitter-rate", type=float, default=50.0, help="jitter run rate (Hz)")
    ap.add_argument(
        "--no-fifo",
        action="store_true",
        help="skip the second jitter run under SCHED_FIFO priority",
    )
    ap.add_argument("--cpu-rate", type=float, default=100.0, help="rate for the CPU share (Hz)")
    args = ap.parse_args(argv)
    budget = args.budget if args.budget is not None else (0.03 if args.quick else 0.5)
    rounds = args.rounds if args.rounds is not None else (1 if args.quick else 3)
    jitter_s = args.jitter_seconds
    if jitter_s is None:
        jitter_s = 1.0 if args.quick else 10.0
    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]

    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(
        f"btrun tick overhead - {time.strftime('%Y-%m-%d %H:%M')}, Python "
        f"{platform.python_version()}, {platform.machine()}, {os.cpu_count()} CPUs, "
        f"load avg {load}"
    )
    print(
        f"BT.CPP via behaviortreepy: {'yes' if bt is not None else 'NOT INSTALLED (rows skipped)'}"
        f"; {budget:g} s of bare btrun ticks per engine x {rounds} round(s); "
        f"mission actions run {args.action_ticks} ticks"
    )

    shapes: list[tuple[str, Spec]] = []
    for n in sizes:
        shapes.append((f"mission-{n}", mission_tree(n, args.action_ticks)))
        shapes.append((f"worst-{n}", worst_tree(n)))

    leaf_rates: dict[str, dict[str, float]] = {}
    for label, spec in shapes:
        # the whole mission and its restart (legs x action ticks), capped
        check_ticks = min(
            300 if args.quick else 10_000, (spec.count() // 6 + 3) * args.action_ticks + 50
        )
        leaf_rates[label] = check_equivalent(spec, check_ticks)
    if shapes:
        engines = ", ".join(leaf_rates[shapes[0][0]])
        print(f"checked: same root status and leaf-tick count on every tick in {engines}")
        min_ticks, max_ticks = (30, 2000) if args.quick else (300, 20_000)
        rows = measure(shapes, ENGINES, budget, rounds, min_ticks, max_ticks)
        report(rows, leaf_rates, args.cpu_rate)

    if jitter_s > 0:
        print(
            f"\nwall-clock jitter: ~100-node mission, Runner on WallClock at "
            f"{args.jitter_rate:g} Hz (load avg {' '.join(f'{x:.2f}' for x in os.getloadavg())})"
        )
        _print_jitter(
            jitter(jitter_s, args.jitter_rate), "normal priority", args.jitter_rate, jitter_s
        )
        if not args.no_fifo:
            _print_jitter(
                jitter(jitter_s, args.jitter_rate, fifo=True),
                "SCHED_FIFO 10",
                args.jitter_rate,
                jitter_s,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
