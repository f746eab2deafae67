"""Load, validate and build a mission; tick it and inspect every node and the blackboard.

This is the Python face of btrun for tests and tools::

    from bt_engine import Mission, SimClock

    m = Mission.from_file("missions/hello.xml", clock=SimClock())
    m.tick()
    assert m.status_of("wait") == "RUNNING"
    m.blackboard["target"] = (1.0, 0.0, 1.0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, MutableMapping
from typing import Any

from bt_engine.builder import build_tree
from bt_engine.clock import Clock, SimClock
from bt_engine.inputs import mission_inputs, parse_set_value, typed_inputs
from bt_engine.loading import load_spec
from bt_engine.node import (
    FAILURE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    BTNode,
    MissionContext,
    NodeRuntimeError,
    NodeStatus,
)
from bt_engine.node_checks import said
from bt_engine.plugin_code import conversion_said
from bt_engine.registry import REGISTRY, Registry
from bt_engine.spec import Loc, MissionError, MissionSpec, Problem
from bt_engine.validate import (
    validate,
)


def check_file(path: str, registry: Registry | None = None) -> tuple[MissionSpec, list[Problem]]:
    """Load and validate ``path``; return the spec and every problem found."""
    spec = load_spec(path)
    return spec, validate(spec, registry or REGISTRY)


#: Distinct leaf failures a mission remembers (more are counted in the last one's place).
MAX_LEAF_FAILURES = 200


class _BlackboardView(MutableMapping):
    """Dictionary view of a mission's root blackboard scope."""

    def __init__(self, mission: Mission) -> None:
        self._m = mission

    def __getitem__(self, key: str) -> Any:
        return self._m.scope.get(key)

    def __setitem__(self, key: str, value: Any) -> None:
        self._m.scope.set(key, value)

    def __delitem__(self, key: str) -> None:
        self._m.scope.unset(key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._m.scope.all_items())

    def __len__(self) -> int:
        return len(self._m.scope.all_items())

    def __repr__(self) -> str:
        return f"Blackboard({self._m.scope.all_items()!r})"


