"""Gradients of ``links1_whitted`` on LLVM.

* every parameter family: the reverse-mode gradient (``mi.render(scene, params)``,
  ``dr.backward``) of a pixel-sum loss equals a central finite difference of the same
  renderer's primal frames;
* forward mode equals reverse mode (the dot-product test ``u·(J v) = (Jᵀ u)·v``);
* closed forms: a diffuse plane under Mitsuba's point light, the centre pixel
  ``ρ/π · I cos θ / r²`` and its derivatives in ρ, I and the light's position;
* the primal frame of ``mi.render`` with gradients enabled is the frame without them, bit for
  bit (to float32 rounding where the derivative pass's frame is kept: test_kept_graph.py);
  ``params.update()`` of the links1 plugins' parameters gives the frame of a scene loaded
  with the new values.

Finite differences. All renders use spp 1 (the sample at the pixel centre, whatever the seed:
the gradient pass's ``seed_grad`` then gives the same rays as the primal), delta lights only.
The scenes keep shadow edges and silhouettes out of the differentiated parameters' reach (the
interior derivative is what links1_whitted differentiates): colour parameters do not move any
edge; the light-position scenes have no occluder. Step: colours enter the frame linearly, so
the central difference is exact up to float32 rounding of the frame: a sum of ~400 pixels of
size ~1 carries ~400 · 6e-8 absolute rounding, divided by 2h = 0.02 that is ~1e-3 against
gradients of 1-100; tolerance 2e-3 relative (+1e-2 absolute). Non-linear parameters (the
exponent, light positions): central differences err by h²/6 · f''' (relative ~1e-5 at
h = 1e-2 on these smooth functions, measured ~3e-5), the same tolerance.
"""
from __future__ import annotations

import numpy as np
import pytest

from tests import scenes

pytestmark = pytest.mark.mitsuba

def camera(depth, rfilter="box"):
    """links1_whitted to ``depth`` and a 24 x 18 camera, spp 1 (``rfilter`` "": gaussian)."""
    return scenes.whitted(depth) + scenes.perspective("0, 3, 6", "0, 0.5, 0", fov=40, width=24, height=18,
                                                      rfilter=rfilter)

# colours: a Phong sphere (all coefficients), a Mitsuba diffuse floor, both kinds of point light
# and a links1 spot; a mirror-and-glass Phong sphere sends rays down the tree (depth 4)
SHADING = """
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="sphere" id="ball"><point name="center" x="-0.9" y="0.8" z="0"/><float name="radius" value="0.8"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.3, 0.4, 0.5"/><rgb name="specular" value="0.3"/>
      <rgb name="ambient" value="0.05"/><float name="exponent" value="15"/></bsdf></shape>
  <shape type="sphere" id="glass"><point name="center" x="0.9" y="0.9" z="0.6"/><float name="radius" value="0.7"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.1"/><rgb name="specular" value="0.2"/>
      <rgb name="reflectance" value="0.3"/><rgb name="transmittance" value="0.5"/><float name="ior" value="1.3"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.7"/>
    <rgb name="L2" value="0.3"/><vector name="direction" x="-0.4" y="-1" z="-0.6"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="2"/><rgb name="intensity" value="5"/></emitter>
  <emitter type="links1_spot" id="sp"><point name="origin" x="0" y="5" z="0"/><vector name="direction" x="0" y="-1" z="0"/>
    <float name="radius" value="1.5"/><rgb name="intensity" value="0.4"/></emitter>
"""

# light positions: planes only, nothing casts a shadow; a Phong plane with a highlight and a
# diffuse one (the light's cosine lobe and the highlight move with the light)
LIGHTS_MOVE = """
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.4"/>
      <float name="exponent" value="8"/></bsdf></shape>
  <shape type="rectangle" id="wall"><transform name="to_world"><scale value="5"/><translate z="-2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.4, 0.5, 0.6"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="1" y="2.5" z="1"/><rgb name="L1" value="0.5"/>
    <rgb name="L2" value="0.5"/><vector name="direction" x="0" y="-1" z="-0.3"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-1.5" y="2" z="1.5"/><rgb name="intensity" value="4"/></emitter>
"""

SHADING_KEYS = ["ball.bsdf.diffuse.value", "ball.bsdf.specular.value", "ball.bsdf.ambient.value",
                "ball.bsdf.exponent", "glass.bsdf.reflectance.value", "glass.bsdf.transmittance.value",
                "glass.bsdf.diffuse.value", "floor.bsdf.reflectance.value", "lp.L1.value", "lp.L2.value",
                "mp.intensity.value", "sp.intensity.value"]
