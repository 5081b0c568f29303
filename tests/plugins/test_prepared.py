"""The per-scene tables of links1_whitted (``prepared.Prepared``) have a declared shape: every field named and typed in one dataclass, an undeclared name refused, and every
field a prepared scene's camera view needs actually set."""
from __future__ import annotations

import dataclasses
import os

import pytest

from .conftest import SCENES

pytestmark = pytest.mark.mitsuba


def test_prepared_refuses_an_undeclared_attribute():
    from links1_mitsuba.prepared import Prepared
    P = Prepared()
    P.nslots = 3                      # a declared field
    assert P.nslots == 3
    with pytest.raises(AttributeError):
        P.n_slots = 3                 # a typo of it: refused, not a new attribute
    with pytest.raises(AttributeError):
        P.nslots_extra                # noqa: B018 - reading an undeclared name
    assert not hasattr(P, "__dict__")
    # a field without a default is unset until the tables set it; defaults where code reads it
    with pytest.raises(AttributeError):
        P.lights                      # noqa: B018
    assert P.geo_ad is None and P.base is None and P.shadow_split is None


@pytest.mark.slow
@pytest.mark.parametrize("name", ["fig11", "mitsuba_glass", "lights"])
def test_a_prepared_view_sets_every_field(variant, name):
    from links1_mitsuba import MitsubaRenderer
    from links1_mitsuba.prepared import CameraView, Prepared
    path = os.path.join(SCENES, f"{name}.xml")
    r = MitsubaRenderer(path, width=8, height=6, spp=1)
    r.render()
    V = r.integrator.info()["tables"]
    assert isinstance(V, CameraView) and isinstance(V.base, Prepared)
    unset = [f.name for f in dataclasses.fields(Prepared) if not hasattr(V, f.name)]
    assert unset == []
    # the view holds only its own fields and reads the others through the scene's tables
    assert V.lights is V.base.lights and V.dif is V.base.dif and not hasattr(V, "__dict__")
    assert V.tables().lights is V.base.lights and V.tables().cam is V.cam
    # the scene's own tables (no camera): the camera fields are the only ones unset
    camera = {"sensor", "film_size", "rfilter", "projection", "cam", "near", "far"}
    assert {f.name for f in dataclasses.fields(Prepared) if not hasattr(V.base, f.name)} == camera
