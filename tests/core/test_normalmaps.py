"""Normal and bump maps in the core (:mod:`links1.shading.normalmaps`) without Mitsuba: the
shapes' ``dp_du``/``dp_dv`` against finite differences of their ``uv``, a bitmap's gradient
against finite differences of its lookup, flat maps that leave the nested BSDF as it is, and
the loader's one-line refusals. Mitsuba's own values: tests/plugins/test_normalmaps_vs_mitsuba.py."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from links1.geometry import meshes
from links1.geometry.shapes import Disk, Quadric, TriangleMesh
from links1.maths import transform as tf
from links1.scene.loader import load_string
from links1.errors import SceneError
from links1.shading.materials import Diffuse
from links1.shading.normalmaps import BumpMap, NormalMap, needs_frame
from links1.shading.textures import Bitmap, Checkerboard

RNG = np.random.default_rng(11)


def _shapes():
    m = tf.translate([0.2, -0.1, 0.3]) @ tf.rotate([1, 1, 0], 35.0) @ tf.scale([1.3, 0.8, 1.1])
    v, f, n, uv = meshes.rectangle_mesh(uv=True)
    vw = v @ m[:3, :3].T + m[:3, 3]
    sphere = tf.translate([0.1, 0.2, -0.3]) @ tf.rotate([0, 1, 1], 20.0) @ tf.scale(1.2)
    return {"sphere": Quadric("sphere", sphere),
            "cylinder": Quadric("cylinder", m, clips=[(np.array([0, 0, -1.0]), 0.0), (np.array([0, 0, 1.0]), 1.0)]),
            "disk": Disk(m),
            "rectangle (texcoords)": TriangleMesh(vw, f, texcoords=np.array([[0.1, 0.2], [0.9, 0.1], [0.8, 0.7], [0.2, 0.9]])),
            "rectangle (barycentric)": TriangleMesh(vw, f)}


@pytest.mark.parametrize("name", list(_shapes()))
def test_tangents_are_the_derivatives_of_uv(name):
    """Moving a hit by ``h dp_du`` (``h dp_dv``) along the surface changes its ``uv`` by ``(h, 0)``
    (``(0, h)``) to first order: central differences of ``uv`` agree within 1e-5."""
    shape = _shapes()[name]
    lo, hi = shape.bounds()
    c = 0.5 * (lo + hi)
    n = 400
    o = c + RNG.normal(size=(n, 3)) * 0.1 + np.array([0.3, 4.0, 2.5])
    d = c + RNG.uniform(-0.4, 0.4, (n, 3)) * (hi - lo) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, prim = shape.intersect(o, d, np.zeros(n), np.full(n, np.inf))
    ok = np.isfinite(t)
    o, d, t, prim = o[ok], d[ok], t[ok], prim[ok]
    assert ok.sum() > 50
    uv = shape.uv(o, d, t, prim)
    keep = (np.abs(uv[:, 0] - 0.5) < 0.45) & (uv[:, 1] > 0.05) & (uv[:, 1] < 0.95) \
        if name in ("sphere", "cylinder", "disk") else np.ones(len(t), dtype=bool)
    if name == "disk":
        keep &= uv[:, 0] > 0.1
    o, d, t, prim, uv = o[keep], d[keep], t[keep], prim[keep], uv[keep]
    assert keep.sum() > 20
    p, ng, _ = shape.surface(o, d, t, prim)
    h = 1e-5
    for k, tangent in enumerate(shape.tangents(o, d, t, prim)):
        step = []
        for sgn in (1.0, -1.0):
            q = p + sgn * h * tangent
            t2, prim2 = shape.intersect(q + 1e-3 * ng, -ng, np.zeros(len(q)), np.full(len(q), np.inf))
            step.append(shape.uv(q + 1e-3 * ng, -ng, t2, prim2))
        duv = (step[0] - step[1]) / (2 * h)
        expect = np.zeros_like(duv)
        expect[:, k] = 1.0
        assert np.max(np.abs(duv - expect)) < 1e-5, (name, k, np.max(np.abs(duv - expect)))


def test_bitmap_gradient_is_the_derivative_of_its_lookup():
    """``eval_1_grad`` of a bilinear bitmap (with a ``to_uv`` scale) equals central differences
    of ``eval_1`` inside the texels (Mitsuba's gradient is of the same bilinear patch); a
    ``nearest`` lookup has none."""
    data = RNG.random((5, 7, 3))
    tex = Bitmap(data, to_uv=np.diag([2.0, 3.0, 1.0]))
    uv = RNG.random((300, 2))
    s, t = uv[:, 0] * 2 * 7 - 0.5, uv[:, 1] * 3 * 5 - 0.5
    inside = (np.abs(s - np.round(s)) > 0.01) & (np.abs(t - np.round(t)) > 0.01)
    uv = uv[inside]
    h = 1e-7
    fd = np.stack([(tex.eval_1(uv + [h, 0]) - tex.eval_1(uv - [h, 0])) / (2 * h),
                   (tex.eval_1(uv + [0, h]) - tex.eval_1(uv - [0, h])) / (2 * h)], axis=1)
    assert np.allclose(tex.eval_1_grad(uv), fd, rtol=1e-6, atol=1e-6)
    assert not np.any(Bitmap(data, filter_type="nearest").eval_1_grad(uv))


def _frame_given(n):
    """A flat hit frame: dp_du along x, dp_dv along y, normal +z."""
    return {"dp_du": np.tile([2.0, 0, 0], (n, 1)), "dp_dv": np.tile([0, 3.0, 0], (n, 1)),
            "ng": np.tile([0, 0, 1.0], (n, 1))}


@pytest.mark.parametrize("wrapper", ["flat normal map", "constant height"])
def test_flat_maps_leave_the_nested_bsdf_as_it_is(wrapper):
    """A normal map of (0.5, 0.5, 1) (the unturned normal) or a bump map of constant height
    turns nothing: eval, pdf and samples are the nested diffuse's (the shadowing term is 1)."""
    n = 500
    inner = Diffuse(reflectance=[0.6, 0.4, 0.2])
    if wrapper == "flat normal map":
        m = NormalMap(nested=inner, normalmap=Bitmap(np.full((2, 2, 3), [0.5, 0.5, 1.0])))
    else:
        m = BumpMap(nested=inner, texture=Bitmap(np.full((4, 4, 1), 0.3)), scale=5.0)
    uv = RNG.random((n, 2))
    b = m.at(uv, _frame_given(n))
    v = RNG.normal(size=(2, n, 3))
    wo, wi = v / np.linalg.norm(v, axis=2)[..., None]
    wo[:, 2] = np.abs(wo[:, 2])
    z = np.tile([0, 0, 1.0], (n, 1))
    assert np.allclose(b.eval(wo, wi, z, z), inner.eval(wo, wi, z, z), rtol=1e-12, atol=1e-15)
    assert np.allclose(b.pdf(wo, wi, z, z), inner.pdf(wo, wi, z, z), rtol=1e-12, atol=1e-15)
    s1, s2 = b.sample(wo, z, z, RNG.random(n), uv), inner.sample(wo, z, z, RNG.random(n), uv,
                                                                tangent=np.tile([1.0, 0, 0], (n, 1)))
    for a, c in zip(s1, s2):
        assert np.allclose(a, c, rtol=1e-12, atol=1e-15)


def test_a_tilted_normal_map_tilts_the_lobe():
    """A normal map tilted toward +x: a diffuse surface lit from +x is brighter than from -x,
    by the ratio of the cosines to the turned normal (times the shadowing term)."""
    tilt = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    m = NormalMap(nested=Diffuse(reflectance=1.0), normalmap=Bitmap(np.full((2, 2, 3), 0.5 * tilt + 0.5)),
                  use_shadowing_function=False).at(np.full((2, 2), 0.5), _frame_given(2))
    wi = np.array([[np.sin(0.5), 0, np.cos(0.5)], [-np.sin(0.5), 0, np.cos(0.5)]])
    z = np.tile([0, 0, 1.0], (2, 1))
    f = m.eval(z, wi, z, z)[:, 0]
    nt = (0.5 * tilt + 0.5) * 2 - 1
    nt /= np.linalg.norm(nt)
    assert np.allclose(f, wi @ nt / np.pi, rtol=1e-12)


def test_frame_is_needed_through_nesting():
    inner = NormalMap(nested=Diffuse(), normalmap=np.array([0.5, 0.5, 1.0]))
    from links1.shading.materials import Mask
    assert needs_frame(Mask(nested=inner)) and not needs_frame(Mask(nested=Diffuse()))
    with pytest.raises(ValueError, match="dp_du"):
        inner.at(np.zeros((1, 2)))


def _scene(bsdf):
    return f'<scene version="3.0.0">\n<shape type="sphere">\n{bsdf}\n</shape>\n</scene>'


def test_bumpmap_of_a_checkerboard_is_refused_in_one_line():
    """Mitsuba has the gradient of a bitmap only: a checkerboard height is refused at load time,
    naming the texture's line."""
    xml = _scene('<bsdf type="bumpmap">\n<texture type="checkerboard"/>\n<bsdf type="diffuse"/></bsdf>')
    with pytest.raises(SceneError) as exc:
        load_string(xml)
    msg = str(exc.value)
    assert ":4:" in msg and "checkerboard" in msg and "\n" not in msg


def _tilted_mirror(tilt_deg, target, shadowing=True):
    """Radiance seen straight down (from y = 5) on a mirror rectangle in the xz plane under a
    constant normal map that tilts its normal by ``tilt_deg`` toward the rectangle's dp_du (world
    +x), with a small emitting sphere (radiance 2) at ``target``; the core at max_depth 2."""
    from links1.tracing.integrator import WhittedIntegrator
    a = np.radians(tilt_deg)
    c = [float(x) for x in 0.5 * np.array([np.sin(a), 0.0, np.cos(a)]) + 0.5]
    xml = (f'<scene version="3.0.0"><shape type="rectangle"><transform name="to_world"><rotate x="1" '
           f'angle="-90"/></transform><bsdf type="normalmap"><rgb name="normalmap" value="{c[0]!r}, '
           f'{c[1]!r}, {c[2]!r}"/><boolean name="use_shadowing_function" value="{str(shadowing).lower()}"/>'
           f'<bsdf type="conductor"/></bsdf></shape><shape type="sphere"><point name="center" '
           f'value="{", ".join(map(repr, map(float, target)))}"/><float name="radius" value="0.05"/>'
           f'<emitter type="area"><rgb name="radiance" value="2"/></emitter></shape></scene>')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sc = load_string(xml)
    assert not [w for w in caught if "normal" in str(w.message)]   # nothing approximated
    it = WhittedIntegrator(sc, max_depth=2)
    L, _, _ = it.trace(np.array([[0.0, 5.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]), np.zeros(1),
                       np.full(1, np.inf), np.zeros(1, dtype=np.int64))
    return L[0]


@pytest.mark.parametrize("tilt", [10.0, 20.0, 35.0])
def test_mirror_under_a_normal_map_reflects_about_the_turned_normal(tilt):
    """A normal tilted by θ toward +x reflects a ray coming straight down into
    ``(sin 2θ, cos 2θ, 0)``: an emitter on that line is seen with the mirror's weight 1 times
    Mitsuba's shadowing term ``2 / (1 + sqrt(1 + α² tan² 2θ))``, ``α² = min(tan² θ / 8, 1)`` (exactly 1
    without it); one 4 degrees off that line (1 degree wide) is not seen. (About the unturned normal
    the ray would go straight back up and see neither.)"""
    a = np.radians(tilt)
    on_line = 3.0 * np.array([np.sin(2 * a), np.cos(2 * a), 0.0])
    alpha2 = min(np.tan(a) ** 2 / 8.0, 1.0)
    g = 2.0 / (1.0 + np.sqrt(1.0 + alpha2 * np.tan(2 * a) ** 2))
    assert g < 1.0
    assert np.allclose(_tilted_mirror(tilt, on_line), 2.0 * g, rtol=1e-12, atol=0)
    assert np.allclose(_tilted_mirror(tilt, on_line, shadowing=False), 2.0, rtol=1e-12, atol=0)
    off = a + np.radians(2.0)
    assert np.all(_tilted_mirror(tilt, 3.0 * np.array([np.sin(2 * off), np.cos(2 * off), 0.0])) == 0.0)


def test_a_reflection_turned_below_the_surface_is_dropped():
    """Tilted by 50 degrees the reflection ``(sin 100°, cos 100°, 0)`` leaves below the mirror's plane:
    Mitsuba's normalmap gives that sample no weight (no folding back), so an emitter on that line
    (beyond the rectangle's edge) is not seen, and neither is one on the mirror image of the line."""
    a = np.radians(100.0)
    assert np.all(_tilted_mirror(50.0, 3.0 * np.array([np.sin(a), np.cos(a), 0.0])) == 0.0)
    assert np.all(_tilted_mirror(50.0, 3.0 * np.array([np.sin(a), -np.cos(a), 0.0])) == 0.0)


def test_pplastic_is_not_approximated():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sc = load_string(_scene('<bsdf type="pplastic"><float name="alpha" value="0.2"/></bsdf>'))
    assert type(sc.shapes[0].material).__name__ == "PolarizedPlastic"
    assert not [w for w in caught if "bsdf" in str(w.message)]
    with pytest.raises(SceneError, match="eta"):
        load_string(_scene('<bsdf type="pplastic"><float name="eta" value="1.5"/>'
                           '<float name="int_ior" value="1.5"/></bsdf>'))


def test_delta_lobes_of_a_map_inside_a_blend_or_mask_are_warned():
    """A normal map's mirror rays are turned where the map is the hit's BSDF (also inside
    ``twosided``): no warning; inside a ``blendbsdf`` or a ``mask`` the integrator does not see the
    map, and the loader says so."""
    mirror = ('<bsdf type="normalmap"><rgb name="normalmap" value="0.6, 0.5, 0.9"/>'
              '<bsdf type="conductor"/></bsdf>')
    blend = f'<bsdf type="blendbsdf"><float name="weight" value="0.3"/>{mirror}<bsdf type="diffuse"/></bsdf>'
    for xml, warned in ((mirror, False), (f'<bsdf type="twosided">{mirror}</bsdf>', False),
                        (blend, True), (f'<bsdf type="mask">{mirror}</bsdf>', True)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            load_string(_scene(xml))
        assert any("unturned normal" in str(w.message) for w in caught) == warned, xml
