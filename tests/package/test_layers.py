"""The package is cut by layer (README "Layout"): no import circles, lazy imports included, and no
layer imports one above it. Read from the source with ``ast`` (nothing is imported)."""

import ast
import os
from collections import defaultdict

import pytest

PKG = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "olti_drake")

#: What each layer may import besides itself (the top-level modules of olti_drake are open to all).
ALLOWED = {
    "model": set(),
    "io": {"model"},
    "estimation": {"model", "io"},
    "sim": {"model", "io", "estimation"},
    "hardware": {"model", "io", "estimation", "sim"},
    "report": {"model", "io", "estimation", "sim", "hardware"},
    "cli": {"model", "io", "estimation", "sim", "hardware", "report"},
}


def _modules():
    out = {}
    for dirpath, _, files in os.walk(PKG):
        for f in files:
            if f.endswith(".py"):
                rel = os.path.relpath(os.path.join(dirpath, f), os.path.dirname(PKG))[:-3].replace(os.sep, ".")
                out[rel[: -len(".__init__")] if rel.endswith(".__init__") else rel] = os.path.join(dirpath, f)
    return out


def _graph():
    """{module: {imported olti_drake modules}}, every import statement (module level or in a function)."""
    mods, graph = _modules(), defaultdict(set)
    for name, path in mods.items():
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            graph[name].update(t for t in targets if t in mods and t != name and t.startswith("olti_drake"))
    return mods, graph


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in ALLOWED) else ""


def test_no_relative_imports():
    """Absolute imports only: a module's imports read the same wherever it lives."""
    for name, path in _modules().items():
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        rel = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level > 0]
        assert not rel, f"{name}: relative imports at lines {rel}"


def test_no_import_circles():
    mods, graph = _graph()
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(mods):
        if v not in index:
            visit(v)
    assert not cycles, f"import circles: {cycles}"


def test_no_layer_imports_one_above_it():
    _, graph = _graph()
    bad = sorted(f"{a} -> {b}" for a, targets in graph.items() for b in targets
                 if _layer(a) and _layer(b) and _layer(a) != _layer(b) and _layer(b) not in ALLOWED[_layer(a)])
    assert not bad, "imports against the layer order (README Layout): " + "; ".join(bad)


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_every_layer_says_what_it_holds(layer):
    with open(os.path.join(PKG, layer, "__init__.py"), encoding="utf-8") as fh:
        doc = ast.get_docstring(ast.parse(fh.read()))
    assert doc and len(doc) > 40, layer
