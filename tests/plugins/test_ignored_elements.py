"""What both renderers ignore is ignored alike, with one warning naming its place (docs/guide.md's
support table: ``sunsky`` / ``directionalarea`` emitters, media).

The reference is the same scene without the element: adding an ignored element must leave the
image bit for bit as it was, and say so in one ``FILE:LINE: <element>`` warning.
"""
import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer

from tests.scenes import perspective, scene

pytestmark = pytest.mark.mitsuba

BASE = scene(perspective("0, 1, 5", "0, 0, 0", fov=40, width=24, height=16), """
<emitter type="directional"><vector name="direction" x="-0.3" y="-1" z="-0.4"/><rgb name="irradiance" value="2"/></emitter>
<shape type="sphere"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.4, 0.2"/></bsdf>{interior}</shape>
<shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
  <translate y="-1"/></transform></shape>
{extra}""")

MEDIUM = ('<medium type="homogeneous" name="interior"><rgb name="albedo" value="0.5"/>'
          '<float name="sigma_t" value="1"/></medium>')
PANEL = ('<shape type="rectangle"><transform name="to_world"><translate z="-3"/></transform>'
         '<bsdf type="diffuse"><rgb name="reflectance" value="0.3"/></bsdf>{}</shape>')
#: the edited scene's additions, and the reference's (the same geometry without the ignored part)
CASES = {
    "directionalarea": dict(extra=PANEL.format('<emitter type="directionalarea"><rgb name="radiance" value="1"/>'
                                               '</emitter>'), ref_extra=PANEL.format(""), tag="directionalarea"),
    "medium": dict(interior=MEDIUM, tag="medium"),
}


def _render(kind, path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        img = np.asarray(make_renderer(kind, str(path), spp=1).render(), dtype=np.float64)
    return img, [str(w.message) for w in caught]


@pytest.mark.parametrize("case", sorted(CASES))
def test_ignored_element_leaves_the_image_and_warns_once(tmp_path, renderer_kind, case):
    kind = renderer_kind
    spec = CASES[case]
    ref = tmp_path / "ref.xml"
    ref.write_text(BASE.format(interior="", extra=spec.get("ref_extra", "")))
    edited = tmp_path / "edited.xml"
    edited.write_text(BASE.format(interior=spec.get("interior", ""), extra=spec.get("extra", "")))
    want, _ = _render(kind, ref)
    got, messages = _render(kind, edited)
    assert want.max() > 0.05, "the reference scene should be lit"
    np.testing.assert_array_equal(got[..., :3], want[..., :3])
    mine = [m for m in messages if spec["tag"] in m and "edited.xml:" in m]
    assert len(mine) == 1, f"expected one warning naming edited.xml and {spec['tag']}, got {messages}"