MOVE_KEYS = ["lp.position", "mp.position"]


def load(body, depth=4, rfilter="box"):
    import mitsuba as mi
    return mi.load_string(scenes.scene(camera(depth, rfilter), body))


def frame(scene, **kw):
    import mitsuba as mi
    return np.array(mi.render(scene, **kw), dtype=np.float64)


def reverse_grad(scene, key, weights=None):
    """d(Σ weights · image)/d params[key] by mi.render + dr.backward (weights: all ones)."""
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    img = mi.render(scene, params)
    loss = dr.sum(img if weights is None else img * mi.TensorXf(weights), axis=None)
    dr.backward(loss)
    g = np.array(dr.grad(params[key]), dtype=np.float64).ravel()
    dr.disable_grad(params[key])
    return g


def set_value(scene, key, values):
    import mitsuba as mi
    params = mi.traverse(scene)
    cur = params[key]
    params[key] = type(cur)(*[float(v) for v in values]) if len(values) > 1 else type(cur)(float(values[0]))
    params.update()


def central_difference(scene, key, comp, h):
    import mitsuba as mi
    v0 = np.array(mi.traverse(scene)[key], dtype=np.float64).ravel().copy()

    def loss(delta):
        v = v0.copy()
        v[comp] += delta
        set_value(scene, key, v)
        return frame(scene).sum()
    fd = (loss(h) - loss(-h)) / (2 * h)
    set_value(scene, key, v0)
    return fd


@pytest.mark.slow
@pytest.mark.parametrize("key", SHADING_KEYS)
def test_reverse_equals_finite_difference_shading(variant, key):
    scene = load(SHADING)
    g = reverse_grad(scene, key)
    comps = range(len(g))
    for c in comps:
        fd = central_difference(scene, key, c, 1e-2)
        assert abs(g[c] - fd) <= 2e-3 * abs(fd) + 1e-2, (key, c, g, fd)
    assert np.any(np.abs(g) > 0.05), f"{key}: no gradient at all ({g})"


@pytest.mark.slow
@pytest.mark.parametrize("key", MOVE_KEYS)
def test_reverse_equals_finite_difference_light_position(variant, key):
    scene = load(LIGHTS_MOVE, depth=1)
    g = reverse_grad(scene, key)
    for c in range(3):
        fd = central_difference(scene, key, c, 1e-2)
        assert abs(g[c] - fd) <= 2e-3 * abs(fd) + 1e-2, (key, c, g, fd)
    assert np.max(np.abs(g)) > 1.0


FAMILY_KEYS = ["ball.bsdf.diffuse.value", "glass.bsdf.transmittance.value", "lp.L2.value", "ball.bsdf.exponent",
               "floor.bsdf.reflectance.value", "mp.intensity.value"]


@pytest.mark.slow
def test_forward_equals_reverse(variant):
    """Dot-product test over several families at once, with a Gaussian film at spp 1 (the
    film's neighbour loop differentiated too)."""
    _forward_equals_reverse(load(SHADING, rfilter=""), FAMILY_KEYS, spp=1)


@pytest.mark.slow
@pytest.mark.parametrize("spp", [2, 7])
def test_film_forward_equals_reverse(variant, spp):
    """The Gaussian film at spp > 1 differentiated: a derivative pass takes its two passes
    (film._filter_partials, film._filter_sum) at every such spp, their sample loops unrolled up
    to film.UNROLL_MAX steps (spp 2) or not (spp 7); a depth-1 frame and two parameters, so the
    film is what differs from the spp-1 test."""
    _forward_equals_reverse(load(SHADING, depth=1, rfilter=""), ["floor.bsdf.reflectance.value", "lp.L2.value"],
                            spp=spp)