class Mission:
    """A validated, built mission: tick it and inspect it.

    Args:
        spec: a loaded spec (see :func:`load_spec`).
        clock: the mission clock (default: a fresh :class:`SimClock`).
        registry: the node registry (default: the process-wide one).
        vehicle: the vehicle leaves talk to, if any.
        resources: extra shared objects for plug-in nodes.
        blackboard: initial entries (e.g. from ``--set``).
        namespace: the py_trees blackboard namespace (default: a fresh unique one).

    Raises:
        MissionError: with every located problem if the spec is invalid.
    """

    def __init__(
        self,
        spec: MissionSpec,
        clock: Clock | None = None,
        registry: Registry | None = None,
        vehicle: Any = None,
        resources: dict[str, Any] | None = None,
        blackboard: dict[str, Any] | None = None,
        namespace: str | None = None,
        enums: dict[str, int] | None = None,
    ) -> None:
        self.registry = registry or REGISTRY
        problems = validate(spec, self.registry)
        if problems:
            raise MissionError(problems)
        self.spec = spec
        self.clock = clock or SimClock()
        self.ctx = MissionContext(self.clock, vehicle, dict(resources or {}), dict(enums or {}))
        for model in self.registry.models():
            for port in model.ports.values():
                members = getattr(port.type, "members", None)
                if members:
                    for k, v in members.items():
                        self.ctx.enums.setdefault(k, v)
        self.root, self.scope, self.nodes, self._changes = build_tree(
            spec, self.registry, self.ctx, namespace
        )
        self.blackboard: MutableMapping[str, Any] = _BlackboardView(self)
        # a default goes on the blackboard as a --set of it would: typed (laps="3" is 3)
        written = mission_inputs(spec)
        self.inputs = {
            k: parse_set_value(v) if isinstance(v, str) else v for k, v in written.items()
        }
        typed_inputs(spec, self.inputs, written)  # a default of no value of its type: validate
        for k, v in self.inputs.items():
            if k not in (blackboard or {}):
                self.scope.set(k, v)
        for k, v in (blackboard or {}).items():
            self.scope.set(k, v)
        self._by_path = {n.path: n for n in self.nodes}
        self._by_name: dict[str, list[BTNode]] = {}
        for n in self.nodes:
            self._by_name.setdefault(n.name, []).append(n)
        self.ticks = 0
        self.last_failure = ""
        self._leaf_failure = ""
        self.finished: dict[str, str] = {}
        #: every distinct leaf failure of the run (``"<leaf> failed (<loc>): why" -> times``),
        #: also those a Fallback or a retry handled: ``btrun`` lists them after the result
        self.leaf_failures: dict[str, int] = {}
        self._drained = True
        self.status: NodeStatus = self.root.bt_status

    @classmethod
    def from_file(cls, path: str, **kwargs: Any) -> Mission:
        """Load, validate and build the mission in ``path`` (XML or YAML)."""
        return cls(load_spec(path), **kwargs)

    # -- ticking --------------------------------------------------------------------------
    def tick(self) -> NodeStatus:
        """Tick the root once (again at once if a node asked for a wake-up); return its status.

        As in BehaviorTree.CPP's ``tickOnce``, a finished root is reset to IDLE afterwards,
        so the next tick starts the mission again; :attr:`status` keeps the result.
        """
        ctx = self.ctx
        if not self._drained:  # nobody reads the changes: keep the list bounded
            self._changes.clear()
        self._drained = False
        status = self.root.execute_tick()
        # As BT.CPP's WakeUpSignal: the flag is consumed only when checked (root RUNNING), so a
        # wake-up emitted in a tick that finished the root carries over to the next tick.
        while status is RUNNING and ctx.woken:
            ctx.check_stop()
            ctx.woken = False
            status = self.root.execute_tick()
        # The last leaf that failed, in this tick or an earlier one: a tree that handles a
        # failure (a Fallback that flies home, then ForceFailure) still ends on its cause.
        last = None
        for node, _, st in self._changes:
            if st is FAILURE and not node.children:
                why = getattr(node, "failure_reason", "")  # leaves may say why they failed
                last = f"{node.describe()} failed ({node.loc})" + (f": {why}" if why else "")
                self._note_failure(last)
        if last is not None:
            self._leaf_failure = last
        if status is FAILURE:
            self.last_failure = self._leaf_failure
        if status is not RUNNING and status is not SKIPPED:
            self.root.reset_status()
        self.ticks += 1
        self.status = status
        return status

    def preflight(self, set_keys: set[str] | None = None, loads: bool = True) -> list[Problem]:
        """Let every node check its inputs against the run before anything flies.

        A node class may define ``preflight() -> list[Problem | tuple[str, str]]`` (e.g. an
        inventory plan naming places the world does not have). A ``(port, message)`` pair
        is located where the port's value came from: the node's element in the mission
        file, or ``--set`` when it reads a blackboard entry given there (``set_keys``).
        A preflight that raises is reported as a problem, never as a traceback.

        The checks of node classes with ``preflight_loads = True`` (they load models or
        build a gallery: seconds to minutes) run last, and only once every other check and
        the ``--set`` values have passed: a typo is refused at once, not after a build.
        ``loads=False`` leaves them out (a fleet check that already found a problem).
        """
        out = self._preflight(lambda node: not getattr(node, "preflight_loads", False), set_keys)
        out.extend(self.set_value_problems(set_keys or set()))
        if not out and loads:
            out = self._preflight(lambda node: getattr(node, "preflight_loads", False), set_keys)
        return out

    def value_problems(self) -> list[Problem]:
        """The values the mission file itself gives its ports through the blackboard (a
        ``<TreeNodesModel>`` default, a SubTree call's value) that a port reading them
        cannot take, type or range: what ``btrun validate`` says without a rig (the nodes'
        own pre-flight checks need one)."""
        return self.set_value_problems(set()) + self._preflight(lambda node: True, set(), False)

    def _preflight(
        self, which: Callable[[Any], bool], set_keys: set[str] | None, checks: bool = True
    ) -> list[Problem]:
        """The problems of the pre-flight checks of the nodes ``which`` selects (``checks``
        False: their port ranges only)."""
        out: list[Problem] = []
        ranged: set[str] = set()  # --set entries a range check refused already
        for node in self.nodes:
            if not which(node):
                continue
            check = getattr(node, "preflight", None) if checks else None
            found: list[Any] = []
            try:
                found = list(check() or ()) if check is not None else []
            except Exception as exc:  # a broken check must not hide the others
                found = [("", f"pre-flight check failed: {said(exc, type(node))}")]
            ranges = self._range_problems(node)
            for item in found + ranges:
                if isinstance(item, Problem):
                    out.append(item)
                    continue
                if not (
                    isinstance(item, (tuple, list))
                    and len(item) == 2
                    and all(isinstance(x, str) for x in item)
                ):  # a plug-in's check that returned something else: said, not a traceback
                    where = node.loc or Loc("<mission>")
                    out.append(
                        Problem(
                            where,
                            f"{node.describe()}: pre-flight check returned {item!r:.80}; "
                            "expected (port, message) pairs or Problems",
                        )
                    )
                    continue
                port, message = item
                key = node.input_entry(port) if port else None
                if key is not None and node.scope is not None:  # through SubTree remapping
                    key = node.scope.display_key(key)
                if key is not None and key in (set_keys or ()):
                    if item in ranges:  # several leaves' ranges for one value: the first
                        if key in ranged:
                            continue
                        ranged.add(key)
                    out.append(Problem(Loc("--set", 0, 0), f"{key}: {message}"))
                else:
                    where = node.loc or Loc("<mission>")
                    out.append(Problem(where, f"{node.describe()}: {message}"))
        # one --set value refused alike by several nodes reading it is said once
        seen: set[tuple[Any, ...]] = set()
        unique = []
        for p in out:
            key = (p.loc.file, p.loc.line, p.loc.col, p.message)
            if key not in seen:
                seen.add(key)
                unique.append(p)
        return unique

    @staticmethod
    def _range_problems(node: Any) -> list[tuple[str, str]]:
        """``(port, message)`` for every input outside its declared range
        (:attr:`bt_engine.ports.Port.low` / ``high``); ports not readable before flight
        (written in flight) are checked when read."""
        out = []
        for decl in type(node).ports:
            if not decl.reads or (decl.low is None and decl.high is None):
                continue
            try:
                value = node.get_input(decl.name, ranged=False)
            except Exception:  # noqa: BLE001 - written in flight, or a bad value said elsewhere
                continue
            why = decl.out_of_range(value)
            if why is not None:
                out.append((decl.name, why))
        return out

    def set_value_problems(self, set_keys: set[str]) -> list[Problem]:
        """A value on the blackboard before flight that a port reading it cannot take
        (``sweep_speed=abc`` read as a number, ``nan`` where a finite number is needed), once
        per entry, with the first node that reads it: refused before flight, not found by the
        first tick that reads it, after take-off. Ports inside SubTrees are followed through
        their remapping. A ``--set`` value (``set_keys``) is said at ``--set``; one the
        mission file gives (a ``<TreeNodesModel>`` default, a SubTree call's value) at the
        node that reads it."""
        out: list[Problem] = []
        done: set[str] = set()
        for node in self.nodes:
            for decl in type(node).ports:
                if not decl.reads:
                    continue
                key = node.input_entry(decl.name)
                if key is None or node.scope is None:
                    continue
                entry = node.scope.display_key(key)
                if entry in done:
                    continue
                try:
                    node.get_input(decl.name, ranged=False)  # ranges: _range_problems
                except NodeRuntimeError as exc:
                    text = str(exc)
                    if "which is not set" in text:  # an output writes it in flight
                        continue
                    why = text.split(f"from {{{key}}}: ", 1)[-1]
                except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plug-in port
                    # type's convert raising other than PortValueError: said, located (it
                    # had been a traceback of btrun validate and run)
                    value = node.scope.get(key, None)
                    why = conversion_said(decl, type(node).__name__, value, exc)
                else:
                    continue
                done.add(entry)
                where = f" ({node.loc})" if node.loc is not None else ""
                if entry in set_keys:
                    value = self.scope.get(entry, None)
                    out.append(
                        Problem(
                            Loc("--set", 0, 0),
                            f"{entry}={value}: {why} (read as '{decl.name}' by "
                            f"{node.describe()}{where})",
                        )
                    )
                else:
                    loc = node.loc or Loc(self.spec.file or "mission", 0, 0)
                    out.append(
                        Problem(
                            loc,
                            f"{{{key}}}: the value the mission gives it (a default or a "
                            f"SubTree's value) cannot be read as '{decl.name}' by "
                            f"{node.describe()}: {why}",
                        )
                    )
        return out

    def _note_failure(self, text: str) -> None:
        """Remember a leaf failure (each distinct one once, counted; bounded)."""
        counts = self.leaf_failures
        if text in counts:
            counts[text] += 1
        elif len(counts) < MAX_LEAF_FAILURES:
            counts[text] = 1

    def drain_changes(self) -> dict[str, str]:
        """Statuses that changed since the last call, as ``{path: status}``."""
        changes = self._changes
        first: dict[BTNode, NodeStatus] = {}
        for n, old, _ in changes:
            first.setdefault(n, old)
        # only nodes whose status differs from before the ticks (IDLE->SUCCESS->IDLE is not
        # a change); ``_value_`` is ``.value`` without the enum descriptor call (hot path)
        out = {n.path: n.bt_status._value_ for n, old in first.items() if n.bt_status is not old}
        #: leaves that finished during the drained ticks, even if reset to IDLE since
        self.finished = {
            n.path: st._value_
            for n, _, st in changes
            if (st is SUCCESS or st is FAILURE) and not n.children
        }
        changes.clear()
        self._drained = True
        return out

    def halt(self) -> None:
        """Halt every running node (actions stop; the tree goes back to IDLE).

        A halt that raises (a node's halt stopped by the watchdog) leaves every node IDLE
        all the same, so that nothing halts the node again; while a halt is under way (one
        that never returned, on another thread) a second one does nothing."""
        if getattr(self, "_halting", False):
            return
        self._halting = True
        try:
            if self.root.bt_status is RUNNING:
                self.root.halt_node()
        except BaseException:
            for node in self.nodes:
                node.reset_status()
            self._halting = False
            raise
        self._halting = False
        self.root.reset_status()

    def close(self) -> None:
        """Halt and remove this mission's entries from the shared py_trees blackboard."""
        self.halt()
        self.scope.clear()

    # -- inspection -----------------------------------------------------------------------
    def node(self, key: str) -> BTNode:
        """Return a node by its unique ``name`` or its path (``Main/Sequence/GoTo``).

        Raises KeyError (listing candidates) if unknown or ambiguous.
        """
        if key in self._by_path:
            return self._by_path[key]
        found = self._by_name.get(key, [])
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise KeyError(f"name {key!r} is ambiguous; use a path: {[n.path for n in found]}")
        ends = [n for n in self.nodes if n.path.endswith("/" + key)]
        if len(ends) == 1:
            return ends[0]
        raise KeyError(f"no node {key!r}; paths are: {list(self._by_path)}")

    def status_of(self, key: str) -> str:
        """The BehaviorTree.CPP status (``"RUNNING"`` ...) of a node by name or path."""
        return self.node(key).bt_status.value

    def statuses(self) -> dict[str, str]:
        """Every node's status, by path (pre-order)."""
        return {n.path: n.bt_status.value for n in self.nodes}

    def running_nodes(self) -> list[BTNode]:
        """Nodes currently RUNNING, outermost first."""
        return [n for n in self.nodes if n.bt_status is RUNNING]
