"""Gradients of the links1 shapes' geometry.

``links1_whitted`` lists the geometry of ``links1_quadric`` (``to_world``, ``clip_<k>_offset``)
and ``links1_blob`` (``centers``, ``weights``, ``radii``, ``threshold``, ``to_world``) under its
own id; the derivative is the interior one (the hit moving with the surface by implicit
differentiation of the surface equation), silhouettes and shadow edges are left out.

Finite differences. spp 1 (the sample at the pixel centre, so the derivative pass traces the
primal's rays), delta lights. The loss sums the pixels that see the differentiated shape and
whose 8 neighbours and their neighbours see it too (the shape's pixels, found by changing its
diffuse colour, eroded twice): with steps h = 1e-2 the silhouette moves by under a tenth of a
pixel, so no pixel of the loss changes visibility, and no shadow falls on the shape. The
frames are smooth functions of the parameters there; the central difference errs by
h²/6 · f''' (relative ~1e-5) plus the float32 rounding of ~50 pixels of size ~0.5 divided by
2h (~1e-4 absolute): tolerance 2e-3 relative + 2e-3 absolute (5e-3 relative for blobs, whose
hit is a float32 root of an iterative solver: its rounding noise, ~1e-6 of the distance, moves
the sums by ~1e-4 relative between the two frames).
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

CAMERA = perspective("0, 3, 6", "0, 0.8, 0", fov=40, width=24, height=18)

FLOOR = """<shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/><rgb name="reflectance" value="0.2"/></bsdf></shape>"""

LIGHTS = """<emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.6"/>
    <rgb name="L2" value="0.4"/><string name="falloff" value="inverse_square"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="4"/><rgb name="intensity" value="6"/></emitter>"""

# a Phong sphere with a highlight above a mirror-ish floor (no mirror term on the sphere: its
# reflection of the floor would hold its own shadow's edge, which moves with it, left out)
SPHERE = f"""{FLOOR}
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="12"/></bsdf></shape>
  {LIGHTS}"""

# a capped cylinder cut by two planes, tilted so that the camera sees its top cap
CYLINDER = f"""{FLOOR}
  <shape type="links1_quadric" id="can"><string name="kind" value="cylinder"/>
    <vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="0.5"/>
    <vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="0.5"/>
    <boolean name="capped" value="true"/>
    <transform name="to_world"><rotate x="1" angle="-60"/><scale value="1.1"/><translate x="0" y="1.5" z="0"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.2"/>
      <rgb name="reflectance" value="0"/></bsdf></shape>
  {LIGHTS}"""


def load(tmp_path, body, depth=3, camera=None):
    import links1_mitsuba as lm
    path = tmp_path / "scene.xml"
    path.write_text(scene(camera or whitted(depth) + CAMERA, body))
    return lm.load_file(str(path))


def frame(scene):
    import mitsuba as mi
    return np.array(mi.render(scene), dtype=np.float64)


def erode(m, times):
    for _ in range(times):
        p = np.pad(m, 1, constant_values=False)
        m = m & p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:] & p[:-2, :-2] & p[2:, 2:] & p[:-2, 2:] & p[2:, :-2]
    return m


def interior(scene, shape, times=2):
    """Weights on the pixels that see ``shape`` (its diffuse colour changes them), eroded
    ``times``: a ramp from 1 to 2.5 over the frame, 0 elsewhere."""
    import mitsuba as mi
    params = mi.traverse(scene)
    key = f"links1_whitted.{shape}.bsdf.diffuse.value"
    before = frame(scene)
    old = mi.Color3f(params[key])
    params[key] = mi.Color3f(0.9, 0.05, 0.7)
    params.update()
    after = frame(scene)
    params[key] = old
    params.update()
    m = erode(np.abs(after - before).sum(-1) > 0, times)
    assert m.sum() >= 20, m.sum()
    # a ramp over the frame: no symmetric cancellation in the sum
    h, w = m.shape
    ramp = 1.0 + np.arange(h)[:, None] / h + 0.5 * np.arange(w)[None, :] / w
    return np.repeat((m * ramp)[..., None], 3, -1).astype(np.float32)


def transform_of(mi, kind, th, m0):
    """``to_world`` as a function of one parameter ``th`` around ``m0``: a translation along an
    axis (kind 0, 1, 2) or a uniform scale about the centre (kind "scale", th the factor)."""
    base = mi.Transform4f(m0.tolist())
    if kind == "scale":
        c = [float(x) for x in m0[:3, 3]]
        lin = mi.Transform4f((np.c_[np.r_[m0[:3, :3], np.zeros((1, 3))], [0, 0, 0, 1]]).tolist())
        return mi.Transform4f().translate(mi.Vector3f(*c)) @ mi.Transform4f().scale(th) @ lin
    v = [mi.Float(0.0)] * 3
    v[kind] = th
    return mi.Transform4f().translate(mi.Vector3f(*v)) @ base


def param_grad(scene, key, make, th0, weights):
    """d(Σ weights · image)/dθ where ``params[key] = make(θ)``, by mi.render + dr.backward."""
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(scene)
    old = type(params[key])(params[key])
    th = mi.Float(th0)
    dr.enable_grad(th)
    params[key] = make(th)
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(weights), axis=None))
    g = float(dr.grad(th)[0])
    params[key] = old
    params.update()
    return g


def param_fd(scene, key, make, th0, weights, h=1e-2):
    import mitsuba as mi
    params = mi.traverse(scene)
    old = type(params[key])(params[key])
    sums = []
    for th in (th0 + h, th0 - h):
        params[key] = make(mi.Float(th))
        params.update()
        sums.append(float((frame(scene) * weights).sum()))
    params[key] = old
    params.update()
    return (sums[0] - sums[1]) / (2 * h)


@pytest.mark.slow
@pytest.mark.parametrize("kind", [0, 1, 2, "scale"])
def test_quadric_transform_reverse_equals_finite_difference(variant, tmp_path, kind):
    """A sphere's translation along each axis and its uniform scale: the reverse-mode gradient
    of the sum over its interior pixels equals the central difference (the hit moving with the
    closed-form root; the normal, the highlight, the light's distance and the mirror floor's
    reflection of it all move)."""
    import mitsuba as mi
    scene = load(tmp_path, SPHERE)
    key = "links1_whitted.ball.to_world"
    m0 = np.array(mi.traverse(scene)[key].matrix, dtype=np.float64).reshape(4, 4)
    w = interior(scene, "ball")
    th0 = 1.0 if kind == "scale" else 0.0
    make = (lambda th: transform_of(mi, kind, th, m0))
    g = param_grad(scene, key, make, th0, w)
    fd = param_fd(scene, key, make, th0, w)
    assert abs(g - fd) <= 2e-3 * abs(fd) + 2e-3, (kind, g, fd)
    assert abs(fd) > 0.3, fd


# a mirror ball inside a diffuse room (a links1 sphere seen from inside), lit from the camera's
# place: its reflection of the room is smooth (the ball's own shadow lies behind it, reached
# only by grazing reflections at its silhouette, which the loss leaves out), and it moves with
# the ball, through the mirror rays' origins and directions
MIRROR_BALL = """
  <shape type="links1_quadric" id="room"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="12"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.5, 0.3"/><rgb name="reflectance" value="0"/></bsdf></shape>
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="1.2"/><translate x="0.2" y="1.4" z="0.3"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.2, 0.2, 0.2"/><rgb name="reflectance" value="0.6"/></bsdf></shape>
  <emitter type="point"><point name="position" x="0" y="3" z="6"/><rgb name="intensity" value="40"/></emitter>"""


@pytest.mark.parametrize("kind", [0, 2])
def test_moving_mirror_reverse_equals_finite_difference(variant, tmp_path, kind):
    """A mirror ball's translation: the reverse-mode gradient of the sum over its interior
    pixels equals the central difference, the reflection included (the mirror rays start
    on the moving surface and turn with its normal: their derivative is carried to the next
    level of the tree; without it the gradient is the direct shading's alone, ~half of it)."""
    import mitsuba as mi
    scene = load(tmp_path, MIRROR_BALL, depth=2)
    key = "links1_whitted.ball.to_world"
    m0 = np.array(mi.traverse(scene)[key].matrix, dtype=np.float64).reshape(4, 4)
    w = interior(scene, "ball")
    make = (lambda th: transform_of(mi, kind, th, m0))
    g = param_grad(scene, key, make, 0.0, w)
    fd = param_fd(scene, key, make, 0.0, w)
    assert abs(g - fd) <= 2e-3 * abs(fd) + 2e-3, (kind, g, fd)
    assert abs(fd) > 0.3, fd


@pytest.mark.slow
@pytest.mark.parametrize("key", ["clip_0_offset", "to_world"])
def test_capped_cylinder_reverse_equals_finite_difference(variant, tmp_path, key):
    """A capped cylinder cut by two planes: moving its top cap (``clip_0_offset``, the cap's
    plane ``z ≤ h`` in object space) or the whole shape (a translation along y) changes the
    cap's distance to the lights; pixels inside the cap only (its side's pixels, whose hits do
    not move with the offset, are in the mask too and add zero)."""
    import mitsuba as mi
    scene = load(tmp_path, CYLINDER)
    full = f"links1_whitted.can.{key}"
    params = mi.traverse(scene)
    assert full in params
    w = interior(scene, "can")
    if key == "to_world":
        m0 = np.array(params[full].matrix, dtype=np.float64).reshape(4, 4)
        make, th0 = (lambda th: transform_of(mi, 1, th, m0)), 0.0
    else:
        make, th0 = (lambda th: mi.Float(th)), 0.5
    g = param_grad(scene, full, make, th0, w)
    fd = param_fd(scene, full, make, th0, w)
    assert abs(g - fd) <= 2e-3 * abs(fd) + 2e-3, (key, g, fd)
    assert abs(fd) > 0.1, fd


HEAD_ON = """<integrator type="links1_whitted"><integer name="max_depth" value="1"/></integrator>
  <sensor type="orthographic">
    <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="33"/><integer name="height" value="33"/><rfilter type="box"/></film>
    <sampler type="independent"><integer name="sample_count" value="1"/></sampler></sensor>
  <shape type="links1_quadric" id="ball"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.8"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.5, 0.3"/></bsdf></shape>
  <emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/><rgb name="irradiance" value="1.5"/></emitter>"""


def test_closed_form_sphere_radius_head_on(variant, tmp_path):
    """A diffuse sphere of radius R seen head-on (orthographic camera along −z) under a light
    along the view: a pixel at distance ρ from the axis sees ``I = k E cos θ`` with
    ``cos θ = √(1 − ρ²/R²)`` (eq. 3.11, k the diffuse coefficient), so
    ``dI/dR = k E ρ²/(R³ cos θ) = k E (1 − cos² θ)/(R cos θ)``: with ``cos θ = I/(kE)`` read
    from the primal frame, a closed form per pixel, against render_forward's derivative image
    (pixels with cos θ > 0.3: away from the silhouette, where it diverges)."""
    import drjit as dr
    import mitsuba as mi
    scene = load(tmp_path, "", camera=HEAD_ON)
    key = "links1_whitted.ball.to_world"
    R, E, k = 0.8, 1.5, np.array([0.7, 0.5, 0.3])
    img = frame(scene)
    cos = img / (k * E)
    params = mi.traverse(scene)
    r = mi.Float(R)
    dr.enable_grad(r)
    params[key] = mi.Transform4f().scale(r)
    params.update()
    out = mi.render(scene, params)
    dr.set_grad(r, 1.0)
    dr.forward_to(out)
    d_img = np.array(dr.grad(out), dtype=np.float64)
    inside = cos[..., 0] > 0.3
    assert inside.sum() > 300
    expect = k * E * (1 - cos ** 2) / (R * np.where(cos > 0, cos, 1.0))
    np.testing.assert_allclose(d_img[inside], expect[inside], rtol=2e-3, atol=2e-4)
    assert np.max(expect[inside]) > 1.0


@pytest.mark.slow
def test_forward_equals_reverse_geometry(variant, tmp_path):
    """Dot-product test ``u·(J v) = (Jᵀ u)·v`` over a quadric's translation, a clip offset, a
    light's position and a colour at once, through the whole ray tree (depth 3)."""
    import drjit as dr
    import mitsuba as mi
    scene = load(tmp_path, CYLINDER)
    params = mi.traverse(scene)
    m0 = np.array(params["links1_whitted.can.to_world"].matrix, dtype=np.float64).reshape(4, 4)
    rng = np.random.default_rng(5)
    v = rng.normal(size=6)
    u = rng.normal(size=(18, 24, 3)).astype(np.float32)

    def setup():
        tr, off = mi.Vector3f(0.0), mi.Float(0.5)
        pos, dif = mi.Point3f(2, 4, 3), mi.Color3f(0.6, 0.5, 0.4)
        for x in (tr, off, pos, dif):
            dr.enable_grad(x)
        params["links1_whitted.can.to_world"] = mi.Transform4f().translate(tr) @ mi.Transform4f(m0.tolist())
        params["links1_whitted.can.clip_0_offset"] = off
        params["lp.position"] = pos
        params["floor.bsdf.diffuse.value"] = dif
        params.update()
        return tr, off, pos, dif
    tr, off, pos, dif = setup()
    dr.set_grad(tr, mi.Vector3f(*[float(x) for x in v[:3]]))
    dr.set_grad(off, float(v[3]))
    dr.set_grad(pos, mi.Point3f(float(v[4]), float(v[5]), 0.0))
    dr.set_grad(dif, mi.Color3f(0.3, -0.2, 0.1))
    img = mi.render(scene, params)
    dr.forward_to(img)
    lhs = float(np.sum(u * np.array(dr.grad(img), dtype=np.float64)))
    tr, off, pos, dif = setup()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(u), axis=None))
    gv = np.r_[np.array(dr.grad(tr)).ravel(), np.array(dr.grad(off)).ravel(), np.array(dr.grad(pos)).ravel()[:2]]
    rhs = float(np.dot(gv, v)) + float(np.dot(np.array(dr.grad(dif)).ravel(), [0.3, -0.2, 0.1]))
    assert abs(lhs) > 0.1
    assert abs(lhs - rhs) <= 1e-4 * abs(lhs), (lhs, rhs)


