"""The visibility term of ``links1_whitted``'s derivatives (``projective=true``, boundary.py)
against references it did not make: central differences of high-spp frames and Mitsuba's own
``direct_projective``.

The shapes carry an ambient-only ``links1_phong`` (a constant colour) before a black
background, so a parameter that moves them changes the frame only through their outlines:
without the term every derivative is 0. Both sides are estimates with noise: the derivative
over 12 seeds (``seed_grad``), the finite differences over 12 seeds too (the two frames of a
difference share their samples, so only the samples the outline sweeps differ; the step moves
the outline by about 0.1 pixel). Each check is ``|AD − FD| ≤ 5 σ`` with ``σ`` the two standard
errors combined (each estimated from its 12 values: Student's t with about 20 degrees of
freedom, beyond 5 in fewer than 1 in 10⁴ checks), and asserts first that the reference is
sharp (``|FD| ≥ 10`` of its standard errors), so that a term of 0, a wrong sign or a factor of
two fails. (With 4 seeds the errors' own estimates were too rough: a pixel's differences are
a sum of few swept samples, heavy-tailed.)
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene, whitted

pytestmark = pytest.mark.mitsuba

W, H = 32, 24
CAMERA = perspective("0, 0, 6", "0, 0, 0", fov=30, width=W, height=H, spp=4)
AMBIENT = (0.8, 0.5, 0.2)
PHONG = (f'<bsdf type="links1_phong"><rgb name="ambient" value="{", ".join(map(str, AMBIENT))}"/>'
         '<rgb name="diffuse" value="0"/></bsdf>')
LIGHT = '<emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="6"/></emitter>'

SHAPES = {
    "quadric": ("links1_whitted.obj.to_world", f"""<shape type="links1_quadric" id="obj"><string name="kind" value="sphere"/>
        <transform name="to_world"><scale x="1.1" y="0.9" z="1"/><translate x="0.2" y="0.1"/></transform>{PHONG}</shape>"""),
    "mitsuba_sphere": ("obj.to_world", f"""<shape type="sphere" id="obj"><point name="center" x="0.2" y="0.1" z="0"/>
        <float name="radius" value="1"/>{PHONG}</shape>"""),
    "blob": ("links1_whitted.obj.centers", f"""<shape type="links1_blob" id="obj">
        <string name="centers" value="-0.45 0 0 1 0.9,  0.45 0.1 0 1 0.9"/><float name="threshold" value="0.5"/>{PHONG}</shape>"""),
    # a capped cylinder seen at an angle (its outline: two side silhouettes, two rims), and an
    # open one cut by a slanted plane (the inside of the shell seen past a rim)
    "capped_cylinder": ("links1_whitted.obj.to_world", f"""<shape type="links1_quadric" id="obj"><string name="kind" value="cylinder"/>
        <boolean name="capped" value="true"/><vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="1"/>
        <vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="1"/>
        <transform name="to_world"><scale x="0.7" y="0.7" z="0.9"/><rotate x="1" angle="60"/><rotate y="1" angle="25"/>
        <translate x="0.1"/></transform>{PHONG}</shape>"""),
    "cut_cylinder": ("links1_whitted.obj.to_world", f"""<shape type="links1_quadric" id="obj"><string name="kind" value="cylinder"/>
        <vector name="clip_0" x="0.3" y="0" z="1"/><float name="clip_0_offset" value="0.8"/>
        <vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="1"/>
        <transform name="to_world"><scale x="0.7" y="0.7" z="0.9"/><rotate x="1" angle="-70"/><rotate y="1" angle="20"/>
        <translate x="0.1"/></transform>{PHONG}</shape>"""),
    "mitsuba_mesh": ("obj.vertex_positions", f"""<shape type="cube" id="obj">
        <transform name="to_world"><scale value="0.8"/><rotate y="1" angle="35"/><rotate x="1" angle="20"/><translate x="0.1"/></transform>
        {PHONG}</shape>"""),
}

AD_SEEDS, AD_SPP = range(12), 32
FD_SEEDS, FD_SPP, FD_STEP = range(12), 1024, 1e-2


def load(tmp_path, body, projective=True, rfilter="box"):
    import links1_mitsuba as lm
    cam = CAMERA if rfilter == "box" else perspective("0, 0, 6", "0, 0, 0", fov=30, width=W, height=H,
                                                      spp=4, rfilter=rfilter)
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(1, projective=projective) + cam, body, LIGHT))
    return lm.load_file(str(path))


def mover(mi, dr, params, key):
    """``make(θ)``: the shape moved by ``θ`` along x (a transform's translation, a blob's
    first centre, a mesh's every vertex)."""
    base = params[key]
    if key.endswith("vertex_positions"):
        arr = np.array(base, dtype=np.float64)
        xs = mi.Float((np.arange(arr.size) % 3 == 0).astype(np.float32))
        return lambda th: mi.Float(arr) + xs * th
    if key.endswith("centers"):
        arr = np.array(base, dtype=np.float64).reshape(3, -1)
        first = dr.arange(mi.UInt32, arr.shape[1]) == 0
        return lambda th: mi.Point3f(mi.Float(arr[0]) + dr.select(first, th, 0.0), mi.Float(arr[1]), mi.Float(arr[2]))
    base = mi.Transform4f(base)
    return lambda th: mi.Transform4f().translate(mi.Vector3f(th, 0.0, 0.0)) @ base


def forward(sc, key, seed, spp=AD_SPP, integrator=None, make=None):
    """d frame / dθ (forward mode, every pixel) at θ = 0 with ``seed_grad = seed``;
    ``params[key] = make(θ)`` (default: :func:`mover`)."""
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(sc)
    make = make or mover(mi, dr, params, key)
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = make(th)
    params.update()
    img = mi.render(sc, params, integrator=integrator, seed=seed + 100, seed_grad=seed, spp=spp)
    dr.set_grad(th, 1.0)
    dr.forward_to(img)
    out = np.array(dr.grad(img), dtype=np.float64)
    params[key] = make(mi.Float(0.0))
    params.update()
    return out


def reverse(sc, key, weight, seed, spp=AD_SPP, integrator=None):
    """d Σ weight · frame / dθ (reverse mode) at θ = 0 with ``seed_grad = seed``."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.util import aligned
    params = mi.traverse(sc)
    make = mover(mi, dr, params, key)
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = make(th)
    params.update()
    img = mi.render(sc, params, integrator=integrator, seed=seed + 100, seed_grad=seed, spp=spp)
    # (64-byte aligned: a kernel reading numpy's memory is compiled again per alignment)
    dr.backward(dr.sum(img * mi.TensorXf(aligned(weight, np.float32).reshape(weight.shape)), axis=None))
    g = float(np.array(dr.grad(th)).ravel()[0])
    params[key] = make(mi.Float(0.0))
    params.update()
    return g


def finite_differences(sc, key, seed, make=None):
    """(frame(+h) − frame(−h)) / 2h, both frames of the same seed (shared samples)."""
    import drjit as dr
    import mitsuba as mi
    params = mi.traverse(sc)
    make = make or mover(mi, dr, params, key)
    pair = []
    for s in (FD_STEP, -FD_STEP):
        params[key] = make(mi.Float(s))
        params.update()
        pair.append(np.array(mi.render(sc, seed=seed, spp=FD_SPP), dtype=np.float64))
    params[key] = make(mi.Float(0.0))
    params.update()
    return (pair[0] - pair[1]) / (2 * FD_STEP)


def mean_se(samples):
    a = np.asarray(samples, dtype=np.float64)
    return a.mean(axis=0), a.std(axis=0, ddof=1) / np.sqrt(len(a))


def assert_agree(what, ad, ad_se, fd, fd_se):
    sigma = np.hypot(ad_se, fd_se)
    assert abs(fd) >= 10 * fd_se, f"{what}: the reference {fd:.4g} ± {fd_se:.2g} is not sharp"
    assert abs(ad - fd) <= 5 * sigma, f"{what}: AD {ad:.4g} ± {ad_se:.2g}, FD {fd:.4g} ± {fd_se:.2g}"


def outline_pixels(frame, count=4):
    """Pixels the outline crosses (partly covered: red between 15 % and 85 % of the shape's)."""
    frac = frame[..., 0] / AMBIENT[0]
    ys, xs = np.nonzero((frac > 0.15) & (frac < 0.85))
    pick = np.linspace(0, len(ys) - 1, count).astype(int)
    return [(int(ys[i]), int(xs[i])) for i in pick]


@pytest.mark.slow
@pytest.mark.parametrize("family", sorted(SHAPES))
def test_outline_translation_against_finite_differences(variant, tmp_path, family):
    """d (right half's red sum) / d x-translation, and d pixel / dθ on pixels the outline
    crosses, against central differences of 1024-spp frames: a links1 ellipsoid, a capped and
    a slant-cut open cylinder (their rims: about half the crossings), a Mitsuba sphere and cube
    mesh, a two-centre blob (its first centre)."""
    import mitsuba as mi
    key, body = SHAPES[family]
    sc = load(tmp_path, body)
    ads = [forward(sc, key, s) for s in AD_SEEDS]
    fds = [finite_differences(sc, key, s) for s in FD_SEEDS]
    ad, ad_se = mean_se([a[:, W // 2:, 0].sum() for a in ads])
    fd, fd_se = mean_se([f[:, W // 2:, 0].sum() for f in fds])
    assert_agree(f"{family}: right half", ad, ad_se, fd, fd_se)
    frame = np.array(mi.render(sc, seed=7, spp=256), dtype=np.float64)
    for y, x in outline_pixels(frame):
        ad, ad_se = mean_se([a[y, x, 0] for a in ads])
        fd, fd_se = mean_se([f[y, x, 0] for f in fds])
        if abs(fd) < 10 * fd_se:   # a pixel the outline grazes: its reference is all noise
            continue
        assert_agree(f"{family}: pixel ({x}, {y})", ad, ad_se, fd, fd_se)


def cube_ply(path):
    """A cube as a PLY mesh whose faces share their 8 vertices (Mitsuba's ``cube`` gives each face
    its own 4: its edges are then each two open boundaries, and ``direct_projective`` counts
    the outline twice: 355.4 ± 1.1 against central differences' 178.6 ± 1.0 here)."""
    v = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    head = (f"ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(tris)}\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in v) + "".join(f"3 {a} {b} {c}\n" for a, b, c in tris))
    return str(path)


#: two lobes of one blob, the front one hiding part of the back one (its first centre, the
#: front lobe's, moves): a diffuse colour, so the lobes differ where one hides the other
BLOB_LOBES = """<shape type="links1_blob" id="obj">
    <string name="centers" value="0.35 0.25 0.9 1 0.5,  -0.2 -0.1 -0.6 1 0.55"/><float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.5, 0.3"/><rgb name="ambient" value="0.1"/></bsdf></shape>"""


@pytest.mark.slow
def test_blob_hiding_its_own_lobe(variant, tmp_path):
    """Where one lobe of a blob hides another the slot seen does not change: the lines tell
    the lobes apart by their dominant centre. d (right half's red sum) / d (front centre's x)
    against central differences (measured without the lobes told apart: the term 57 % of the
    differences' over the frame). Single pixels there are not checked: where the front lobe's
    shadow falls on the back one, the receiving surface moves with the front centre too (its
    field), a share the term leaves out (docs/method.md §6)."""
    key = "links1_whitted.obj.centers"
    sc = load(tmp_path, BLOB_LOBES)
    ad, ad_se = mean_se([forward(sc, key, s)[:, W // 2:, 0].sum() for s in AD_SEEDS])
    fd, fd_se = mean_se([finite_differences(sc, key, s)[:, W // 2:, 0].sum() for s in FD_SEEDS])
    assert_agree("blob lobes: right half", ad, ad_se, fd, fd_se)


SHADOW_CAMERA = perspective("0, 5, 5", "0, 0, 0", fov=35, width=W, height=H, spp=4)
FLOOR = ('<shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>'
         '</transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>')
def point_light(x, y, z, L1):
    """A ``links1_point`` ``lp`` at ``(x, y, z)`` of ``L1``, falling off with the squared distance."""
    return (f'<emitter type="links1_point" id="lp"><point name="position" x="{x}" y="{y}" z="{z}"/>'
            f'<rgb name="L1" value="{L1}"/><string name="falloff" value="inverse_square"/></emitter>')


SHADOW_LIGHT = point_light(0.5, 4, 0.5, 12)
OCCLUDERS = {
    "quadric": ("links1_whitted.obj.to_world", f"""<shape type="links1_quadric" id="obj"><string name="kind" value="sphere"/>
        <transform name="to_world"><scale value="0.5"/><translate x="0.3" y="1" z="-0.5"/></transform>{PHONG}</shape>"""),
    "mitsuba_sphere": ("obj.to_world", f"""<shape type="sphere" id="obj"><point name="center" x="0.3" y="1" z="-0.5"/>
        <float name="radius" value="0.5"/>{PHONG}</shape>"""),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", ["quadric", "mitsuba_sphere", "light"])
def test_shadow_edges_against_finite_differences(variant, tmp_path, case):
    """A sphere (constant colour) over a diffuse floor under a ``links1_point`` light: d Σ ramp ·
    frame / dθ (the ramp ``(x − W/2)/(W/2)`` on red: a sideways move changes it) for the
    occluder's x-translation (its outline and its shadow's edge move) and for the light's x
    (its shadow's edge moves, and the floor's shading: the interior term), against central
    differences of 1024-spp frames. Without the term the first two are 0 and the light's is
    8 % short (measured: 6.29 against 6.84)."""
    import drjit as dr
    import mitsuba as mi
    key, body = OCCLUDERS["quadric" if case == "light" else case]
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(1, projective=True) + SHADOW_CAMERA, FLOOR, body, SHADOW_LIGHT))
    import links1_mitsuba as lm
    sc = lm.load_file(str(path))
    if case == "light":
        key = "lp.position"
        x0, y0, z0 = np.array(mi.traverse(sc)[key], dtype=np.float64).ravel()
        make = lambda th: mi.Point3f(th + float(x0), float(y0), float(z0))   # noqa: E731
    else:
        make = mover(mi, dr, mi.traverse(sc), key)
    ramp = np.zeros((H, W, 3))
    ramp[..., 0] = (np.arange(W) - W / 2) / (W / 2)
    ads = [float((forward(sc, key, s, make=make) * ramp).sum()) for s in AD_SEEDS]
    fds = [float((finite_differences(sc, key, s, make=make) * ramp).sum()) for s in FD_SEEDS]
    assert_agree(f"{case}: ramp", *mean_se(ads), *mean_se(fds))


def _mitsuba_scene(mi, shape, emitter, tmp_path=None):
    """A Mitsuba sphere or cube (a mesh) before a black background: an area emitter (the frame
    changes at its outline alone) or diffuse under a point light (its shading changes too)."""
    t = mi.ScalarTransform4f()
    if shape == "sphere":
        obj = {"type": "sphere", "to_world": t.translate([0.2, 0.1, 0.0])}
    else:
        obj = {"type": "ply", "filename": cube_ply(tmp_path / "cube.ply"), "face_normals": True,
               "to_world": t.translate([0.1, 0.0, 0.0]).rotate([1, 0, 0], 20).rotate([0, 1, 0], 35).scale(0.8)}
    obj["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
    d = {"type": "scene", "obj": obj,
         "sensor": {"type": "perspective", "fov": 30, "to_world": t.look_at(origin=[0, 0, 6], target=[0, 0, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}}}}
    if emitter:
        obj["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": list(AMBIENT)}}
    else:
        d["light"] = {"type": "point", "position": [2, 4, 3], "intensity": {"type": "rgb", "value": [30, 30, 30]}}
    return mi.load_dict(d)


@pytest.mark.slow
@pytest.mark.parametrize("shape, emitter", [("sphere", True), ("sphere", False), ("cube", True)],
                         ids=["sphere_area_emitter", "sphere_diffuse_point_light", "cube_area_emitter"])
def test_mitsuba_shapes_against_direct_projective(variant, tmp_path, shape, emitter):
    """d (right half's red sum) / d x-translation of a Mitsuba sphere (its ``to_world``) and a
    cube (its vertices): links1_whitted with ``projective`` against Mitsuba's
    ``direct_projective`` on the same scene."""
    import mitsuba as mi
    if not variant.startswith(("llvm_ad", "cuda_ad")):
        pytest.skip("direct_projective needs an AD variant")
    sc = _mitsuba_scene(mi, shape, emitter, tmp_path)
    key = "obj.to_world" if shape == "sphere" else "obj.vertex_positions"
    weight = np.zeros((H, W, 3))
    weight[:, W // 2:, 0] = 1.0
    ours = mi.load_dict({"type": "links1_whitted", "projective": True, "max_depth": 1})
    theirs = mi.load_dict({"type": "direct_projective", "sppi": 0})
    a, a_se = mean_se([reverse(sc, key, weight, s, integrator=ours) for s in AD_SEEDS])
    b, b_se = mean_se([reverse(sc, key, weight, s, integrator=theirs) for s in AD_SEEDS])
    assert_agree("links1 vs direct_projective", a, a_se, b, b_se)


def test_forward_equals_reverse(variant, tmp_path):
    """The term is attached through the velocity's graph: forward and reverse mode give the
    same d (weighted sum) / dθ at the same samples (to float32 rounding)."""
    key, body = SHAPES["quadric"]
    sc = load(tmp_path, body)
    rng = np.random.default_rng(3)
    weight = rng.uniform(-1, 1, (H, W, 3))
    fwd = float((forward(sc, key, 5, spp=4) * weight).sum())
    rev = reverse(sc, key, weight, 5, spp=4)
    assert abs(fwd) > 1.0
    assert rev == pytest.approx(fwd, rel=1e-4, abs=1e-4)


def test_blocks_do_not_change_the_term(variant, tmp_path, monkeypatch):
    """Reverse mode renders the frame in blocks of rows: the term's lines are drawn from the
    film's sample ids and its pixels chosen by their own neighbourhood, so six blocks give the
    one block's gradient (to the order of the sums): the derivative pass's six blocks with the
    term over the frame apart (its own blocks, larger), and with six blocks of the term too."""
    import links1_mitsuba.boundary as boundary
    import links1_mitsuba.gradients as gradients
    key, body = SHAPES["quadric"]
    sc = load(tmp_path, body)
    weight = np.random.default_rng(5).uniform(0, 1, (H, W, 3))
    one = reverse(sc, key, weight, 3, spp=4)
    monkeypatch.setattr(gradients, "AD_BLOCK_LANES", 4 * W * 4)   # four rows a block
    assert len(gradients.row_blocks((0, 0, W, H), (W, H), 0, 4)) == 6
    six = reverse(sc, key, weight, 3, spp=4)
    monkeypatch.setattr(boundary, "BLOCK_LANES", 4 * W * 4)
    six_apart = reverse(sc, key, weight, 3, spp=4)
    assert abs(one) > 1.0
    assert six == pytest.approx(one, rel=1e-5)
    assert six_apart == pytest.approx(one, rel=1e-5)


def test_kernels_compiled_once(variant, tmp_path):
    """The term's kernels are compiled in the first frames only: more reverse-mode frames, other
    seeds, compile none. (Its device arrays made from numpy are 64-byte aligned: a kernel that
    reads numpy's memory is compiled again for each alignment it meets, and the term's
    bisection was, in most frames.)"""
    import drjit as dr
    key, body = SHAPES["quadric"]
    sc = load(tmp_path, body)
    weight = np.random.default_rng(7).uniform(0, 1, (H, W, 3))
    for s in range(2):
        reverse(sc, key, weight, s, spp=4)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        for s in range(2, 14):
            assert reverse(sc, key, weight, s, spp=4) != 0.0
        kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(kernels) > 6
    assert [k["operation_count"] for k in kernels if not k["cache_hit"]] == []


def _blob_and_ball_over_floor(tmp_path):
    """A blob and a quadric over a floor, lit (outlines, shadow edges on the floor and on the
    blob), ``projective``."""
    import links1_mitsuba as lm
    blob = SHAPES["blob"][1].replace('id="obj"', 'id="blob"')
    ball = OCCLUDERS["quadric"][1].replace('id="obj"', 'id="ball"')
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(1, projective=True) + SHADOW_CAMERA, FLOOR, blob, ball, SHADOW_LIGHT))
    return lm.load_file(str(path))


@pytest.mark.slow
def test_frozen_stages_replay_the_traced_crossings(variant, tmp_path, monkeypatch):
    """The term's stages (the corners, the points of the lines and their intervals' kinds, the
    bisection, what the crossings' ends see with the outline and screen gradient there) are
    frozen launches (``Launches.frozen_stage``): over an optimisation's loop of moves of a
    blob and a quadric over a floor (outlines, shadow edges on the floor and on the blob) each
    frame's crossings (pixel, weight, grazing point, normal, kind) are those the stages give
    traced as they are (``stage=None``), bit for bit, while the stages are recorded once and
    replayed."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import boundary
    sc = _blob_and_ball_over_floor(tmp_path)
    real, compared = boundary._crossings, []

    def both(trace_points, scene_, P, sensor, win, spp, seed, stage):
        frozen = real(trace_points, scene_, P, sensor, win, spp, seed, stage)
        traced = real(trace_points, scene_, P, sensor, win, spp, seed, lambda fn, *a: fn(P, scene_, *a))
        assert (frozen is None) == (traced is None)
        for k in ("pixel", "weight", "q", "m", "slot", "valid", "part", "light") if frozen is not None else ():
            a, b = frozen[k], traced[k]
            for c in range(dr.size_v(a)) if dr.size_v(a) > 1 else [None]:
                assert np.array_equal(np.array(a if c is None else a[c]), np.array(b if c is None else b[c])), k
        compared.append((0, 0) if frozen is None else (int(np.count_nonzero(np.array(frozen["valid"]))),
                                                       int(np.count_nonzero(np.array(frozen["light"]) >= 0))))
        return frozen
    monkeypatch.setattr(boundary, "_crossings", both)
    params = mi.traverse(sc)
    B, Q = "links1_whitted.blob.centers", "links1_whitted.ball.to_world"
    centres = np.array(params[B], dtype=np.float64).reshape(3, -1)
    for it in range(4):
        centres[0] += 0.03
        params[B] = mi.Point3f(*[mi.Float(c) for c in centres])
        params[Q] = mi.Transform4f().translate(mi.Vector3f(-0.02, 0.01, 0.0)) @ mi.Transform4f(params[Q])
        dr.enable_grad(params[B])
        params.update()
        img = mi.render(sc, params, seed=it)
        dr.backward(dr.sum(img, axis=None))
        if it == 1:
            stages = dict(sc.integrator().engine.launches.stage_launches)
            recorded = {f: s.n_recordings for f, s in stages.items()}
    assert len(compared) == 4 and all(c[0] and c[1] for c in compared)   # outlines and shadow edges
    now = sc.integrator().engine.launches.stage_launches
    # the same stage launches, at most one more recording each since (freeze's layout change, never one an update)
    assert now == stages and all(s.n_recordings <= recorded[f] + 1 for f, s in now.items()), (recorded, {f.__name__: s.n_recordings for f, s in now.items()})
    assert set(f.__name__ for f in stages) == {"_seen_slots", "_line_kinds", "_bisected", "_edges"}


@pytest.mark.slow
def test_ends_in_one_kernel_are_the_kernel_by_kernel_crossings(variant, tmp_path, monkeypatch):
    """The ends' values made in one kernel before they are put back in order
    (``boundary.EDGES_ONE_KERNEL``) are those each gather makes alone, bit for bit (a blob and a
    quadric over a floor: outlines and shadow edges)."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import boundary
    sc = _blob_and_ball_over_floor(tmp_path)
    real, compared = boundary._crossings, []

    def both(trace_points, scene_, P, sensor, win, spp, seed, stage):
        got = []
        for one in (True, False):
            monkeypatch.setattr(boundary, "EDGES_ONE_KERNEL", one)
            got.append(real(trace_points, scene_, P, sensor, win, spp, seed, lambda fn, *a: fn(P, scene_, *a)))
        for k in ("pixel", "weight", "q", "m", "slot", "valid", "part", "light"):
            a, b = got[0][k], got[1][k]
            for c in range(dr.size_v(a)) if dr.size_v(a) > 1 else [None]:
                assert np.array_equal(np.array(a if c is None else a[c]), np.array(b if c is None else b[c])), k
        compared.append((int(np.count_nonzero(np.array(got[0]["valid"]))),
                         int(np.count_nonzero(np.array(got[0]["light"]) >= 0))))
        return got[0]
    monkeypatch.setattr(boundary, "_crossings", both)
    params = mi.traverse(sc)
    dr.enable_grad(params["links1_whitted.blob.centers"])
    params.update()
    dr.backward(dr.sum(mi.render(sc, params, seed=0), axis=None))
    assert len(compared) == 1 and compared[0][0] and compared[0][1]   # outlines and shadow edges


def test_nothing_added_where_no_outline_moves(variant, tmp_path):
    """With no shape's geometry attached (a light's position), ``projective`` changes neither
    the frame nor the derivative, bit for bit; without the option a moving outline's term is
    absent (the derivative of this constant-colour sphere is 0 everywhere)."""
    import drjit as dr
    import mitsuba as mi
    key, body = SHAPES["quadric"]
    out = {}
    for proj in (False, True):
        sc = load(tmp_path, body, projective=proj)
        params = mi.traverse(sc)
        dr.enable_grad(params["lp.position"])
        params.update()
        dr.set_grad(params["lp.position"], mi.Point3f(1.0, 0.0, 0.0))
        img = mi.render(sc, params, seed=1, seed_grad=2, spp=4)
        dr.forward_to(img)
        out[proj] = (np.array(img), np.array(dr.grad(img)))
        if not proj:
            out["geometry"] = forward(load(tmp_path, body, projective=False), key, 2, spp=4)
    np.testing.assert_array_equal(out[True][0], out[False][0])
    np.testing.assert_array_equal(out[True][1], out[False][1])
    assert not np.any(out["geometry"])


def test_other_filters_refused(variant, tmp_path):
    """The term integrates over pixel squares: a gaussian filter is refused, naming the fix."""
    import drjit as dr
    import mitsuba as mi
    key, body = SHAPES["quadric"]
    sc = load(tmp_path, body, rfilter="gaussian")
    params = mi.traverse(sc)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(sc, params, seed=1, spp=1)
    with pytest.raises(NotImplementedError, match="box reconstruction filter"):
        dr.backward(dr.sum(img, axis=None))


#: lit from the side and a little behind: the Phong highlight (eq. 3.11) does not vanish where
#: a surface turns away from the light (the mirror of L leans toward the viewer), so the frame
#: jumps there; most of the lit side is wider than a pixel (where a lit rim is thinner than
#: 1/7 pixel the term finds its outline alone: docs/method.md §6, bias (3))
BACK_LIGHT = point_light(-4, 0.5, -0.7, 20)
SHINY = ('<bsdf type="links1_phong"><rgb name="diffuse" value="0.4, 0.3, 0.2"/><rgb name="specular" value="0.8"/>'
         '<float name="exponent" value="1"/></bsdf>')
TERMINATORS = {
    # the light moves: the terminator alone (the outline stays)
    "quadric_light": ("lp.position", f"""<shape type="links1_quadric" id="obj"><string name="kind" value="sphere"/>
        <transform name="to_world"><scale value="1.2"/><translate x="0.1"/></transform>{SHINY}</shape>"""),
    # a lobe moves: the outline and the terminator
    "blob_centre": ("links1_whitted.obj.centers", f"""<shape type="links1_blob" id="obj">
        <string name="centers" value="-0.5 0 0 1 0.8,  0.45 0.35 0.3 1 0.7"/><float name="threshold" value="0.5"/>
        {SHINY}</shape>"""),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", sorted(TERMINATORS))
def test_terminators_against_finite_differences(variant, tmp_path, case):
    """Shapes lit from behind and to the side: where their side turns from the light the
    highlight is cut (a jump in the frame, ``boundary.UNLIT``). d Σ red / dθ for the light's x
    (the terminator moves, the outline does not) and for a blob centre's x (both move) against
    central differences of 1024-spp frames; the interior term alone (no visibility term)
    misses them by more than the error bars (measured: 121 and 290 against 83 and 3)."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    key, body = TERMINATORS[case]
    red = np.zeros((H, W, 3))
    red[..., 0] = 1.0
    out = {}
    for projective in (True, False):
        path = tmp_path / f"scene_{projective}.xml"
        path.write_text(scene(whitted(1, projective=projective) + CAMERA, body, BACK_LIGHT))
        sc = lm.load_file(str(path))
        if key == "lp.position":
            x0, y0, z0 = np.array(mi.traverse(sc)[key], dtype=np.float64).ravel()
            make = lambda th: mi.Point3f(th + float(x0), float(y0), float(z0))   # noqa: E731
        else:
            make = mover(mi, dr, mi.traverse(sc), key)
        out[projective] = mean_se([float((forward(sc, key, s, make=make) * red).sum()) for s in AD_SEEDS])
        if projective:
            fd = mean_se([float((finite_differences(sc, key, s, make=make) * red).sum()) for s in FD_SEEDS])
    assert_agree(f"{case}: red", *out[True], *fd)
    interior, interior_se = out[False]
    assert abs(interior - fd[0]) > 5 * np.hypot(interior_se, fd[1]), \
        f"{case}: the interior term alone ({interior:.4g}) already agrees with FD ({fd[0]:.4g}): no terminator tested"


def _ambient(rgb):
    return (f'<bsdf type="links1_phong"><rgb name="ambient" value="{rgb}"/><rgb name="diffuse" value="0"/>'
            '<rgb name="specular" value="0"/></bsdf>')


#: a ball of constant colour sunk into the floor: a one-centre blob (its centre's y moves), a
#: links1 quadric sphere (its translation's y)
SUNK = {
    "blob": ("links1_whitted.obj.centers", '<shape type="links1_blob" id="obj"><string name="centers" '
             'value="0.1 0.25 0 1 0.8"/><float name="threshold" value="0.5"/>{bsdf}</shape>'),
    "quadric": ("links1_whitted.obj.to_world", '<shape type="links1_quadric" id="obj"><string name="kind" '
                'value="sphere"/><transform name="to_world"><translate x="0.1" y="0.25"/></transform>{bsdf}</shape>'),
}


@pytest.mark.slow
@pytest.mark.parametrize("shape", sorted(SUNK))
def test_sunk_into_a_floor_against_finite_differences(variant, tmp_path, shape):
    """A ball of constant colour sunk into a floor of another constant colour: moving it up
    moves its outline against the black above and the curve where it cuts the floor
    (``boundary.CUT``), nothing else (without the term every derivative is 0). d Σ red / dθ over
    the rows where the floor shows (the cut's) and over the frame, for the ball's y, against
    central differences of 1024-spp frames."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    floor = ('<shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/>'
             f'<rotate x="1" angle="-90"/></transform>{_ambient("0.1, 0.3, 0.7")}</shape>')
    key, ball = SUNK[shape]
    cam = perspective("0, 1.6, 5", "0, 0.3, 0", fov=40, width=W, height=H, spp=4)
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(1, projective=True) + cam, floor, ball.format(bsdf=_ambient("0.9, 0.6, 0.2"))))
    sc = lm.load_file(str(path))
    if shape == "blob":
        arr = np.array(mi.traverse(sc)[key], dtype=np.float64).reshape(3, -1)
        make = lambda th: mi.Point3f(mi.Float(arr[0]), mi.Float(arr[1]) + th, mi.Float(arr[2]))   # noqa: E731
    else:
        base = mi.Transform4f(mi.traverse(sc)[key])
        make = lambda th: mi.Transform4f().translate(mi.Vector3f(0.0, th, 0.0)) @ base   # noqa: E731
    ads = [forward(sc, key, s, make=make) for s in AD_SEEDS]
    fds = [finite_differences(sc, key, s, make=make) for s in FD_SEEDS]
    frame = np.array(mi.render(sc, seed=0, spp=64))
    floor_rows = (frame[..., 2] > 0.35).any(axis=1)   # rows where the floor shows
    for what, rows in (("floor rows", floor_rows), ("frame", np.ones(H, bool))):
        assert_agree(f"{shape} in floor, {what}", *mean_se([float(a[rows, :, 0].sum()) for a in ads]),
                     *mean_se([float(f[rows, :, 0].sum()) for f in fds]))


@pytest.mark.slow
def test_lights_followed_once_a_surface_takes_light(variant, tmp_path):
    """Where no surface takes light (every one a ``links1_phong`` of ambient alone) the term
    follows no light's shadows; once a parameter gives the floor a diffuse colour, the term's
    recorded stages follow them again: the derivative is then the one of a scene loaded with
    that floor (same seeds: the same values)."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    key, ball = OCCLUDERS["quadric"]

    def load_with(diffuse):
        floor = ('<shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/>'
                 '<rotate x="1" angle="-90"/></transform><bsdf type="links1_phong">'
                 f'<rgb name="ambient" value="0.1"/><rgb name="diffuse" value="{diffuse}"/>'
                 '<rgb name="specular" value="0"/></bsdf></shape>')
        path = tmp_path / f"scene_{diffuse}.xml"
        path.write_text(scene(whitted(1, projective=True) + SHADOW_CAMERA, floor, ball, SHADOW_LIGHT))
        return lm.load_file(str(path))
    changed = load_with(0)
    forward(changed, key, 0, spp=4)   # (recorded without lights)
    params = mi.traverse(changed)
    params["floor.bsdf.diffuse.value"] = mi.Color3f(0.6)
    params.update()
    fresh = load_with(0.6)
    a, b = forward(changed, key, 1, spp=4), forward(fresh, key, 1, spp=4)
    dark = forward(load_with(0), key, 1, spp=4)
    assert np.abs(b - dark).max() > 1e-2          # the floor's shadow edge: a share of its own
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
