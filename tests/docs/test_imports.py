"""One direction of dependency, no circles.

Every module of ``links1/``, ``links1_app/``, ``plugins/links1_mitsuba/`` and ``compare/`` is
parsed with :mod:`ast` (imports inside functions count: a lazy import couples two modules all
the same). An import of ``a.b.c`` is an edge to the module ``a.b.c``, or to ``a.b`` when ``c``
is a name in it (``from a.b import c``); a package's ``__init__`` is a module with its own
edges, and importing ``a.b`` is no edge to ``a`` (Python runs ``a/__init__`` first, but the
package re-exports are not what a module depends on). Only edges between the project's own
modules count; an import by name at run time (a partitioning ``module:callable`` renderer,
``importlib.import_module``) is not an edge.

The tests: no strongly connected component of more than one module (a circle, named in the
failure); three layers by package, each importing only itself and the layers below it
(``PACKAGE_LAYERS``): the core ``links1`` <- the plugin ``links1_mitsuba`` <- the front ends
``links1_app``; inside the core, each package imports only the packages below it (``LAYERS``:
geometry never imports scene loading, shading or tracing).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Where each top-level package lives (the plugin suite is installed from plugins/).
PACKAGES = {"links1": ROOT / "links1", "links1_mitsuba": ROOT / "plugins" / "links1_mitsuba",
            "links1_app": ROOT / "links1_app", "compare": ROOT / "compare"}

#: The layers by top-level package, bottom up, each with the packages it may import: the core,
#: the Mitsuba plugin (built on the core), the front ends (CLI, pytest plugin, renderer factory,
#: partitioning runtime: above both renderers). ``compare`` (benchmarks) stands above them all.
PACKAGE_LAYERS = {
    "links1": {"links1"},
    "links1_mitsuba": {"links1", "links1_mitsuba"},
    "links1_app": {"links1", "links1_mitsuba", "links1_app"},
    "compare": {"links1", "links1_mitsuba", "links1_app", "compare"},
}

#: The core's packages, bottom up, each with the core packages it may import: one way, so no
#: circle between packages (docs/architecture.md, "Packages"). ``links1.errors`` (the error
#: classes every layer raises) and ``links1.interrupts`` (Ctrl-C held and raised at safe points,
#: for the front ends and the plugin) are the modules outside them; ``links1`` itself (its
#: ``__init__``, the public API) is the top, and a module belongs to the longest name here that
#: contains it.
LAYERS = {
    "links1.errors": set(),
    "links1.interrupts": set(),
    "links1.maths": {"links1.errors"},
    "links1.imaging": {"links1.errors"},
    "links1.geometry": {"links1.errors", "links1.maths"},
    "links1.sensor": {"links1.errors", "links1.maths"},
    "links1.shading": {"links1.errors", "links1.maths", "links1.imaging", "links1.geometry"},
    "links1.scene": {"links1.errors", "links1.maths", "links1.imaging", "links1.geometry",
                     "links1.sensor", "links1.shading"},
    "links1.tracing": {"links1.errors", "links1.maths", "links1.imaging", "links1.geometry",
                       "links1.sensor", "links1.shading", "links1.scene"},
    # the paper's partitioning maths: strategies and the eq. 4.1 load model (scene files read
    # for their shapes and camera); running a plan is the front ends' (links1_app.partition)
    "links1.partition": {"links1.errors", "links1.maths", "links1.geometry", "links1.sensor",
                         "links1.scene"},
    "links1": {"links1.errors", "links1.interrupts", "links1.maths", "links1.imaging", "links1.geometry",
               "links1.sensor", "links1.shading", "links1.scene", "links1.tracing", "links1.partition"},
}


def _package(module: str) -> str:
    return module.split(".")[0]


def modules() -> dict[str, Path]:
    """Dotted module name -> source file, for every module of the project's packages."""
    out = {}
    for pkg, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join([pkg, *parts])] = path
    return out


