"""No import circles inside the package, and every import goes down the layers.

Every ``import`` statement of every module (at the top or inside a function: a deferred import
still ties the two modules together) is an edge of the module graph; a strongly connected set of
more than one module is a circle. ``from pkg import name`` counts as an import of ``pkg.name``
when that is a module, else of ``pkg``. The one allowed exception is the root package
``stillpoint``: the public facade, whose ``main()`` defers to the command line and whose
``__version__`` the command line reads.

Layers (docs/layout.md), each importing only itself and the layers below it:
core (``stillpoint.engine.core``) <- drivers (``stillpoint.drivers``) <- engine (the rest of
``stillpoint.engine``) <- CLI (``stillpoint.tools``) <- the facade (``stillpoint``). An edge
going up is a violation, with no exceptions.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"_stillpoint": "stillpoint", "engine": "stillpoint.engine",
            "drivers": "stillpoint.drivers", "tools": "stillpoint.tools"}
FACADE = "stillpoint"


def _modules() -> dict[str, tuple[Path, bool]]:
    mods = {}
    for folder, package in PACKAGES.items():
        base = ROOT / folder
        for path in base.rglob("*.py"):
            if "__pycache__" in path.parts:
                continue
            parts = list(path.relative_to(base).with_suffix("").parts)
            is_init = parts[-1] == "__init__"
            if is_init:
                parts = parts[:-1]
            mods[".".join([package, *parts])] = (path, is_init)
    return mods


def _edges(mods) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, (path, is_init) in mods.items():
        package = name if is_init else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod
                           for a in node.names]
            else:
                continue
            graph[name].update(t for t in targets if t in mods and t != name and t != FACADE)
    return graph


def _circles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
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
                        found.append(sorted(comp))
    return found


def test_the_package_has_no_import_circles():
    mods = _modules()
    assert len(mods) > 100  # the walk found the package
    circles = _circles(_edges(mods))
    assert circles == [], "import circles: " + "; ".join(" <-> ".join(c) for c in circles)


LAYERS = (("core", "stillpoint.engine.core"), ("drivers", "stillpoint.drivers"),
          ("engine", "stillpoint.engine"), ("cli", "stillpoint.tools"), ("facade", "stillpoint"))

def layer(module: str) -> int:
    """Index in ``LAYERS`` of a module's layer (the first prefix that matches)."""
    for i, (_, prefix) in enumerate(LAYERS):
        if module == prefix or module.startswith(prefix + "."):
            return i
    raise ValueError(f"{module} is in no layer")


def upward_edges(graph) -> set[tuple[str, str]]:
    """Every import of a module in a higher layer."""
    return {(a, b) for a, targets in graph.items() for b in targets if layer(b) > layer(a)}


def test_imports_go_down_the_layers():
    up = sorted(upward_edges(_edges(_modules())))
    assert not up, ("imports against the layers core <- drivers <- engine <- CLI: "
                    + "; ".join(f"{a} ({LAYERS[layer(a)][0]}) imports {b} ({LAYERS[layer(b)][0]})"
                                for a, b in up))


def test_the_layer_check_finds_an_upward_edge():
    graph = {"stillpoint.engine.core.blocks": {"stillpoint.drivers.byteio"},
             "stillpoint.drivers.cwa": {"stillpoint.engine.core.blocks"},
             "stillpoint.tools.cli": {"stillpoint.engine.run"}}
    assert upward_edges(graph) == {("stillpoint.engine.core.blocks", "stillpoint.drivers.byteio")}


def test_the_check_finds_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _circles(graph) == [["a", "b", "c"]]