def test_quadric_update_shows_in_next_frame(variant, tmp_path):
    """``params.update()`` of a quadric's ``to_world`` and clip offset gives the frame of the
    scene loaded with those values, bit for bit; a singular transform is refused."""
    import mitsuba as mi
    scene = load(tmp_path, CYLINDER)
    before = frame(scene)
    params = mi.traverse(scene)
    m = np.array(params["links1_whitted.can.to_world"].matrix, dtype=np.float64).reshape(4, 4)
    m[:3, 3] += [0.25, 0.5, -0.125]
    params["links1_whitted.can.to_world"] = mi.Transform4f(m.tolist())
    params["links1_whitted.can.clip_0_offset"] = mi.Float(0.25)
    params.update()
    after = frame(scene)
    body = CYLINDER.replace('<translate x="0" y="1.5" z="0"/>', '<translate x="0" y="1.5" z="0"/><translate x="0.25" y="0.5" z="-0.125"/>') \
        .replace('<float name="clip_0_offset" value="0.5"/>', '<float name="clip_0_offset" value="0.25"/>')
    expect = frame(load(tmp_path, body))
    assert not np.array_equal(before, after)
    assert np.array_equal(after, expect)
    params["links1_whitted.can.to_world"] = mi.Transform4f(np.diag([1.0, 1.0, 0.0, 1.0]).tolist())
    with pytest.raises(ValueError, match="links1_quadric 'can'"):
        params.update()


