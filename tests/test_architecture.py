"""The layers of docs/architecture.md, enforced: who may import whom, and no import cycle.

Every ``import`` and ``from ... import`` statement counts, at module level or inside a
function (a function-level import is still a dependency, just a late one). Imports are read
from the source with :mod:`ast`; nothing is executed.
"""

from __future__ import annotations

import ast
import os
from collections.abc import Iterator

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("bt_engine", "nodes", "drivers", "perception", "store")
#: Modules at the top of the repository: btrun_launcher is the ``btrun`` console script,
#: which must catch Ctrl-C before ``bt_engine`` is imported (so it cannot live inside it).
TOP_MODULES = ("btrun_launcher",)

#: (importer prefix, forbidden prefix, why): the rules docs/architecture.md states.
FORBIDDEN: list[tuple[str, str, str]] = [
    ("bt_engine", "drivers", "the engine knows nothing of drones"),
    ("bt_engine", "nodes", "the engine reaches plug-ins only through bt_engine.plugins"),
    ("bt_engine", "perception", "the engine knows nothing of pallets"),
    ("perception", "drivers", "perception is a library of its own"),
    ("perception", "nodes", "perception is a library of its own"),
    ("perception", "bt_engine", "perception is a library of its own"),
    ("drivers", "bt_engine", "drivers run without the engine (the runner hook is in nodes/)"),
    ("drivers", "nodes", "drivers know no leaves"),
    ("drivers.vehicle", "drivers.sim", "the Vehicle API imports no platform"),
    ("drivers.vehicle", "drivers.crazyflie", "the Vehicle API imports no platform"),
    ("drivers.vehicle", "drivers.rig", "the Vehicle API imports no platform"),
    ("drivers.vehicle", "drivers.safety", "safety sits above the Vehicle API"),
    ("drivers.vehicle", "perception", "the Vehicle API imports no platform"),
    ("drivers.crazyflie", "drivers.sim", "real hardware never imports the simulator"),
    ("drivers.crazyflie", "drivers.rig", "platforms take their parts as arguments"),
    ("drivers.crazyflie", "drivers.safety", "platforms know no safety policy"),
    ("drivers.sim", "drivers.rig", "the rig floor builds the simulator, not the reverse"),
    ("drivers.sim", "drivers.safety", "platforms know no safety policy"),
    ("drivers.safety", "drivers.sim", "safety works over the Vehicle API only"),
    ("drivers.safety", "drivers.crazyflie", "safety works over the Vehicle API only"),
    ("drivers.safety", "drivers.rig", "safety works over the Vehicle API only"),
    ("drivers.safety", "perception", "safety works over the Vehicle API only"),
    ("drivers.settings", "drivers.", "the settings language is the bottom of drivers/"),
    ("btrun_launcher", "nodes", "the console script starts the engine, which loads plug-ins"),
    ("btrun_launcher", "drivers", "the console script starts the engine, which loads plug-ins"),
    ("btrun_launcher", "perception", "the console script starts the engine only"),
    ("store", "bt_engine", "the store is the bottom layer: it imports nothing of btrun"),
    ("store", "nodes", "the store is the bottom layer: it imports nothing of btrun"),
    ("store", "drivers", "the store is the bottom layer: it imports nothing of btrun"),
    ("store", "perception", "the store is the bottom layer: it imports nothing of btrun"),
    ("bt_engine", "store", "the engine passes --store on as an opaque option"),
    ("drivers", "store", "drivers know no inventory"),
    ("drivers.guard", "drivers.sim", "the guard owns a real link; it knows no simulator"),
    ("drivers.guard", "drivers.rig", "the rig floor starts the guard, not the reverse"),
    ("drivers.guard", "drivers.safety", "the guard's landing needs no policy: it is the last"),
    ("drivers.guard", "perception", "the guard forwards no images"),
    ("drivers.vehicle", "drivers.guard", "the Vehicle API imports no platform"),
    ("drivers.crazyflie", "drivers.guard", "platforms take their link as an argument"),
]

#: Narrow exceptions to FORBIDDEN, each with its reason.
ALLOWED: list[tuple[str, str, str]] = [
    (
        "drivers.sim.emulators",
        "drivers.crazyflie.cpx",
        "the emulators speak the real CPX wire format (SITL = real code on emulated devices)",
    ),
]

#: What a module outside drivers.sim.renderers / drivers.crazyflie may use of perception.
PERCEPTION_FOR_DRIVERS = {
    "drivers.sim.renderers": ("perception.synth",),
    "drivers.crazyflie": ("perception.white_balance",),
}


def _modules() -> dict[str, str]:
    mods = {name: os.path.join(REPO, f"{name}.py") for name in TOP_MODULES}
    for pkg in PACKAGES:
        for root, dirs, files in os.walk(os.path.join(REPO, pkg)):
            dirs[:] = [d for d in dirs if not d.startswith((".", "__pycache__"))]
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(root, f), REPO)[:-3].split(os.sep)
                    if rel[-1] == "__init__":
                        rel = rel[:-1]
                    mods[".".join(rel)] = os.path.join(root, f)
    return mods


MODULES = _modules()


