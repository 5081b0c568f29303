"""What both renderers ignore is ignored alike, with one warning naming its place (docs/guide.md's
support table: ``sunsky`` / ``directionalarea`` emitters, media).

The reference is the same scene without the element: adding an ignored element must leave the
image bit for bit as it was, and say so in one ``FILE:LINE: <element>`` warning.
"""
import warnings

import numpy as np
import pytest

from links1_app.renderers import make_renderer

pytestmark = pytest.mark.mitsuba

BASE = """<scene version="3.0.0">
<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 1, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
  <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
  <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="16"/>
    <rfilter type="box"/></film></sensor>
<emitter type="directional"><vector name="direction" x="-0.3" y="-1" z="-0.4"/><rgb name="irradiance" value="2"/></emitter>
<shape type="sphere"><bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.4, 0.2"/></bsdf>{interior}</shape>
<shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
  <translate y="-1"/></transform></shape>
{extra}
</scene>
"""

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