# a 6-centre blob above the mirror floor (positive weights: a carving centre makes a dent that
# shadows itself, a shadow edge moving with the centres)
BLOB = f"""{FLOOR}
  <shape type="links1_blob" id="blob">
    <string name="centers" value="-0.625 1.375 0 1 0.75,  0.5 1.5 0.2 1 0.6,  0 2.0 -0.2 0.8 0.6,
                                  0 1.25 0.3 0.9 0.5,  0.875 1.25 -0.25 0.75 0.5,  0.1 1.6 0.4 0.5 0.4"/>
    <float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="10"/></bsdf></shape>
  {LIGHTS}"""


def flat_grad(scene, key, weights):
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(weights), axis=None))
    g = np.array(dr.grad(params[key]), dtype=np.float64).ravel()
    dr.disable_grad(params[key])
    return g


def flat_fd(scene, key, comp, weights, h):
    import mitsuba as mi
    params = mi.traverse(scene)
    old = params[key]
    v0 = np.array(old, dtype=np.float64).copy()    # a Point3f: (3, N)
    shape = v0.shape
    sums = []
    for s in (h, -h):
        v = v0.ravel().copy()
        v[comp] += s
        v = v.reshape(shape)
        params[key] = type(old)(*v) if v.ndim == 2 else type(old)(v)
        params.update()
        sums.append(float((frame(scene) * weights).sum()))
    params[key] = type(old)(*v0) if v0.ndim == 2 else type(old)(v0)
    params.update()
    return (sums[0] - sums[1]) / (2 * h)


