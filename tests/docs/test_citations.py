"""Every citation in the code resolves inside the repository.

Comments cite the method as ``docs/method.md §N`` (a section heading ``§N`` there) and other
documents as ``docs/NAME.md``; a citation of a document that is not in the repository (the
old "digest §N", ``shared/docs/...``) fails.
"""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SOURCES = [p for d in ("links1", "plugins", "tests", "compare") for p in (ROOT / d).rglob("*.py")
           if p != Path(__file__).resolve()]
SECTION = re.compile(r"docs/method\.md §(\d+(?:\.\d+)?)(?:[–-](\d+(?:\.\d+)?))?")
DOC = re.compile(r"\bdocs/([\w-]+\.md)")


def _headings():
    text = (ROOT / "docs" / "method.md").read_text(encoding="utf-8")
    return set(re.findall(r"^#+ §(\d+(?:\.\d+)?)\b", text, flags=re.M))


def test_method_sections_cited_exist():
    headings = _headings()
    assert {"1", "2", "3.1", "3.2", "3.3", "4.1", "4.3", "5"} <= headings
    cited = []
    for path in SOURCES:
        for m in SECTION.finditer(path.read_text(encoding="utf-8")):
            for sec in filter(None, m.groups()):
                cited.append((path.relative_to(ROOT), sec))
    assert cited, "no code cites docs/method.md"
    missing = [(str(p), s) for p, s in cited if s not in headings]
    assert not missing, f"citations of sections docs/method.md does not have: {missing}"


def test_cited_documents_are_in_the_repository():
    missing = []
    for path in SOURCES:
        text = path.read_text(encoding="utf-8")
        for name in set(DOC.findall(text)):
            if not (ROOT / "docs" / name).is_file():
                missing.append((str(path.relative_to(ROOT)), name))
        if "shared/docs/" in text or re.search(r"\bdigest §", text):
            missing.append((str(path.relative_to(ROOT)), "a document outside the repository"))
    assert not missing, f"citations that do not resolve in the repository: {missing}"


#: Where module paths are checked. plugins/links1_mitsuba/ is left out until its docstrings
#: name the sub-packages: add "plugins" here then.
#: compare/results/ is left out too: measured records (profiles name the files as they were).
MODULE_PATH_SOURCES = [p for d in ("links1", "plugins", "tests", "compare", "tools", "docs") for p in (ROOT / d).rglob("*")
                       if p.suffix in (".py", ".md") and p != Path(__file__).resolve()
                       and (ROOT / "compare" / "results") not in p.parents] + [ROOT / "README.md"]
DOTTED = re.compile(r"(?<![\w./-])links1((?:\.\w+)+)")
SLASHED = re.compile(r"(?<![\w./-])(links1/[\w/]+\.py)\b")


def _module_file(parts) -> bool:
    base = ROOT.joinpath("links1", *parts)
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def test_cited_module_paths_exist():
    """A module named in code or docs (``links1.geometry.shapes.Quadric``, ``links1/scene/loader.py``)
    exists: after a move, a stale path (``links1.shapes``) fails. A dotted name must start with a
    module or package of links1, or a public name of the package (``links1.render``)."""
    import links1
    public = set(links1.__all__) | {"__version__", "__file__", "__all__"}
    stale = []
    for path in MODULE_PATH_SOURCES:
        text = path.read_text(encoding="utf-8")
        for m in DOTTED.finditer(text):
            parts = m.group(1).split(".")[1:]
            if not (_module_file(parts[:1]) or parts[0] in public):
                stale.append((str(path.relative_to(ROOT)), m.group(0)))
                continue
            # below a sub-package (whose __init__ defines no lower-case names of its own), the
            # next part is one of its modules; past a module, names are not checked (an import)
            for i in range(1, len(parts)):
                if not (ROOT.joinpath("links1", *parts[:i]) / "__init__.py").is_file():
                    break
                if not _module_file(parts[:i + 1]) and parts[i][:1].islower() and i + 1 < len(parts):
                    stale.append((str(path.relative_to(ROOT)), m.group(0)))
                    break
        for m in SLASHED.finditer(text):
            if not (ROOT / m.group(1)).is_file():
                stale.append((str(path.relative_to(ROOT)), m.group(1)))
    assert not stale, f"module paths that do not exist: {sorted(set(stale))}"
