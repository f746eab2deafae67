"""The node registry: every node type a mission may use, with its declared ports.

The engine knows no concrete drone nodes; packages register theirs here (see
:func:`register`). Validation, conversion, ``btrun nodes``, the Groot2 palette and the node
reference are all generated from these declarations.
"""

from __future__ import annotations

import difflib
import inspect
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bt_engine.ports import (
    INOUT,
    INPUT,
    NO_DEFAULT,
    OUTPUT,
    Port,
    PortType,
    PortValueError,
    blackboard_ref,
)

if TYPE_CHECKING:
    from bt_engine.node import BTNode

ACTION, CONDITION, CONTROL, DECORATOR, SUBTREE = (
    "Action",
    "Condition",
    "Control",
    "Decorator",
    "SubTree",
)
KINDS = (ACTION, CONDITION, CONTROL, DECORATOR, SUBTREE)


@dataclass
class NodeModel:
    """What the registry knows of one node type."""

    id: str
    kind: str
    cls: type[BTNode]
    ports: dict[str, Port]
    description: str
    min_children: int
    max_children: int | None
    category: str = ""

    @property
    def summary(self) -> str:
        """The first line of the description."""
        return self.description.strip().splitlines()[0] if self.description.strip() else ""


def _children_range(kind: str, cls: Any) -> tuple[int, int | None]:
    explicit = getattr(cls, "children_range", None)
    if explicit is not None:
        return explicit
    if kind == CONTROL:
        return (1, None)
    if kind == DECORATOR:
        return (1, 1)
    return (0, 0)


#: a node ID or a port name as a mission file writes it (an XML tag or attribute name)
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
_NAME_RULE = "expected an XML name: letters, digits, _, . and -, starting with a letter or _"
#: attribute names a port may not take (BehaviorTree.CPP reserves them, and ``_`` ones)
RESERVED_PORTS = ("name", "ID")


def _checked_ports(node_id: str, declared: Any) -> dict[str, Port]:
    """``{name: port}`` of a node's declaration, refusing (``ValueError``) an ID or port
    name a mission file cannot write, a port declared twice, a default its own type does
    not take (it would fail only when the node first ran, in flight) or its own range
    (``low``/``high``) refuses, and an empty range."""
    if not _NAME.match(node_id):
        raise ValueError(f"node ID {node_id!r}: {_NAME_RULE}")
    ports: dict[str, Port] = {}
    for p in declared:
        if not isinstance(p, Port):
            raise ValueError(
                f"node {node_id!r}: a port must be declared with bt_engine.ports.input_port / "
                f"output_port / inout_port, got {p!r:.60}"
            )
        where = f"node {node_id!r}, port {p.name!r}"
        if not isinstance(p.type, PortType):
            raise ValueError(
                f"{where}: type {p.type!r:.40} is not a port type (use one of bt_engine.ports: "
                "FLOAT, INT, BOOL, STRING, DURATION, VEC3, ANY, ...)"
            )
        if p.direction not in (INPUT, OUTPUT, INOUT):
            raise ValueError(
                f"{where}: direction {p.direction!r:.40} (expected {INPUT!r}, {OUTPUT!r} or "
                f"{INOUT!r})"
            )
        for bound in ("low", "high"):
            value = getattr(p, bound)
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, (int, float))
            ):
                raise ValueError(f"{where}: {bound} must be a number, got {value!r:.40}")
        if not isinstance(p.name, str) or not _NAME.match(p.name) or p.name.startswith("_"):
            raise ValueError(f"{where}: {_NAME_RULE}, not starting with _")
        if p.name in RESERVED_PORTS:
            raise ValueError(f"{where}: a reserved attribute name ({', '.join(RESERVED_PORTS)})")
        if p.name in ports:
            raise ValueError(f"{where}: declared twice")
        if p.low is not None and p.high is not None and p.low > p.high:
            raise ValueError(f"{where}: range {p.low:g} to {p.high:g} is empty")
        if p.default is not NO_DEFAULT and p.default is not None and not blackboard_ref(p.default):
            try:
                value = p.type.convert(p.default)
            except PortValueError as exc:
                raise ValueError(f"{where}: default {p.default!r}: {exc}") from None
            outside = p.out_of_range(value)
            if outside is not None:  # every mission keeping the default would be refused
                raise ValueError(f"{where}: default outside its range: {outside}")
        ports[p.name] = p
    return ports