@pytest.mark.slow
@pytest.mark.parametrize("key", ["centers", "weights", "radii", "threshold"])
def test_blob_reverse_equals_finite_difference(variant, tmp_path, key):
    """A 6-centre blob's centres, weights, ranges S and threshold T: the hit moves by
    ``dt = −(∂W/∂θ)/(∂W/∂t)`` (implicit differentiation of W(x) = T, eq. 3.6–3.9) and the
    normal with ∇W; reverse mode against central differences over the blob's interior pixels
    (components that change the sum by more than 0.05 per unit; at least 3 of them). Step
    h = 1e-3: the kernel P (eq. 3.9) is C¹ only (its second derivative jumps at S and 3S), so
    pixels whose point crosses r = S within ±h make the central difference err by O(h)
    (measured for a range: 4.3005, 4.4156, 4.4155, 4.4157 at h = 2e-3, 1e-3, 5e-4, 2.5e-4
    against the gradient's 4.4155); float32 rounding of the sums / 2h stays ~5e-4."""
    scene = load(tmp_path, BLOB)
    w = interior(scene, "blob")
    full = f"links1_whitted.blob.{key}"
    g = flat_grad(scene, full, w)
    checked = 0
    for c in range(len(g)):
        fd = flat_fd(scene, full, c, w, 1e-3)
        assert abs(g[c] - fd) <= 5e-3 * abs(fd) + 5e-3, (key, c, g[c], fd)
        checked += abs(fd) > 0.05
    assert checked >= min(3, len(g)), (key, g)


