"""The GPU-capable plugin suite: the user's guide's command (docs/guide.md)
``python -m pytest tests/plugins -k cuda_ad_rgb`` selects exactly the cases marked ``gpu``
(the cuda_ad_rgb parameters of ``variant``, ``renderer_kind``, ``kind_with_mitsuba`` and the
tests that list the variants themselves), and a plugin test that runs on llvm_ad_rgb only
says why in its docstring."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGINS = ROOT / "tests" / "plugins"
COMMAND = "python -m pytest tests/plugins -k cuda_ad_rgb"
#: llvm_ad_rgb cases without a cuda_ad_rgb twin, each an LLVM-only path its test's docstring names
LLVM_ONLY_CASES = {
    # the shadow sub-scenes (shadow_plan.shadow_split); the crossing walk runs on both variants
    "tests/plugins/test_shadow_split.py::"
    "test_split_transmittance_is_the_product_over_the_shapes_met[llvm_ad_rgb-split]",
}


def collected(*args) -> set[str]:
    res = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                          "tests/plugins", *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode in (0, 5), res.stdout[-2000:] + res.stderr[-2000:]
    return {ln.strip() for ln in res.stdout.splitlines() if "::" in ln}


@pytest.mark.slow
def test_readme_command_selects_exactly_the_gpu_cases():
    assert COMMAND in (ROOT / "docs" / "guide.md").read_text()
    by_k, by_marker, every = collected("-k", "cuda_ad_rgb"), collected("-m", "gpu"), collected()
    assert by_k == by_marker
    assert by_k == {t for t in every if "cuda_ad_rgb" in t.split("::", 1)[1]}
    # each test that runs on llvm_ad_rgb through a variant fixture has its CUDA case
    llvm = {t for t in every if "llvm_ad_rgb" in t.split("::", 1)[1]}
    assert LLVM_ONLY_CASES <= llvm
    assert {t.replace("llvm_ad_rgb", "cuda_ad_rgb") for t in llvm - LLVM_ONLY_CASES} <= by_k
    assert len(by_k) > 200


def test_llvm_only_tests_say_why():
    """A test taking the ``llvm`` fixture names the LLVM-only path (or why it runs once) in its
    docstring, after the words "LLVM only"."""
    silent = []
    for path in sorted(PLUGINS.glob("test_*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_") \
                    and "llvm" in {a.arg for a in node.args.args}:
                if "LLVM only:" not in (ast.get_docstring(node) or ""):
                    silent.append(f"{path.name}::{node.name}")
    assert not silent, f"tests on llvm_ad_rgb alone that do not say why: {silent}"
