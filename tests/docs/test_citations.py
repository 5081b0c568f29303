"""Every citation in the code resolves inside the repository (issue 24, item 5).

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
