"""The wheel as a user gets it: built, installed into a fresh venv, run elsewhere.

``make setup`` installs the checkout in editable mode, which imports every module straight from
the source tree and so hides a wheel that leaves modules out (the partitioning package once
was: ``links1 render --workers 2`` then said "unrecognized arguments", ``links1 schedule``
"invalid choice"). Here:

* the wheel is built from a copy of the packaged sources (``pip wheel --no-deps``, with build
  isolation: setuptools comes from the index as ``build-system.requires`` asks, and nothing
  left in the checkout's ``build/`` can slip into it), and must hold exactly the files of
  ``links1/``, ``links1_app/`` and ``plugins/links1_mitsuba/``, ``.py`` files and data alike;
* it is installed into a fresh virtual environment with its dependencies resolved from the
  package index (``links1[mitsuba,dask]`` plus pytest, for the pytest plugin): no
  ``--system-site-packages``, nothing from the project's ``.venv``, so an undeclared
  dependency fails here as it would for a user;
* from a temporary directory outside the checkout, with ``PYTHONPATH`` cleared, it renders
  (core, Mitsuba, ``--workers 2``, ``--dask-local 2``), runs ``schedule``, ``diff`` and the
  pytest plugin; images must equal the checkout's own renders bit for bit.

Needs the package index (pip's configured one) for setuptools and the dependencies; with a
warm pip cache the module takes about 30 s.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from links1.imaging.image import read_exr, write_exr

PIP_TIMEOUT = 600  # a cold cache downloads Mitsuba, Dr.Jit, numpy, Dask... from the index
# the first test that needs the venv also waits for its installation
pytestmark = [pytest.mark.slow, pytest.mark.wheel, pytest.mark.timeout(PIP_TIMEOUT + 300)]

ROOT = Path(__file__).resolve().parent.parent
# top-level package in the wheel -> its source directory (pyproject.toml's packages.find)
PACKAGES = {"links1": "links1", "links1_app": "links1_app", "links1_mitsuba": "plugins/links1_mitsuba"}
BUILD_FILES = ("pyproject.toml", "README.md")
RES = ("--width", "32", "--height", "24")


def _source_files() -> list[str]:
    """The files a fresh clone would package (tracked or new and not ignored), relative to ROOT."""
    dirs = list(PACKAGES.values())
    try:
        out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard",
                              "--", *dirs, *BUILD_FILES], cwd=ROOT, capture_output=True, check=True)
        files = [f for f in out.stdout.decode().split("\0") if f]
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: walk the tree
        files = [str(p.relative_to(ROOT)) for d in dirs for p in (ROOT / d).rglob("*") if p.is_file()]
        files += list(BUILD_FILES)
    return sorted(f for f in files if (ROOT / f).is_file()
                  and "__pycache__" not in Path(f).parts and not f.endswith((".pyc", ".pyo")))


def _run(cmd, *, cwd, env=None, timeout=300, check=True):
    res = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                         timeout=timeout)
    if check and res.returncode != 0:
        pytest.fail(f"{' '.join(map(str, cmd))} -> exit {res.returncode}\n"
                    f"stdout:\n{res.stdout[-4000:]}\nstderr:\n{res.stderr[-4000:]}")
    return res


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    d = tmp_path_factory.mktemp("wheel")
    yield d
    shutil.rmtree(d, ignore_errors=True)  # the venv alone is ~400 MB; pytest keeps 3 runs' tmp


@pytest.fixture(scope="module")
def sources():
    return _source_files()


@pytest.fixture(scope="module")
def wheel(tmp, sources) -> Path:
    src = tmp / "src"
    for f in sources:
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, src / f)
    dist = tmp / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", dist, src], cwd=tmp,
         timeout=PIP_TIMEOUT)
    wheels = list(dist.glob("links1-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def test_wheel_holds_every_module_and_data_file(wheel, sources):
    expected = set()
    for top, d in PACKAGES.items():
        expected |= {top + f[len(d):] for f in sources if f.startswith(d + "/")}
    assert {"links1/partition/strategies.py", "links1_app/partition/cli.py", "links1_app/cli.py",
            "links1/data/cie1931_d65.csv"} <= expected
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        info = next(n.split("/")[0] for n in names if n.endswith(".dist-info/METADATA"))
        entry_points = z.read(f"{info}/entry_points.txt").decode()
    packaged = {n for n in names if not n.startswith(info + "/")}
    assert sorted(expected - packaged) == [], "left out of the wheel (pyproject.toml: packages.find / package-data)"
    assert sorted(packaged - expected) == [], "in the wheel but not in the source tree"
    lines = [ln.replace(" ", "") for ln in entry_points.splitlines()]
    assert lines[lines.index("[console_scripts]") + 1:].count("links1=links1_app.cli:main") == 1
    assert "links1=links1_app.pytest_plugin" in lines[lines.index("[pytest11]"):]


# ------------------------------------------------------------------ installed in a fresh venv

@pytest.fixture(scope="module")
def venv(tmp, wheel):
    """A fresh venv with the wheel and its dependencies from the index; returns (bin dir, env)."""
    vdir = tmp / "venv"
    _run([sys.executable, "-m", "venv", vdir], cwd=tmp, timeout=120)
    bindir = vdir / ("Scripts" if os.name == "nt" else "bin")
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP", "VIRTUAL_ENV", "PYTHONSAFEPATH")}
    env.update(PYTHONNOUSERSITE="1", VIRTUAL_ENV=str(vdir),
               PATH=str(bindir) + os.pathsep + env.get("PATH", ""))
    _run([bindir / "python", "-m", "pip", "install", "-q", f"{wheel}[mitsuba,dask]", "pytest"],
         cwd=tmp, env=env, timeout=PIP_TIMEOUT)
    return bindir, env


@pytest.fixture(scope="module")
def work(tmp):
    """A directory outside the checkout, holding a copy of the scenes."""
    w = tmp / "work"
    shutil.copytree(ROOT / "scenes", w / "scenes")
    assert ROOT not in w.resolve().parents
    return w


def _links1(venv, work, *args, check=True):
    bindir, env = venv
    return _run([bindir / "links1", *args], cwd=work, env=env, check=check)


def _checkout_render(path, *args):
    """The same render by the checkout's code (the suite's own interpreter)."""
    _run([sys.executable, "-c", "import sys; from links1_app.cli import main; sys.exit(main())",
          "render", *args, "--no-progress", "-o", path], cwd=ROOT)
    return read_exr(path)[0]


def test_every_module_imports_from_the_venv(venv, work):
    bindir, env = venv
    script = r"""