def _targets(module: str, path: str, node: ast.AST) -> Iterator[str]:
    if isinstance(node, ast.Import):
        for alias in node.names:
            yield alias.name
        return
    assert isinstance(node, ast.ImportFrom)
    if node.level:
        base = module.split(".")
        if not path.endswith("__init__.py"):
            base = base[:-1]
        base = base[: len(base) - (node.level - 1)]
        name = ".".join(base + ([node.module] if node.module else []))
    else:
        name = node.module or ""
    for alias in node.names:
        sub = f"{name}.{alias.name}"
        yield sub if sub in MODULES else name


def _resolve(target: str) -> str | None:
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def import_graph() -> dict[str, dict[str, int]]:
    """module -> {imported project module: line of the first such import}."""
    graph: dict[str, dict[str, int]] = {}
    for module, path in MODULES.items():
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read(), path)
        deps: dict[str, int] = {}
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for t in _targets(module, path, node):
                    r = _resolve(t)
                    if r is not None and r != module:
                        deps.setdefault(r, node.lineno)
        graph[module] = deps
    return graph


GRAPH = import_graph()


def _under(module: str, prefix: str) -> bool:
    if prefix.endswith("."):
        return module.startswith(prefix)
    return module == prefix or module.startswith(prefix + ".")


def layer_violations(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every import that breaks a rule, as ``file:line: a imports b (why)``."""
    out = []
    for module, deps in sorted(graph.items()):
        for dep, line in sorted(deps.items()):
            if _under(dep, module.split(".")[0]) and not dep.startswith("drivers"):
                continue  # within bt_engine, nodes or perception
            for importer, forbidden, why in FORBIDDEN:
                if not (_under(module, importer) and _under(dep, forbidden)):
                    continue
                if importer == "drivers.settings" and dep == module:
                    continue
                if any(_under(module, a) and _under(dep, b) for a, b, _ in ALLOWED):
                    continue
                out.append(f"{MODULES[module]}:{line}: {module} imports {dep} ({why})")
            if module.startswith("drivers") and dep.startswith("perception"):
                allowed = [
                    p
                    for m, prefixes in PERCEPTION_FOR_DRIVERS.items()
                    if _under(module, m)
                    for p in prefixes
                ]
                if not any(_under(dep, p) for p in allowed):
                    out.append(
                        f"{MODULES[module]}:{line}: {module} imports {dep} (drivers may use "
                        "only perception.synth (renderers) and perception.white_balance "
                        "(camera streams))"
                    )
    return out


def import_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    cycles: list[list[str]] = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        cycles.append(sorted(comp))
    return cycles


def test_the_graph_sees_every_package_and_function_level_imports() -> None:
    assert {m.split(".")[0] for m in MODULES} == set(PACKAGES) | set(TOP_MODULES)
    assert len(MODULES) > 100
    # a function-level import is an edge too: the Rig's platform factory is imported late
    assert "drivers.sim.world" in GRAPH["drivers.rig.loader"]


def test_every_top_level_module_is_known_here() -> None:
    """A new ``.py`` file at the top of the repository gets its rules in this file."""
    top = {f[:-3] for f in os.listdir(REPO) if f.endswith(".py")}
    assert top == set(TOP_MODULES), top ^ set(TOP_MODULES)


def test_the_launcher_imports_nothing_of_btrun_before_its_signal_handler() -> None:
    """btrun_launcher's module level imports only the standard library; bt_engine.cli is
    imported inside main(), after SIGINT/SIGTERM are routed to the recorder."""
    with open(MODULES["btrun_launcher"], encoding="utf-8") as f:
        tree = ast.parse(f.read())
    top_level = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    names = {a.name for n in top_level if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module or "" for n in top_level if isinstance(n, ast.ImportFrom)}
    assert not {n.split(".")[0] for n in names} & set(PACKAGES), names
    assert set(GRAPH["btrun_launcher"]) == {"bt_engine.cli"}


def test_no_module_imports_across_a_layer_it_must_not() -> None:
    violations = layer_violations(GRAPH)
    assert not violations, "layer violations:\n" + "\n".join(violations)


def test_there_is_no_import_cycle() -> None:
    cycles = import_cycles(GRAPH)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


@pytest.mark.parametrize(
    "importer, imported, rule",
    [
        ("bt_engine.runner", "drivers.vehicle.vehicle", "the engine knows nothing of drones"),
        ("drivers.crazyflie.cf_platform", "drivers.sim.emulators.sitl", "never imports"),
        ("drivers.vehicle.vehicle", "drivers.rig.loader", "imports no platform"),
        ("perception.gallery", "bt_engine.spec", "library of its own"),
        ("drivers.safety.supervisor", "bt_engine.runner", "without the engine"),
        ("drivers.crazyflie.cpx", "perception.gallery", "drivers may use only"),
    ],
)
def test_a_forbidden_import_is_caught(importer: str, imported: str, rule: str) -> None:
    graph = {m: dict(d) for m, d in GRAPH.items()}
    graph[importer][imported] = 1
    assert any(rule in v and importer in v for v in layer_violations(graph))


def test_a_cycle_is_caught_even_through_a_function_level_import() -> None:
    graph = {m: dict(d) for m, d in GRAPH.items()}
    graph["drivers.vehicle.types"]["drivers.vehicle.vehicle"] = 1
    assert any("drivers.vehicle.types" in c for c in import_cycles(graph))
