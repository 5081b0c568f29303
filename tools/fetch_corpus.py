"""Copy the corpus scenes that cannot be committed into ``tests/corpus/external/``.

    python tools/fetch_corpus.py                       # clones each repository from GitHub
    python tools/fetch_corpus.py --git-dir mitsuba-renderer/mitsuba-data=/path/to/clone/.git

Each scene of ``tests/corpus/manifest.py`` is read at its pinned commit with ``git show``,
together with the files it needs: ``<include>``d fragments and every ``filename`` it names,
looked up as Mitsuba does (the ``<path>`` directories, the main scene file's directory, then
the naming file's own).
Files keep their place in the repository, so the scenes' relative paths work unchanged.
Committed scenes (a licence that allows it) are refreshed too.
"""
from __future__ import annotations

import argparse
import os
import posixpath
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from tests.corpus.manifest import EXTERNAL, HERE, SCENES  # noqa: E402

_FILENAME = re.compile(r'name\s*=\s*"filename"\s+value\s*=\s*"([^"$]+)"'
                       r'|value\s*=\s*"([^"$]+)"\s+name\s*=\s*"filename"')
_INCLUDE = re.compile(r'<include\s+filename\s*=\s*"([^"$]+)"')
_PATH = re.compile(r'<path\s+value\s*=\s*"([^"$]+)"')


class Repo:
    def __init__(self, name: str, git_dir: str | None, tmp: str):
        self.name = name
        if git_dir is None:
            git_dir = os.path.join(tmp, name.replace("/", "+"))
            subprocess.run(["git", "clone", "--quiet", "--bare", "--filter=blob:none",
                            f"https://github.com/{name}.git", git_dir], check=True)
        self.git_dir = git_dir

    def read(self, commit: str, path: str) -> bytes | None:
        res = subprocess.run(["git", "--git-dir", self.git_dir, "show", f"{commit}:{path}"],
                             capture_output=True)
        return res.stdout if res.returncode == 0 else None


def collect(repo: Repo, commit: str, scene: str) -> dict:
    """Repository path -> bytes of the scene and everything it needs."""
    files, todo, search = {}, [scene], []
    root = posixpath.dirname(scene)  # Mitsuba resolves fragments' files from the main file's dir
    while todo:
        path = todo.pop()
        if path in files:
            continue
        data = repo.read(commit, path)
        if data is None:
            raise SystemExit(f"{repo.name}@{commit[:10]}: {path} not found")
        files[path] = data
        if not path.endswith(".xml"):
            continue
        text = data.decode("utf-8", "replace")
        here = posixpath.dirname(path)
        search = [posixpath.normpath(posixpath.join(here, p)) for p in _PATH.findall(text)] + search
        for inc in _INCLUDE.findall(text):
            todo.append(posixpath.normpath(posixpath.join(here, inc)))
        for a, b in _FILENAME.findall(text):
            name = a or b
            for d in search + [root, here]:
                cand = posixpath.normpath(posixpath.join(d, name))
                if repo.read(commit, cand) is not None:
                    todo.append(cand)
                    break
            else:
                print(f"warning: {path}: '{name}' not found in the repository", file=sys.stderr)
    return files


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--git-dir", action="append", default=[], metavar="OWNER/NAME=PATH",
                   help="read that repository from a local git directory instead of cloning it")
    args = p.parse_args(argv)
    local = dict(item.split("=", 1) for item in args.git_dir)
    with tempfile.TemporaryDirectory() as tmp:
        repos: dict = {}
        for sc in SCENES:
            repo = repos.get(sc.repo) or repos.setdefault(sc.repo, Repo(sc.repo, local.get(sc.repo), tmp))
            root = os.path.join(HERE if sc.committed else EXTERNAL, sc.repo.replace("/", "+"))
            files = collect(repo, sc.commit, sc.path)
            for path, data in files.items():
                out = os.path.join(root, *path.split("/"))
                os.makedirs(os.path.dirname(out), exist_ok=True)
                with open(out, "wb") as f:
                    f.write(data)
            print(f"{sc.id}: {len(files)} files, {sum(map(len, files.values())) / 1e3:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