class Registry:
    """A name -> :class:`NodeModel` table with aliases (e.g. ``SequenceStar``)."""

    def __init__(self) -> None:
        self._models: dict[str, NodeModel] = {}
        self._aliases: dict[str, str] = {}

    def register(self, cls: type[BTNode], *, replace: bool = False) -> type[BTNode]:
        """Register a node class; its ``bt_id``, ``kind``, ``ports`` and docstring describe it.

        Returns the class so this can be used as a class decorator.
        """
        node_id = getattr(cls, "bt_id", None) or cls.__name__
        kind = cls.kind
        if kind not in KINDS:
            raise ValueError(f"{cls.__name__}: kind must be one of {KINDS}, not {kind!r}")
        if node_id in self._models and not replace and self._models[node_id].cls is not cls:
            raise ValueError(
                f"a node called {node_id!r} is already registered: give yours another bt_id "
                f"(that one: {_defined_at(self._models[node_id].cls)})"
            )
        aliases = tuple(getattr(cls, "aliases", ()))
        for name in (node_id, *aliases):
            taken = self._aliases.get(name)
            if taken is not None and taken != node_id and not replace:
                raise ValueError(
                    f"{name!r} is already an alias of node {taken!r}: give yours another "
                    + ("bt_id" if name == node_id else "alias")
                    + f" (that one: {_defined_at(self._models[taken].cls)})"
                )
            if name != node_id and name in self._models and not replace:
                raise ValueError(
                    f"alias {name!r} of {node_id!r} is already a node: give yours another "
                    f"alias (that one: {_defined_at(self._models[name].cls)})"
                )
        from bt_engine.node import unimplemented

        missing = unimplemented(cls)
        if missing is not None:  # it had loaded, then failed in the air
            raise ValueError(f"{node_id} {missing}")
        ports = _checked_ports(node_id, getattr(cls, "ports", ()))
        self._check_enums(node_id, ports)
        lo, hi = _children_range(kind, cls)
        model = NodeModel(
            id=node_id,
            kind=kind,
            cls=cls,
            ports=ports,
            description=inspect.cleandoc(cls.__doc__ or ""),
            min_children=lo,
            max_children=hi,
            category=getattr(cls, "category", "") or "",
        )
        self._models[node_id] = model
        for alias in aliases:
            self._aliases[alias] = node_id
        return cls

    def _check_enums(self, node_id: str, ports: dict[str, Port]) -> None:
        """Refuse (``ValueError``) an enum member name of ``ports`` that a registered node
        already gives another value: scripts read every member by its bare name
        (``ym := FIXED_YAW``), so the first one registered would silently win in every
        mission, whichever node the mission uses."""
        mine = [
            (name, value, p.name)
            for p in ports.values()
            for name, value in (getattr(p.type, "members", None) or {}).items()
        ]
        if not mine:
            return
        for other in self._models.values():
            if other.id == node_id:
                continue
            for q in other.ports.values():
                theirs = getattr(q.type, "members", None) or {}
                for name, value, port in mine:
                    if name in theirs and theirs[name] != value:
                        raise ValueError(
                            f"node {node_id!r}, port {port!r}: enum name {name} = {value} is "
                            f"already {name} = {theirs[name]} (port {q.name!r} of node "
                            f"{other.id!r}: {_defined_at(other.cls)}); scripts read enum "
                            "names bare in every mission: name yours otherwise"
                        )

    def get(self, node_id: str) -> NodeModel | None:
        """Return the model of ``node_id`` (or of the node it is an alias of), else None."""
        m = self._models.get(node_id)
        if m is None and node_id in self._aliases:
            m = self._models[self._aliases[node_id]]
        return m

    def __contains__(self, node_id: str) -> bool:
        return self.get(node_id) is not None

    def ids(self) -> list[str]:
        """All registered IDs, sorted."""
        return sorted(self._models)

    def models(self) -> list[NodeModel]:
        """All models, sorted by kind then ID."""
        order = {k: i for i, k in enumerate(KINDS)}
        return sorted(self._models.values(), key=lambda m: (order[m.kind], m.category, m.id))

    def suggest(self, node_id: str, extra: list[str] | None = None) -> str | None:
        """Return the closest known name to ``node_id`` (for "did you mean")."""
        names = list(self._models) + list(self._aliases) + list(extra or [])
        lowered = {n.lower(): n for n in names}
        if node_id.lower() in lowered:
            return lowered[node_id.lower()]
        close = difflib.get_close_matches(node_id, names, n=1, cutoff=0.6)
        return close[0] if close else None

    def copy(self) -> Registry:
        """A copy that can take extra nodes without changing this one."""
        r = Registry()
        r._models = dict(self._models)
        r._aliases = dict(self._aliases)
        return r


#: The process-wide default registry; built-ins and plug-in packages register here.
REGISTRY = Registry()


def register(cls: type[BTNode]) -> type[BTNode]:
    """Class decorator: register ``cls`` in the default registry; the one way to add a leaf.

    ::

        @register
        class LinePoint(SyncActionNode):
            # its docstring is the node's description (first line: the summary)
            bt_id = "LinePoint"  # optional: the class name by default
            ports = (input_port("fraction", FLOAT, 0.5, "0 = start, 1 = end"), ...)

    Once its module is imported, the node is known to validation and conversion, ``btrun
    nodes``, the Groot2 palette (``btrun nodes --groot``) and the node reference
    (``btrun nodes --markdown docs/nodes.md``). ``register(cls)`` works as a plain call too.
    """
    return REGISTRY.register(cls)


def _defined_at(cls: Any) -> str:
    """``module, file:line`` where ``cls`` is defined, for a collision's message."""
    module = getattr(cls, "__module__", "?")
    try:
        _, line = inspect.getsourcelines(cls)
        return f"{module}, {inspect.getsourcefile(cls)}:{line}"
    except (OSError, TypeError):
        return str(module)


def suggest_name(name: str, candidates: list[str]) -> str | None:
    """Closest of ``candidates`` to ``name``, or None."""
    close = difflib.get_close_matches(name, candidates, n=1, cutoff=0.6)
    return close[0] if close else None
