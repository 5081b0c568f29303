"""Shared fixtures for the partitioning tests (a fake renderer spec, a small real scene)."""
from __future__ import annotations

import os

import pytest

from links1_app.partition.runtime import RendererSpec

from .fake_renderer import FAKE, FakeRenderer, pixel_values

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MANY = os.path.join(ROOT, "scenes", "many.xml")


@pytest.fixture
def fake_spec():
    return RendererSpec.make(FAKE, "fake")


@pytest.fixture
def fake_ref():
    r = FakeRenderer()
    return pixel_values(0, 0, r.width, r.height, r.nc)


@pytest.fixture(scope="session")
def core_spec():
    """The real core renderer on the many-objects paper scene, small enough for tests."""
    return RendererSpec.make("core", MANY, params={"res": "32"}, aovs=("id", "cost"))


@pytest.fixture(scope="session")
def core_ref(core_spec):
    from links1_app.renderers import make_renderer
    return make_renderer("core", MANY, params={"res": "32"}, aovs=("id", "cost")).render()