def test_blob_update_shows_in_next_frame(variant, tmp_path):
    """``params.update()`` of a blob's centres and threshold gives the frame of the scene
    loaded with them (the candidate tables and bounds rebuilt), bit for bit."""
    import mitsuba as mi
    scene = load(tmp_path, BLOB)
    before = frame(scene)
    params = mi.traverse(scene)
    c = np.array(params["links1_whitted.blob.centers"], dtype=np.float64)   # (3, N)
    c[:, 0] += [0.25, -0.125, 0.0]
    params["links1_whitted.blob.centers"] = mi.Point3f(*c)
    params["links1_whitted.blob.threshold"] = mi.Float(0.375)
    params.update()
    after = frame(scene)
    expect = frame(load(tmp_path, BLOB.replace("-0.625 1.375 0 1 0.75", "-0.375 1.25 0 1 0.75")
                        .replace('value="0.5"/>\n    <bsdf', 'value="0.375"/>\n    <bsdf')))
    assert not np.array_equal(before, after)
    assert np.array_equal(after, expect)
    params["links1_whitted.blob.radii"] = mi.Float([0.75, 0.6, -0.6, 0.5, 0.5, 0.4])
    with pytest.raises(ValueError, match="links1_blob 'blob'.*range S"):
        params.update()


def many_centres(n=40, seed=7):
    """A ``links1_blob`` of ``n`` centres (rows x y z w S) scattered in a ball of radius 0.9
    around (0, 1.2, 0), ``S`` 0.3-0.4, threshold 1, lit from the camera's place (no shadow
    seen on it): the rays through the middle cross the 3S sphere of every centre."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p *= 0.9 * rng.uniform(0, 1, n)[:, None] ** (1 / 3) / np.linalg.norm(p, axis=1)[:, None]
    c = np.c_[p + [0, 1.2, 0], rng.uniform(0.6, 1.0, n), rng.uniform(0.3, 0.4, n)]
    rows = ", ".join(" ".join(f"{x:.3g}" for x in r) for r in c)
    return len(c), f"""<shape type="links1_blob" id="blob"><string name="centers" value="{rows}"/>
    <float name="threshold" value="1"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <rgb name="reflectance" value="0"/><float name="exponent" value="10"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="0" y="3" z="6"/><rgb name="L1" value="0.8"/></emitter>"""


def test_many_centre_blob_forward_and_reverse_equal_finite_difference(variant, tmp_path):
    """A blob of 40 centres, whose solver sums over each ray's candidate centres (registers for
    up to SLOTS of them, the list in local memory beyond: both here), differentiated in
    reverse mode (every centre) and forward mode (one centre's x) through the derivative
    pass's kernels; the centre's x against the central difference over the interior pixels
    (h and tolerance as the 6-centre blob's above)."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.blob_candidates import LIST_MIN_CENTRES
    n, body = many_centres()
    assert n >= LIST_MIN_CENTRES
    scene = load(tmp_path, body, depth=1)
    w = interior(scene, "blob")
    key = "links1_whitted.blob.centers"
    g = flat_grad(scene, key, w)
    k = int(np.argmax(np.abs(g[:n])))      # the x whose term moves the sum most
    fd = flat_fd(scene, key, k, w, 1e-3)
    assert abs(fd) > 1.0, fd
    assert abs(g[k] - fd) <= 5e-3 * abs(fd) + 5e-3, (k, g[k], fd)
    params = mi.traverse(scene)
    c0 = np.array(params[key], dtype=np.float64)          # (3, N)
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = mi.Point3f(mi.Float(c0[0]) + dr.select(dr.arange(mi.UInt32, n) == k, th, 0.0),
                             mi.Float(c0[1]), mi.Float(c0[2]))
    params.update()
    img = mi.render(scene, params)
    dr.set_grad(th, 1.0)
    dr.forward_to(img)
    fwd = float((np.array(dr.grad(img), dtype=np.float64) * w).sum())
    params[key] = mi.Point3f(*c0)
    params.update()
    assert abs(fwd - fd) <= 5e-3 * abs(fd) + 5e-3, (k, fwd, fd)


@pytest.mark.slow
def test_many_centre_blob_projective_forward_equals_reverse(variant, tmp_path):
    """The same blob, now a mirror too, over the floor, with the visibility term
    (``projective``, its outline's samples): forward and reverse mode give the same
    d (weighted sum) / d(first centre's x) at the same samples (to float32 rounding). Its
    mirror rays start on the moving surface (attached), and those that meet it again are
    traced through its candidate lists (the normal there on primal values: moving_hits
    attaches it)."""
    from tests.plugins.test_boundary_gradients import forward, reverse
    _, body = many_centres()
    body = FLOOR + body.replace('<rgb name="reflectance" value="0"/>', '<rgb name="reflectance" value="0.3"/>')
    scene = load(tmp_path, body, camera=whitted(2, projective=True) + CAMERA)
    key = "links1_whitted.blob.centers"
    weight = np.random.default_rng(3).uniform(0.5, 1.5, (18, 24, 3))
    fwd = float((forward(scene, key, 5, spp=2) * weight).sum())
    rev = reverse(scene, key, weight, 5, spp=2)
    assert abs(fwd) > 0.5, (fwd, rev)
    assert rev == pytest.approx(fwd, rel=1e-4, abs=1e-4)
