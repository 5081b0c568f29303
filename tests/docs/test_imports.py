"""One direction of dependency, no circles.

Every module of ``links1/``, ``plugins/links1_mitsuba/`` and ``compare/`` is parsed with
:mod:`ast` (imports inside functions count: a lazy import couples two modules all the same).
An import of ``a.b.c`` is an edge to the module ``a.b.c``, or to ``a.b`` when ``c`` is a name
in it (``from a.b import c``); a package's ``__init__`` is a module with its own edges, and
importing ``a.b`` is no edge to ``a`` (Python runs ``a/__init__`` first, but the package
re-exports are not what a module depends on). Only edges between the project's own modules
count; an import by name at run time (``importlib.import_module``: ``links1.frontends.cli.EXTENSIONS``,
a partitioning ``module:callable`` renderer) is not an edge.

The tests: no strongly connected component of more than one module (a circle, named in the
failure); the dependencies run one way, core <- plugin <- front ends: no core module (``links1``
less its front ends: the CLI, ``partition``, the pytest plugin, the renderer factory
``links1.frontends.renderers``; and less the package's ``__init__``, the public API that re-exports
``make_renderer``) names the plugin package ``links1_mitsuba`` or a front end, and the plugin
imports no front end; inside the core, each package imports only the packages below it
(``LAYERS``: geometry never imports scene loading, shading or tracing).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: Where each top-level package lives (the plugin suite is installed from plugins/).
PACKAGES = {"links1": ROOT / "links1", "links1_mitsuba": ROOT / "plugins" / "links1_mitsuba",
            "compare": ROOT / "compare"}

#: The front ends of links1: they may name the plugin (they choose and drive a renderer).
FRONT_ENDS = ("links1.frontends", "links1.partition")

#: The core's packages, bottom up, each with the core packages it may import: one way, so no
#: circle between packages (docs/architecture.md, "Packages"). ``links1.errors`` (the error
#: classes every layer raises) and ``links1.interrupts`` (Ctrl-C held and raised at safe points,
#: for the front ends and the plugin) are the modules outside them.
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
}


def _front_end(module: str) -> bool:
    """A front end of links1, or the package ``links1`` itself (the public API, which
    re-exports the front end ``make_renderer``)."""
    return module == "links1" or any(module == f or module.startswith(f + ".") for f in FRONT_ENDS)


def _core(module: str) -> bool:
    return module.split(".")[0] == "links1" and not _front_end(module)


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
    assert "links1.partition.runtime" in g["links1.partition.cli"]  # from .runtime import ...
    assert "links1.scene.loader" in g["links1.tracing.render"]    # inside CoreRenderer.__init__
    assert "links1_mitsuba" in g["links1.frontends.renderers"]     # the factory's lazy import
    assert "links1.tracing.aovs" in g["links1_mitsuba.renderer"]   # a plugin -> core edge
    assert "links1" not in g["links1.tracing.render"]              # no edge to a parent package
    assert "links1.scene.params" in g["links1.scene.scene"]        # from . import params (a submodule)


def test_no_import_circles():
    g = graph()
    circles = [c for c in strongly_connected(g) if len(c) > 1]
    assert not circles, "import circles (each: one loop, then the whole component):\n" + "\n".join(
        f"  {' -> '.join(_cycle(g, c))}   [{', '.join(c)}]" for c in circles)


def test_core_never_names_the_plugin_or_a_front_end():
    """The core (links1 less its front ends) never imports ``links1_mitsuba`` or a front end,
    lazily or not."""
    g = graph()
    core = [m for m in g if _core(m)]
    assert {"links1.tracing.render", "links1.errors", "links1.tracing.aovs", "links1.tracing.adaptive"} <= set(core)
    bad = sorted(f"{m} -> {d}" for m in core for d in g[m]
                 if d.split(".")[0] == "links1_mitsuba" or _front_end(d))
    assert not bad, f"core modules that import the plugin or a front end: {bad}"


def _layer(module: str) -> str | None:
    return next((k for k in LAYERS if module == k or module.startswith(k + ".")), None)


def test_core_packages_depend_one_way():
    """Every core module lies in one of ``LAYERS``, and imports (lazily or not) only its own
    package and the packages ``LAYERS`` lets its package import."""
    names = list(LAYERS)
    assert all(dep in names[:i] for i, k in enumerate(names) for dep in LAYERS[k])  # bottom up
    g = graph()
    core = [m for m in g if _core(m) and m != "links1"]
    assert not [m for m in core if _layer(m) is None], "core modules outside the LAYERS packages"
    bad = sorted(f"{m} -> {d}" for m in core for d in g[m] if _core(d) and d != "links1"
                 and _layer(d) != _layer(m) and _layer(d) not in LAYERS[_layer(m)])
    assert not bad, f"core modules importing a package above their own: {bad}"


def test_plugin_never_imports_the_front_ends():
    """The plugin builds on the core only: it never imports links1's front ends (nor the
    package ``links1``, whose ``__init__`` re-exports one)."""
    g = graph()
    bad = sorted(f"{m} -> {d}" for m in g if m.split(".")[0] == "links1_mitsuba" for d in g[m]
                 if _front_end(d))
    assert not bad, f"plugin modules that import a links1 front end: {bad}"


if __name__ == "__main__":  # python tests/docs/test_imports.py: print the circles
    G = graph()
    for comp in strongly_connected(G):
        if len(comp) > 1:
            print(" -> ".join(_cycle(G, comp)), f"  [{len(comp)} modules]")
    sys.exit(0)