def _forward_equals_reverse(scene, keys, spp):
    """u·(J v) from render_forward equals (Jᵀ u)·v from render_backward, to float32 rounding."""
    import drjit as dr
    import mitsuba as mi
    rng = np.random.default_rng(3)
    params = mi.traverse(scene)
    vs = {k: rng.normal(size=dr.width(params[k]) * (3 if dr.size_v(params[k]) == 3 else 1)) for k in keys}
    u = rng.normal(size=(18, 24, 3)).astype(np.float32)
    # forward: J v
    for k in keys:
        dr.enable_grad(params[k])
        v = vs[k]
        dr.set_grad(params[k], type(params[k])(*[float(x) for x in v]) if len(v) > 1 else type(params[k])(float(v[0])))
    img = mi.render(scene, params, spp=spp, seed=1, seed_grad=2)
    dr.forward_to(img)
    jv = np.array(dr.grad(img), dtype=np.float64)
    for k in keys:
        dr.disable_grad(params[k])
    lhs = float(np.sum(u * jv))
    # reverse: Jᵀ u
    params = mi.traverse(scene)
    for k in keys:
        dr.enable_grad(params[k])
    img = mi.render(scene, params, spp=spp, seed=1, seed_grad=2)
    dr.backward(dr.sum(img * mi.TensorXf(u), axis=None))
    rhs = sum(float(np.dot(np.array(dr.grad(params[k]), dtype=np.float64).ravel(), vs[k])) for k in keys)
    for k in keys:
        dr.disable_grad(params[k])
    assert abs(lhs) > 1.0
    assert abs(lhs - rhs) <= 1e-4 * abs(lhs), (lhs, rhs)


PLANE = scenes.whitted(1) + scenes.perspective("0, 4, 0", "0, 0, 0", fov=30, width=9, up="0, 0, -1") + """
  <shape type="rectangle" id="plane"><transform name="to_world"><scale value="10"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <emitter type="point" id="light"><point name="position" x="1" y="3" z="0.5"/><rgb name="intensity" value="7"/></emitter>
"""


@pytest.mark.slow
def test_closed_form_diffuse_plane_point_light(variant):
    """The centre pixel of an odd film looks straight down at the origin of the plane y = 0:
    ``L = ρ/π · I y / r³`` (r = |p|, p the light's position), so dL/dρ = I y/(π r³),
    dL/dI = ρ y/(π r³) and dL/dp = ρ I/π · (e_y/r³ − 3 y p/r⁵)."""
    import drjit as dr
    import mitsuba as mi
    scene = mi.load_string(scenes.scene(PLANE))
    rho, intensity = 0.6, 7.0
    p = np.array([1.0, 3.0, 0.5])
    r = np.linalg.norm(p)
    L = rho / np.pi * intensity * p[1] / r ** 3
    img = frame(scene)
    assert img[4, 4, 0] == pytest.approx(L, rel=1e-5)
    weights = np.zeros((9, 9, 3), dtype=np.float32)
    weights[4, 4, 0] = 1.0
    g_rho = reverse_grad(scene, "plane.bsdf.reflectance.value", weights)
    g_i = reverse_grad(scene, "light.intensity.value", weights)
    g_p = reverse_grad(scene, "light.position", weights)
    assert g_rho[0] == pytest.approx(intensity * p[1] / (np.pi * r ** 3), rel=1e-5)
    assert abs(g_rho[1]) + abs(g_rho[2]) == 0.0
    assert g_i[0] == pytest.approx(rho * p[1] / (np.pi * r ** 3), rel=1e-5)
    dp = rho * intensity / np.pi * (np.array([0.0, 1.0, 0.0]) / r ** 3 - 3 * p[1] * p / r ** 5)
    np.testing.assert_allclose(g_p, dp, rtol=1e-4, atol=1e-7)
    assert dr.grad_enabled(mi.traverse(scene)["light.position"]) is False


@pytest.mark.slow
@pytest.mark.parametrize("keep_graph", [False, True])
def test_primal_unchanged_with_gradients_enabled(variant, keep_graph):
    """The frame mi.render returns while parameters have gradients enabled is the frame without
    them (Gaussian film, depth 4): bit for bit where it is the primal frozen launch; where the
    derivative pass's frame is kept for dr.backward (gradients.py, ``Tuning.keep_graph``), to
    float32 rounding: its ray tree is summed level by level rather than depth first (about
    one sample in ten 1 or 2 ulp off on this scene), and the film's float32 sums round those
    differently (measured: 4 % of the pixel values, at most 3 ulp off; 2 with float64 sums)."""
    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba import tuning
    scene = load(SHADING, rfilter="")
    plain = frame(scene)
    params = mi.traverse(scene)
    for k in SHADING_KEYS + MOVE_KEYS:
        dr.enable_grad(params[k])
    with tuning.tuned(keep_graph=keep_graph):
        with_grad = np.array(mi.render(scene, params), dtype=np.float64)
    kept = scene.integrator().info()["kept_graph"]
    scene.integrator().engine.forget()
    for k in SHADING_KEYS + MOVE_KEYS:
        dr.disable_grad(params[k])
    assert kept == keep_graph
    if keep_graph:
        ulp = np.spacing(np.abs(plain).astype(np.float32)).astype(np.float64)
        assert np.all(np.abs(with_grad - plain) <= 4 * ulp)
    else:
        assert np.array_equal(plain, with_grad)