def _resolve(name: str, known) -> str | None:
    """The project module an import of ``name`` loads: ``name`` itself, else the longest
    known prefix (``a.b.c`` with ``c`` a name in ``a.b``); None outside the project."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def imports(module: str, path: Path, known) -> set[str]:
    """The project modules that ``module`` imports anywhere in its source."""
    is_package = path.name == "__init__.py"
    package = module if is_package else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module
            # from P import x: the submodule P.x when there is one, else the module P
            targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in known else stem for a in node.names]
        else:
            continue
        for t in targets:
            dep = _resolve(t, known)
            if dep is not None and dep != module:
                out.add(dep)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports(m, p, mods) for m, p in mods.items()}


def strongly_connected(g: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of ``g`` (iterative), each sorted."""
    index, low, on_stack, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in sorted(g):
        if root in index:
            continue
        work = [(root, iter(sorted(g[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(g[w]))))
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
                    out.append(sorted(comp))
    return out


def _cycle(g, comp) -> list[str]:
    """One circle through the first module of ``comp`` (a shortest path back to it)."""
    start, members = comp[0], set(comp)
    prev, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(g[v] & members):
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return [start, *reversed(path[:-1]), start] if len(path) > 1 else [start, v, start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp


def test_graph_sees_lazy_and_relative_imports():
    """The parser finds what the tests below rely on: a relative import, a ``from P import
    submodule``, an import inside a function, a package ``__init__``'s own edges."""
    g = graph()
    assert "links1.errors" in g["links1"]                       # links1/__init__: from .errors import ...
    assert "links1_app.partition.runtime" in g["links1_app.partition.cli"]  # from .runtime import ...
    assert "links1_mitsuba" in g["links1_app.renderers"]        # the factory's lazy import
    assert "links1.tracing.aovs" in g["links1_mitsuba.renderer"]   # a plugin -> core edge
    assert "links1" not in g["links1.tracing.render"]              # no edge to a parent package
    assert "links1.scene.params" in g["links1.scene.scene"]        # from . import params (a submodule)


def test_no_import_circles():
    g = graph()
    circles = [c for c in strongly_connected(g) if len(c) > 1]
    assert not circles, "import circles (each: one loop, then the whole component):\n" + "\n".join(
        f"  {' -> '.join(_cycle(g, c))}   [{', '.join(c)}]" for c in circles)


def test_packages_import_down_only():
    """core (``links1``) <- plugin (``links1_mitsuba``) <- front ends (``links1_app``): no
    module imports, lazily or not, a package above its own (the core never names the plugin
    or a front end; the plugin never names a front end)."""
    g = graph()
    assert set(PACKAGE_LAYERS) == set(PACKAGES)
    assert {"links1.tracing.render", "links1.errors", "links1", "links1_app.cli", "links1_mitsuba"} <= set(g)
    bad = sorted(f"{m} -> {d}" for m in g for d in g[m] if _package(d) not in PACKAGE_LAYERS[_package(m)])
    assert not bad, f"modules importing a package above their own: {bad}"


def _layer(module: str) -> str | None:
    return max((k for k in LAYERS if module == k or module.startswith(k + ".")), key=len, default=None)


def test_core_packages_depend_one_way():
    """Every core module lies in one of ``LAYERS``, and imports (lazily or not) only its own
    package and the packages ``LAYERS`` lets its package import."""
    names = list(LAYERS)
    assert all(dep in names[:i] for i, k in enumerate(names) for dep in LAYERS[k])  # bottom up
    g = graph()
    core = [m for m in g if _package(m) == "links1"]
    assert {"links1", "links1.partition.loadmodel", "links1.tracing.render"} <= set(core)
    assert not [m for m in core if _layer(m) is None], "core modules outside the LAYERS packages"
    bad = sorted(f"{m} -> {d}" for m in core for d in g[m] if _package(d) == "links1"
                 and _layer(d) != _layer(m) and _layer(d) not in LAYERS[_layer(m)])
    assert not bad, f"core modules importing a package above their own: {bad}"


if __name__ == "__main__":  # python tests/docs/test_imports.py: print the circles
    G = graph()
    for comp in strongly_connected(G):
        if len(comp) > 1:
            print(" -> ".join(_cycle(G, comp)), f"  [{len(comp)} modules]")
    sys.exit(0)