import importlib, json, pkgutil, sys
import links1, links1_app, links1_mitsuba
failed, names = {}, []
for pkg in (links1, links1_app, links1_mitsuba):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        names.append(m.name)
        try:
            importlib.import_module(m.name)
        except Exception as e:
            failed[m.name] = repr(e)
print(json.dumps({"links1": links1.__file__, "links1_app": links1_app.__file__, "links1_mitsuba": links1_mitsuba.__file__,
                  "names": names, "failed": failed}))
"""
    out = json.loads(_run([bindir / "python", "-c", script], cwd=work, env=env).stdout)
    purelib = Path(_run([bindir / "python", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                        cwd=work, env=env).stdout.strip()).resolve()
    for pkg in ("links1", "links1_app", "links1_mitsuba"):
        f = Path(out[pkg]).resolve()
        assert purelib in f.parents, f"{pkg} imported from {f}, not from the venv's {purelib}"
        assert ROOT not in f.parents
    assert "links1_app.partition.cli" in out["names"] and "links1_mitsuba.integrator" in out["names"]
    assert out["failed"] == {}


@pytest.mark.mitsuba
@pytest.mark.dask
def test_render_core_mitsuba_workers_and_dask_equal_the_checkout(venv, work, tmp):
    scene = work / "scenes" / "fig11.xml"
    runs = {"core": ("--renderer", "core"), "workers": ("--renderer", "core", "--workers", "2"),
            "dask": ("--renderer", "core", "--dask-local", "2"), "mitsuba": ("--renderer", "mitsuba")}
    images = {}
    for name, args in runs.items():
        out = work / f"{name}.exr"
        res = _links1(venv, work, "render", scene, *args, *RES, "--no-progress", "-o", out.name)
        assert res.stderr.startswith(f"links1: wrote {out.name} (32x24, {args[1]})")
        images[name] = read_exr(out)[0]
        assert images[name].shape == (24, 32, 3)
    ref_core = _checkout_render(tmp / "ref-core.exr", ROOT / "scenes" / "fig11.xml", "--renderer", "core", *RES)
    ref_mi = _checkout_render(tmp / "ref-mi.exr", ROOT / "scenes" / "fig11.xml", "--renderer", "mitsuba", *RES)
    assert np.ptp(ref_core) > 0  # a lit scene, not a black frame
    for name in ("core", "workers", "dask"):
        assert np.array_equal(images[name], ref_core), name
    assert np.array_equal(images["mitsuba"], ref_mi)


def test_schedule_reports_every_pixel_and_plot_needs_its_extra(venv, work):
    scene = work / "scenes" / "fig11.xml"
    report = work / "r.json"
    _links1(venv, work, "schedule", scene, "--renderer", "core", *RES, "--nodes", "2",
            "--report", report, "--no-progress")
    r = json.loads(report.read_text())
    assert r["nodes"] == 2
    assert sum(u["pixels"] for u in r["units"]) == 32 * 24
    # matplotlib is the [plot] extra, not installed here: one line, exit 2, nothing written
    report2 = work / "r2.json"
    res = _links1(venv, work, "schedule", scene, "--renderer", "core", *RES, "--nodes", "2",
                  "--report", report2, "--plot", work / "r2.png", "--no-progress", check=False)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "links1: error: --plot needs matplotlib, which is not installed; pip install 'links1[plot]'"]
    assert not report2.exists() and not (work / "r2.png").exists()


def test_diff(venv, work):
    a = np.linspace(0.0, 1.0, 8 * 6 * 3, dtype=np.float32).reshape(6, 8, 3)
    b = a.copy()
    b[2, 3] += np.float32(0.25)
    write_exr(work / "a.exr", a)
    write_exr(work / "b.exr", b)
    same = _links1(venv, work, "diff", "a.exr", "a.exr", "--metric", "max", "--threshold", "0", "--json")
    assert json.loads(same.stdout)["value"] == 0.0
    res = _links1(venv, work, "diff", "b.exr", "a.exr", "--metric", "max", "--threshold", "0.1",
                  "--json", check=False)
    assert res.returncode == 1, res.stderr
    out = json.loads(res.stdout)
    assert out["passed"] is False
    assert out["value"] == pytest.approx(float(np.max(np.abs(b - a))), rel=1e-6)


PLUGIN_TEST = '''
import sys
from pathlib import Path
import numpy as np
import links1_app.pytest_plugin

def test_plugin_is_the_installed_one():
    assert Path(sys.prefix).resolve() in Path(links1_app.pytest_plugin.__file__).resolve().parents

def test_image(links1_baseline):
    y, x = np.mgrid[0:6, 0:8]
    links1_baseline.check("ramp", SCALE * np.stack([x / 8, y / 6, (x + y) / 14], axis=-1))
'''


def test_pytest_plugin_loads_by_its_entry_point(venv, work):
    bindir, env = venv
    d = work / "plugin"
    d.mkdir()
    test = d / "test_images.py"
    pytest_cmd = [bindir / "python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", d, test]
    test.write_text(PLUGIN_TEST.replace("SCALE", "1.0"))
    # no "-p links1_app.pytest_plugin": the fixture must come from the wheel's pytest11 entry point
    _run([*pytest_cmd, "--links1-update-baselines"], cwd=d, env=env)
    assert (d / "baselines" / "ramp.exr").is_file()
    _run(pytest_cmd, cwd=d, env=env)
    test.write_text(PLUGIN_TEST.replace("SCALE", "1.5"))
    res = _run(pytest_cmd, cwd=d, env=env, check=False)
    assert res.returncode == 1
    assert "1 failed, 1 passed" in res.stdout
