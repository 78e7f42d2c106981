"""No import cycles among mocapflow modules, and the core's layers import only downward
(static, parsed with ast).

Every import statement counts, those inside functions too: a deferred import cannot make
a half-initialised module, but a cycle through it is still two modules that cannot be
understood, tested or moved apart. Across the whole tree ``if TYPE_CHECKING:`` blocks (which
never run) are skipped; in ``framework/`` they count too: a type-only import is still a
dependency a reader follows. ``KNOWN`` lists the cycles left, each with why (none today).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {
    "_mocapflow": "mocapflow",
    "framework": "mocapflow.framework",
    "plugins": "mocapflow.plugins",
    "pipelines": "mocapflow.pipelines",
}

#: Cycles still present: frozensets of module names (each one a strongly connected component).
KNOWN: dict[frozenset[str], str] = {}


def modules() -> dict[str, Path]:
    out = {}
    for folder, pkg in PACKAGES.items():
        for p in (ROOT / folder).rglob("*.py"):
            parts = list(p.relative_to(ROOT / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([pkg, *parts])] = p
    return out


def _top_level(body: list[ast.stmt], type_only: bool = False):
    """Every import statement of ``body``, nested ones included; those under TYPE_CHECKING
    only with ``type_only``."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
            continue
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test) and not type_only:
            yield from _top_level(node.orelse, type_only)
            continue
        for name in ("body", "orelse", "finalbody", "handlers", "cases"):
            for child in getattr(node, name, None) or []:
                if isinstance(child, ast.AST):
                    sub = [child] if isinstance(child, ast.stmt) else getattr(child, "body", [])
                    yield from _top_level(sub, type_only)


def import_graph(type_only: bool = False) -> dict[str, set[str]]:
    mods = modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in _top_level(ast.parse(path.read_text(encoding="utf-8")).body, type_only):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = mod.split(".")[: len(mod.split(".")) - node.level + (1 if is_pkg else 0)]
                    src = ".".join(base + ([node.module] if node.module else []))
                else:
                    src = node.module or ""
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in mods else src for a in node.names]
            graph[mod] |= {t for t in targets if t in mods and t != mod}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = set()
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.add(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(frozenset(comp))
    return out


def test_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_graph_sees_relative_and_deferred_imports():
    g = import_graph()
    # inside a function of plugins/similarity/search/lng.py
    assert "mocapflow.plugins.similarity.search.certified" in g["mocapflow.plugins.similarity.search.lng"]
    assert "mocapflow.framework.schema" in g["mocapflow.framework.motion_tables"]
    assert "mocapflow.plugins.similarity.search.lng" in g["mocapflow.plugins.similarity.search.logical"]


def test_no_import_cycles_but_the_known_ones():
    """Over the whole tree, imports made only for type checking included."""
    found = set(cycles(import_graph(type_only=True)))
    new = found - set(KNOWN)
    assert not new, "import cycles: " + "; ".join(" <-> ".join(sorted(c)) for c in new)
    gone = set(KNOWN) - found
    assert not gone, f"fixed, remove from KNOWN: {gone}"


#: The core's layers, bottom first; a module imports only modules of its own layer or below.
LAYERS: dict[str, tuple[str, ...]] = {
    # what motions, datasets and matches are; the workspace's files; no component, no run
    "data model": (
        "errors",
        "bounded_json",
        "params",
        "progress",
        "threads",
        "schema",
        "labels",
        "quaternions",
        "joints",
        "_fk_kernels",
        "skeleton",
        "motion",
        "markers",
        "database",
        "normalize",
        "motion_tables",
        "matching",
        "registry",
        "workspace",
        "output_paths",
        "datasets",
        "clip_refs",
        "cleaning",
        "plotting",
    ),
    # what a component, a step's context, an executor and a plugin hook must provide
    "contracts": ("components", "context", "hookspecs"),
    # the default step of each kind
    "steps": ("queries", "steps", "export"),
    # pipelines, plans, plugins, executors, the runner, the catalog and the CLI
    "engine": ("options", "config", "plan", "plugins", "executors", "runner", "catalog", "commands", "cli"),
    # the Python API the `mocapflow` package re-exports
    "python api": ("api",),
    # what third parties test their components with
    "testing": ("synthetic", "conformance", "testing"),
    # the lazy public names of mocapflow.framework
    "facade": ("",),
}
CORE = "mocapflow.framework"


def _layer_of() -> dict[str, int]:
    return {f"{CORE}.{m}" if m else CORE: i for i, (_, members) in enumerate(LAYERS.items()) for m in members}


def test_every_core_module_has_a_layer():
    core = {m for m in modules() if m == CORE or m.startswith(CORE + ".")}
    assert core == set(_layer_of()), f"unlisted: {core - set(_layer_of())}, gone: {set(_layer_of()) - core}"


def test_no_import_cycle_in_the_core_type_only_imports_included():
    graph = import_graph(type_only=True)
    core = {m: {t for t in ts if t in _layer_of()} for m, ts in graph.items() if m in _layer_of()}
    found = cycles(core)
    assert not found, "import cycles: " + "; ".join(" <-> ".join(sorted(c)) for c in found)


def test_core_layers_import_only_downward():
    layer, names = _layer_of(), list(LAYERS)
    graph = import_graph(type_only=True)
    up = [
        f"{m} ({names[layer[m]]}) imports {t} ({names[layer[t]]})"
        for m in layer
        for t in sorted(graph[m])
        if t in layer and layer[t] > layer[m]
    ]
    assert not up, "imports that go up a layer:\n" + "\n".join(up)