@pytest.mark.slow
def test_params_update_shows_in_next_frame(variant):
    """Changing links1_phong, links1_point and links1_spot parameters through mi.traverse gives
    the frame of the scene loaded with those values, bit for bit."""
    import mitsuba as mi
    scene = load(SHADING)
    before = frame(scene)
    params = mi.traverse(scene)
    for k in ("ball.bsdf.diffuse.value", "ball.bsdf.exponent", "lp.position", "lp.L1.value", "sp.intensity.value",
              "glass.bsdf.transmittance.value"):
        assert k in params, k
    params["ball.bsdf.diffuse.value"] = mi.Color3f(0.8, 0.1, 0.2)
    params["ball.bsdf.exponent"] = mi.Float(30.0)
    params["lp.position"] = mi.Point3f(1.5, 4.0, 2.0)
    params["lp.L1.value"] = mi.Color3f(0.9)
    params["sp.intensity.value"] = mi.Color3f(0.1, 0.2, 0.3)
    params["glass.bsdf.transmittance.value"] = mi.Color3f(0.0)
    params.update()
    after = frame(scene)
    body = (SHADING.replace('<rgb name="diffuse" value="0.3, 0.4, 0.5"/>', '<rgb name="diffuse" value="0.8, 0.1, 0.2"/>')
            .replace('value="15"', 'value="30"').replace('x="2" y="4" z="3"', 'x="1.5" y="4" z="2"')
            .replace('<rgb name="L1" value="0.7"/>', '<rgb name="L1" value="0.9"/>')
            .replace('<rgb name="intensity" value="0.4"/>', '<rgb name="intensity" value="0.1, 0.2, 0.3"/>')
            .replace('<rgb name="transmittance" value="0.5"/>', '<rgb name="transmittance" value="0"/>'))
    assert body != SHADING
    expect = frame(load(body))
    assert not np.array_equal(before, after)
    assert np.array_equal(after, expect)


def test_out_of_range_update_is_refused(variant):
    import mitsuba as mi
    scene = load(SHADING)
    params = mi.traverse(scene)
    params["ball.bsdf.diffuse.value"] = mi.Color3f(-0.5, 0.1, 0.2)
    with pytest.raises(ValueError):
        params.update()


@pytest.mark.slow
def test_update_of_one_colour_channel_is_seen(variant):
    """A change of the green channel alone of Mitsuba's diffuse reflectance after a frame makes
    the next frame anew (the scene digest read colours through ``.matrix``, a Dr.Jit swizzle
    of the red channel, and missed it)."""
    import mitsuba as mi
    scene = load(SHADING)
    before = frame(scene)
    params = mi.traverse(scene)
    params["floor.bsdf.reflectance.value"] = mi.Color3f(0.6, 0.1, 0.4)
    params.update()
    after = frame(scene)
    assert np.array_equal(before[..., 0], after[..., 0])
    assert np.sum(after[..., 1]) < np.sum(before[..., 1]) - 1.0


QUADRIC = """
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="links1_quadric" id="bubble"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.8"/><translate x="0.2" y="0.9" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.2"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0.2"/><rgb name="transmittance" value="0.6, 0.5, 0.4"/><float name="ior" value="1.2"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.8"/></emitter>
"""


@pytest.mark.slow
@pytest.mark.parametrize("key", ["links1_whitted.bubble.bsdf.transmittance.value",
                                 "links1_whitted.bubble.bsdf.reflectance.value",
                                 "links1_whitted.bubble.bsdf.diffuse.value", "floor.bsdf.diffuse.value"])
def test_links1_quadric_materials_and_transparent_shadow(variant, tmp_path, key):
    """A links1_quadric glass sphere (links1_whitted intersects it itself): its colours through
    refraction, reflection and its transparent shadow on the floor (the transmittance product
    of 3-3-3), reverse mode against central differences as above. links1_whitted holds the
    shape, so mi.traverse names its BSDF under the integrator: ``links1_whitted.<id>.bsdf.*``."""
    import links1_mitsuba as lm
    path = tmp_path / "q.xml"
    path.write_text(scenes.scene(camera(4), QUADRIC))
    scene = lm.load_file(str(path))
    g = reverse_grad(scene, key)
    for c in range(3):
        fd = central_difference(scene, key, c, 1e-2)
        assert abs(g[c] - fd) <= 2e-3 * abs(fd) + 1e-2, (key, c, g, fd)
    assert np.max(np.abs(g)) > 0.5
