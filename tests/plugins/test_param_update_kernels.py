"""``params.update()`` of a links1 shape's values replays the same kernels.

``links1_blob`` and ``links1_quadric`` hand their changeable constants (a blob's centres,
weights, radii, threshold; a quadric's inverse transform and clip offsets) to the kernels as a
Dr.Jit table they gather from (``BlobSpec.tables()["values"]``), not as literals. So a frame
after ``params.update()`` with new values (the same count) launches only kernels already
launched before it: every kernel Dr.Jit reports (``dr.kernel_history()``) has the code of one
launched after the previous update (less alignment: :func:`code`), and the frozen launch is
not recorded again. With literals each
new value makes new kernel code (another hash; ~100 kernels compiled per inverse-rendering
iteration of the 6-centre blob before this change).

And the frame after the update is the frame of the file with those values, bit for bit: the
new float32 values (what ``traverse`` hands out) written in a file are read back as the same
numbers, and the values not changed keep the file's float64 (geometry._keep)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from tests.scenes import perspective, whitted

pytestmark = pytest.mark.mitsuba

CENTRES = np.array([[-0.625, 1.375, 0, 1, 0.75], [0.5, 1.5, 0.2, 1, 0.6], [0, 2.0, -0.2, 0.8, 0.6],
                    [0, 1.25, 0.3, 0.9, 0.5], [0.875, 1.25, -0.25, 0.75, 0.5], [0.1, 1.6, 0.4, 0.5, 0.4]])


def head(max_depth, origin, target, w, h):
    """The scenes' start: the integrator, a camera (spp 1, box filter) and a floor."""
    camera = perspective(origin, target, fov=40, width=w, height=h)
    return '<scene version="3.0.0">' + whitted(max_depth) + camera + """
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.6, 0.5, 0.4"/></bsdf></shape>"""


def scene_xml(centres, translate="0.2, 1.4, 0.3"):
    """A 6-centre blob (unrolled field sum: fewer than LIST_MIN_CENTRES centres), a clipped
    quadric and a floor, two delta lights, spp 1 with a box filter. No mirror (the ray tree's
    counts changing with the geometry: :func:`test_ray_tree_counts_changing_with_geometry_replay_the_same_kernels`)."""
    c = ", ".join(" ".join(repr(float(x)) for x in row) for row in centres)
    x, y, z = translate.split(",")
    return head(2, "0, 2.6, 6", "0.1, 1.4, 0", 24, 20) + f"""
  <shape type="links1_blob" id="blob"><string name="centers" value="{c}"/><float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.5, 0.4, 0.3"/><rgb name="specular" value="0.3"/>
      <float name="exponent" value="10"/></bsdf></shape>
  <shape type="links1_quadric" id="can"><string name="kind" value="cylinder"/>
    <vector name="clip_0" x="0" y="0" z="1"/><float name="clip_0_offset" value="0.5"/>
    <vector name="clip_1" x="0" y="0" z="-1"/><float name="clip_1_offset" value="0.5"/>
    <boolean name="capped" value="true"/>
    <transform name="to_world"><rotate x="1" angle="-60"/><scale value="0.4"/>
      <translate x="{x}" y="{y}" z="{z}"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.3, 0.5, 0.4"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.6"/>
    <rgb name="L2" value="0.4"/><string name="falloff" value="inverse_square"/></emitter>
  <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="4"/><rgb name="intensity" value="6"/></emitter>
</scene>"""


def code(k):
    """A kernel's code less what depends on where its buffers lie: Dr.Jit specialises a
    kernel on whether an array is 64-byte aligned (``align 64`` or ``align 1`` on its loads,
    the alignment argument of masked gathers and scatters, hence another hash); seen on the
    derivative pass's small scatter kernels, whose arrays move between frames."""
    ir = k["ir"].getvalue()
    ir = re.sub(r"drjit_[0-9a-f]+", "drjit_", ir)
    ir = re.sub(r"align \d+", "align", ir)
    return re.sub(r"i32 \d+, (<\d+ x i1>)", r"i32 A, \1", ir)


def collect_earlier_scenes():
    """The scenes of earlier tests freed now, not between two frames a test compares: the
    kernels of a Dr.Jit call through the shapes or BSDFs depend on how many instances of a
    class are alive (a call with one target is inlined), so a collection in between gives a
    frame other code."""
    import gc
    gc.collect()


def launched(fn):
    """(``fn()`` as numpy, the code (:func:`code`) of the kernels it compiled or found in a
    cache; the replays of a frozen launch report none)."""
    import drjit as dr
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()                          # clear
        out = fn()
        out = np.array(out)
        dr.sync_thread()
        hist = dr.kernel_history()
    return out, {code(k) for k in hist if "ir" in k}


def derivative_pass(scene, params, keys):
    """A frame with gradients on ``params[keys]`` and its reverse pass (gradients.py) on the
    pixel sum: the gradients, as numpy."""
    import drjit as dr
    import mitsuba as mi
    for k in keys:
        dr.enable_grad(params[k])
    params.update()
    img = mi.render(scene, params, seed=0)
    dr.backward(dr.sum(img, axis=None))
    g = [np.array(dr.grad(params[k])) for k in keys]
    for k in keys:
        dr.disable_grad(params[k])
    return g


@pytest.mark.slow
def test_new_blob_and_quadric_values_replay_the_same_kernels(variant):
    import drjit as dr
    import mitsuba as mi

    import links1_mitsuba as lm
    scene = lm.load_string(scene_xml(CENTRES, "-1.2, 0.6, 1.0"))
    integ = scene.integrator()
    params = mi.traverse(scene)
    C, W = "links1_whitted.blob.centers", "links1_whitted.blob.weights"
    Q = "links1_whitted.can.to_world"

    def primal():
        return mi.render(scene, seed=0)

    def derivative():
        # an inverse-rendering step's derivative pass (gradients.py), on the centres and weights
        return derivative_pass(scene, params, [C, W])[1]

    rng = np.random.default_rng(7)

    def update():
        """New centres, weights and quadric transform (the same counts): the new values."""
        cen = (CENTRES[:, :3] + rng.uniform(-0.05, 0.05, (6, 3))).astype(np.float32)
        wts = (CENTRES[:, 3] * rng.uniform(0.9, 1.1, 6)).astype(np.float32)
        params[C] = mi.Point3f(*[mi.Float(cen[:, k]) for k in range(3)])
        params[W] = mi.Float(wts)
        params[Q] = mi.Transform4f().translate(mi.Vector3f(*map(float, rng.uniform(-0.1, 0.1, 3)))) @ mi.Transform4f(params[Q])
        params.update()
        return cen, wts

    # a first update: the kernels of an update (the tables' build) and of the frame after it
    update()
    before, seen = launched(primal)
    recordings = integ.info()["recordings"]
    g0, seen_d = launched(derivative)
    assert np.any(np.asarray(g0) != 0)               # the pass differentiates the blob

    # three more updates, each frame with no new kernel code; the frozen launch replays: Dr.Jit's
    # freeze may record once more when its inputs' layout changes (a literal made opaque, its
    # auto_opaque; seen in some orders of the suite's tests), never once an update
    for _ in range(3):
        cen, wts = update()
        after, now = launched(primal)
        assert not np.array_equal(after, before)     # the frame shows the new values
        assert now <= seen, f"{len(now - seen)} kernels with new code after params.update()"
        _, now_d = launched(derivative)
        assert now_d <= seen_d, f"{len(now_d - seen_d)} derivative-pass kernels with new code"
    assert integ.info()["recordings"] <= recordings + 1, (integ.info()["recordings"], recordings)

    # the same frame as a fresh load of the file with the new values
    new = CENTRES.copy()
    new[:, :3] = cen
    new[:, 3] = wts
    m = np.array(mi.Transform4f(params[Q]).matrix, dtype=np.float64).reshape(4, 4)
    fresh = lm.load_string(scene_xml(new, "-1.2, 0.6, 1.0"))
    fp = mi.traverse(fresh)
    fp[Q] = mi.Transform4f(m.tolist())                # the same float32 matrix as the updated scene's
    fp.update()
    assert np.array_equal(np.array(mi.render(fresh, seed=0)), after)


def _fresh_frame_and_points(centres, m, xs, ys, keys):
    """The frame and the point launch's radiance of a fresh load of :func:`scene_xml` with
    ``centres`` and the can's float32 matrix ``m`` (given before any frame: a whole build)."""
    import mitsuba as mi

    import links1_mitsuba as lm
    fresh = lm.load_string(scene_xml(centres))
    fp = mi.traverse(fresh)
    fp["links1_whitted.can.to_world"] = mi.Transform4f(m.tolist())
    fp.update()
    img = np.array(mi.render(fresh, seed=0))
    assert fresh.integrator().info()["value_updates"] == 0
    return img, fresh.integrator().engine.trace_points(fresh, xs, ys, keys)[0]


def test_geometry_updates_replay_the_recorded_launches(variant):
    """An optimisation's loop (new centres, weights and quadric transform, then a frame and a
    point launch, four times): the frozen window and point launches recorded in the first
    iterations replay in the later ones (the same functions, no new recording: their kernels
    take the geometry from the shapes' tables, and nothing they hold as a literal changed,
    ``launch.literal_key``), and the last frame and points are those of a fresh load of the
    last geometry, bit for bit."""
    import mitsuba as mi

    import links1_mitsuba as lm
    scene = lm.load_string(scene_xml(CENTRES))
    integ = scene.integrator()
    params = mi.traverse(scene)
    C, W, Q = "links1_whitted.blob.centers", "links1_whitted.blob.weights", "links1_whitted.can.to_world"
    rng = np.random.default_rng(11)
    xs, ys = rng.uniform(0, 1, 64), rng.uniform(0, 1, 64)
    keys = np.arange(64, dtype=np.uint32)
    frames, new = [], CENTRES.copy()
    for it in range(5):
        if it == 2:      # recorded by now (the first frames may record again as literals turn opaque)
            launches = integ.info()["launch"], integ.info()["point_launch"]
            recorded = integ.info()["recordings"], integ.info()["point_recordings"]
        new[:, :3] = (CENTRES[:, :3] + rng.uniform(-0.05, 0.05, (6, 3))).astype(np.float32)
        new[:, 3] = (CENTRES[:, 3] * rng.uniform(0.9, 1.1, 6)).astype(np.float32)
        params[C] = mi.Point3f(*[mi.Float(new[:, k]) for k in range(3)])
        params[W] = mi.Float(new[:, 3])
        params[Q] = mi.Transform4f().translate(mi.Vector3f(*map(float, rng.uniform(-0.05, 0.05, 3)))) \
            @ mi.Transform4f(params[Q])
        params.update()
        frames.append(np.array(mi.render(scene, seed=0)))
        points = integ.engine.trace_points(scene, xs, ys, keys)[0]
    assert integ.info()["value_updates"] == 4 and integ.info()["scene_builds"] == 1   # (the first: a build)
    assert (integ.info()["launch"], integ.info()["point_launch"]) == launches and None not in launches
    # (at most one more recording each in the three updates since: freeze's layout change, never one an update)
    now = integ.info()["recordings"], integ.info()["point_recordings"]
    assert all(r <= r0 + 1 for r, r0 in zip(now, recorded)), (now, recorded)
    assert not np.array_equal(frames[-2], frames[-1])     # the frames show the new geometry
    m = np.array(mi.Transform4f(params[Q]).matrix, dtype=np.float64).reshape(4, 4)
    img, pts = _fresh_frame_and_points(new, m, xs, ys, keys)
    assert np.array_equal(frames[-1], img)
    assert np.array_equal(points, pts)


@pytest.mark.slow
def test_geometry_update_that_changes_a_literal_records_anew(variant):
    """A move that changes what the kernels hold as literals records the launches anew: the
    can under a BVH (``bvh_min`` 1; no light or eye buffers, whose tables' sizes change too)
    moved sideways, so the BVH's root box (literals of its walk, bvh.py) is another. The
    frame and points are then those of a fresh load of the moved can, bit for bit (a replay
    with the old box misses the can where it left the box: not the fresh frame, tried)."""
    import mitsuba as mi

    import links1_mitsuba as lm
    from links1_mitsuba.tuning import Tuning
    xml = scene_xml(CENTRES)
    xml = xml[:xml.index('  <shape type="links1_blob"')] + xml[xml.index('  <shape type="links1_quadric"'):]
    scene = lm.load_string(xml)
    integ = scene.integrator()
    tuned = Tuning(bvh_min=1, light_buffer=False, eye_buffer=False)
    integ.tuning = tuned
    params = mi.traverse(scene)
    Q = "links1_whitted.can.to_world"
    xs, ys = np.linspace(0.05, 0.95, 16), np.full(16, 0.45)
    keys = np.arange(16, dtype=np.uint32)

    def move(dx):
        params[Q] = mi.Transform4f().translate(mi.Vector3f(dx, 0.0, 0.0)) @ mi.Transform4f(params[Q])
        params.update()
        return np.array(mi.render(scene, seed=0)), integ.engine.trace_points(scene, xs, ys, keys)[0]

    move(0.01)
    old_img, old_pts = move(0.01)
    assert integ.info()["tables"].base.bvh is not None and integ.info()["tables"].eye_buf is None
    launches = integ.info()["launch"], integ.info()["point_launch"]
    img, pts = move(0.3)
    assert integ.info()["launch"] is not launches[0] and integ.info()["point_launch"] is not launches[1]
    m = np.array(mi.Transform4f(params[Q]).matrix, dtype=np.float64).reshape(4, 4)
    fresh = lm.load_string(xml)
    fresh.integrator().tuning = tuned
    fp = mi.traverse(fresh)
    fp[Q] = mi.Transform4f(m.tolist())
    fp.update()
    assert np.array_equal(img, np.array(mi.render(fresh, seed=0)))
    assert np.array_equal(pts, fresh.integrator().engine.trace_points(fresh, xs, ys, keys)[0])
    assert not np.array_equal(pts, old_pts) and not np.array_equal(img, old_img)


MIRROR_GLASS = head(4, "0, 2.0, 6", "0, 1.0, 0", 32, 24) + """
  <shape type="links1_quadric" id="mirror"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.7"/><translate x="-0.9" y="1" z="0"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.1"/><rgb name="reflectance" value="0.8"/></bsdf></shape>
  <shape type="links1_quadric" id="glass"><string name="kind" value="sphere"/>
    <transform name="to_world"><scale value="0.6"/><translate x="0.9" y="0.9" z="0.5"/></transform>
    <bsdf type="links1_phong"><rgb name="diffuse" value="0.05"/><rgb name="reflectance" value="0.1"/>
      <rgb name="transmittance" value="0.85"/><float name="ior" value="1.5"/></bsdf></shape>
  <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.6"/>
    <rgb name="L2" value="0.4"/><string name="falloff" value="inverse_square"/></emitter>
</scene>"""


def test_ray_tree_counts_changing_with_geometry_replay_the_same_kernels(variant, monkeypatch):
    """The derivative pass joins each level's mirror and refraction rays (raytree_ad.py ``cat``)
    with their counts as opaque values: moving a sphere changes the counts, not the kernels."""
    import drjit as dr
    import mitsuba as mi

    import links1_mitsuba as lm
    from links1_mitsuba import raytree_ad
    counts = []
    real_cat = raytree_ad.cat

    def recording_cat(a, b, na, nb):
        counts.append((na, nb))
        return real_cat(a, b, na, nb)
    monkeypatch.setattr(raytree_ad, "cat", recording_cat)
    collect_earlier_scenes()
    scene = lm.load_string(MIRROR_GLASS)
    params = mi.traverse(scene)
    K, M = "links1_whitted.glass.bsdf.diffuse.value", "links1_whitted.mirror.to_world"

    def derivative():
        return derivative_pass(scene, params, [K])[0]

    def move(dx):
        params[M] = mi.Transform4f().translate(mi.Vector3f(dx, 0, 0)) @ mi.Transform4f(params[M])
        params.update()

    move(0.05)
    g0, seen = launched(derivative)
    first, counts[:] = list(counts), []
    assert np.all(np.asarray(g0) > 0)                 # the glass sphere's diffuse shows
    move(0.3)                                         # the mirror sphere grows in the frame
    _, now = launched(derivative)
    assert len(counts) == len(first) and counts != first, (first, counts)   # new counts, same levels
    assert now <= seen, f"{len(now - seen)} derivative-pass kernels with new code after the counts changed"


@pytest.mark.slow
def test_blob_reverse_pass_kernels_do_not_grow_with_its_parameters(variant):
    """Reverse mode through the blob (geometry.py ``_blob_terms``): its centres and weights are
    gathered at every lane, so their derivatives are scatter-adds that share the pass's
    kernels. Gathered as width-1 values, each of the 24 values (18 centre coordinates, 6
    weights) had a horizontal sum as its derivative, a kernel of its own recomputing the field:
    a frame and its reverse pass on the centres and weights launched 4× the kernels of one on
    the weights alone."""
    import drjit as dr
    import mitsuba as mi

    import links1_mitsuba as lm
    collect_earlier_scenes()
    scene = lm.load_string(scene_xml(CENTRES, "-1.2, 0.6, 1.0"))
    params = mi.traverse(scene)
    C, W = "links1_whitted.blob.centers", "links1_whitted.blob.weights"

    def backward_kernels(keys):
        for k in keys:
            dr.enable_grad(params[k])
        params.update()
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            img = mi.render(scene, params, seed=0)
            dr.backward(dr.sum(img, axis=None))
            g = [np.array(dr.grad(params[k])) for k in keys]
            dr.sync_thread()
            n = len(dr.kernel_history())
        for k in keys:
            dr.disable_grad(params[k])
        assert all(np.any(x != 0) for x in g)
        return n

    backward_kernels([W])                              # warm-up (compilation)
    n_w = backward_kernels([W])
    n_cw = backward_kernels([C, W])
    # one kernel per value would add at least 24 (270 measured before: 24 values × levels)
    assert n_cw - n_w < 24, (n_w, n_cw)


@pytest.mark.slow
def test_phong_value_update_rebuilds_only_the_material_rows(variant):
    """``params.update()`` of ``links1_phong`` coefficients updates the
    material rows of the prepared tables in place: no scene build (``info()["scene_builds"]``), one
    value update (``info()["value_updates"]``), the other tables the same arrays, the frozen launch
    replayed (no kernel but the launch's own), and the frame the one of the file with those
    values, bit for bit. A change of the transmittance (shadow rays, BVH, light buffers are
    built from it) rebuilds all; a light's is an update in place (the next test); both
    frames are the file's too."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    scene = lm.load_string(scene_xml(CENTRES))
    integ = scene.integrator()
    _, codes_recorded = launched(lambda: mi.render(scene, seed=0))    # the launch's recording
    before, codes = launched(lambda: mi.render(scene, seed=0))
    P = integ.info()["tables"]
    builds, kept = integ.info()["scene_builds"], (P.shadow_t, P.is_phong, P.eps_table, P.trans, P.ior)
    params = mi.traverse(scene)
    params["floor.bsdf.diffuse.value"] = mi.Color3f(0.25, 0.5, 0.75)
    params["floor.bsdf.specular.value"] = mi.Color3f(0.125, 0.25, 0.375)
    params["links1_whitted.blob.bsdf.exponent"] = mi.Float(20.0)
    params.update()
    recorded = integ.info()["recordings"]
    after, codes_after = launched(lambda: mi.render(scene, seed=0))
    # the frozen launch replayed: no new kernel. Dr.Jit's freeze may record it once more at
    # random (test_tuning.py: "an input's memory moved"; seen here only cold, with five other
    # test files before this one): then its kernels are the first recording's code, never new
    # code (tables rebuilt, or constants baked into the kernels, would be)
    assert integ.info()["recordings"] <= recorded + 1
    assert codes_after <= codes | codes_recorded, f"{len(codes_after - codes - codes_recorded)} new kernels"
    Q = integ.info()["tables"]
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == 1
    assert Q is P and all(a is b for a, b in zip(kept, (Q.shadow_t, Q.is_phong, Q.eps_table, Q.trans, Q.ior)))
    assert not np.array_equal(after, before)
    xml = scene_xml(CENTRES).replace(
        '<rgb name="diffuse" value="0.6, 0.5, 0.4"/>',
        '<rgb name="diffuse" value="0.25, 0.5, 0.75"/><rgb name="specular" value="0.125, 0.25, 0.375"/>').replace(
        '<float name="exponent" value="10"/>', '<float name="exponent" value="20"/>')
    assert xml.count("0.25, 0.375") == 1 and xml.count('name="exponent" value="20"') == 1
    fresh = np.array(mi.render(lm.load_string(xml), seed=0))
    assert np.array_equal(after, fresh)
    # nothing changed: neither a build nor an update
    mi.render(scene, seed=0)
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == 1
    # a transmittance, then a light: whole rebuilds, the file's frames
    params["floor.bsdf.transmittance.value"] = mi.Color3f(0.5, 0.5, 0.5)
    params.update()
    t_img = np.array(mi.render(scene, seed=0))
    assert integ.info()["scene_builds"] == builds + 1 and integ.info()["value_updates"] == 1
    xml_t = xml.replace('<rgb name="diffuse" value="0.25, 0.5, 0.75"/>',
                        '<rgb name="diffuse" value="0.25, 0.5, 0.75"/><rgb name="transmittance" value="0.5"/>')
    assert np.array_equal(t_img, np.array(mi.render(lm.load_string(xml_t), seed=0)))
    params["lp.position"] = mi.Point3f(2.5, 4, 3)
    params.update()
    l_img = np.array(mi.render(scene, seed=0))
    assert integ.info()["scene_builds"] == builds + 1 and integ.info()["value_updates"] == 2
    xml_l = xml_t.replace('<point name="position" x="2" y="4" z="3"/>', '<point name="position" x="2.5" y="4" z="3"/>')
    assert np.array_equal(l_img, np.array(mi.render(lm.load_string(xml_l), seed=0)))
    dr.sync_thread()


def test_reflectance_update_that_makes_a_slot_spawn_is_the_files_frame(variant):
    """A ``links1_phong`` reflectance from 0 to more, while another slot reflects already, is
    an update in place (no build); the slots whose hits spawn children (``Prepared.spawns``:
    the ray tree computes the lobes under a branch on it) follow it, so the frame and its
    mirror rays are the file's with that reflectance, bit for bit (the floor's mirror rays
    added to the blob's)."""
    import mitsuba as mi
    import links1_mitsuba as lm
    xml = scene_xml(CENTRES)
    scene = lm.load_string(xml)
    integ = scene.integrator()
    mi.render(scene, seed=0)
    builds, reflect = integ.info()["scene_builds"], integ.stats["reflect"]
    params = mi.traverse(scene)
    params["floor.bsdf.reflectance.value"] = mi.Color3f(0.5, 0.25, 0.125)
    params.update()
    got = np.array(mi.render(scene, seed=0))
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == 1
    old = '<rgb name="diffuse" value="0.6, 0.5, 0.4"/>'
    assert xml.count(old) == 1
    fresh = lm.load_string(xml.replace(old, old + '<rgb name="reflectance" value="0.5, 0.25, 0.125"/>'))
    assert np.array_equal(got, np.array(mi.render(fresh, seed=0)))
    assert integ.stats["reflect"] == fresh.integrator().stats["reflect"] > reflect > 0


def test_specular_update_keeps_the_reflectance_it_defaulted_to(variant):
    """A ``links1_phong`` without ``reflectance`` gets ``r = specular`` when loaded; in
    ``mi.traverse`` the two are separate parameters, so a new ``specular`` leaves ``r`` at the
    loaded value: the frame is the file's with the new specular and the old reflectance written
    out (and not the file's with only the new specular, whose r would follow it)."""
    import mitsuba as mi
    import links1_mitsuba as lm
    xml = scene_xml(CENTRES)
    old = '<rgb name="specular" value="0.3"/>'
    assert xml.count(old) == 1
    scene = lm.load_string(xml)
    params = mi.traverse(scene)
    key = "links1_whitted.blob.bsdf"
    assert np.allclose(np.array(params[f"{key}.reflectance.value"]).ravel(), 0.3)
    params[f"{key}.specular.value"] = mi.Color3f(0.125, 0.5, 0.375)
    params.update()
    got = np.array(mi.render(scene, seed=0))
    assert np.allclose(np.array(params[f"{key}.reflectance.value"]).ravel(), 0.3)
    new = '<rgb name="specular" value="0.125, 0.5, 0.375"/>'
    kept = np.array(mi.render(lm.load_string(xml.replace(old, new + '<rgb name="reflectance" value="0.3"/>')), seed=0))
    assert np.array_equal(got, kept)
    followed = np.array(mi.render(lm.load_string(xml.replace(old, new)), seed=0))
    assert not np.array_equal(got, followed)


#: light_scene_xml's spot light (a rotation and a translation, exact in float32)
SPOT_TO = np.array([[0.6, 0.0, -0.8, 4.0], [-0.48, 0.8, -0.36, 5.0], [0.64, 0.6, 0.48, -3.0], [0, 0, 0, 1]])


def light_scene_xml(pos, spot_to_world, intensity):
    """test_lightbuffer.py's 120 quadrics (a BVH, light buffers) with its point light at
    ``pos`` (id ``pl``, RGB ``intensity``), its spot light's ``to_world`` the 4x4 matrix
    ``spot_to_world`` (id ``sp``), and a second sensor."""
    from tests.plugins.test_lightbuffer import LIGHT, _scene
    xml = _scene(120)
    old = f'<emitter type="point"><point name="position" value="{LIGHT[0]},{LIGHT[1]},{LIGHT[2]}"/>\n    <rgb name="intensity" value="20"/>'
    assert xml.count(old) == 1
    xml = xml.replace(old, f'<emitter type="point" id="pl"><point name="position" value="{pos[0]!r},{pos[1]!r},{pos[2]!r}"/>'
                           f'<rgb name="intensity" value="{intensity!r}"/>')
    spot = re.search(r'<emitter type="spot">.*?</transform>', xml, re.S).group(0)
    m = " ".join(repr(float(x)) for x in np.asarray(spot_to_world, dtype=np.float32).ravel())
    xml = xml.replace(spot, f'<emitter type="spot" id="sp"><transform name="to_world"><matrix value="{m}"/></transform>')
    cam = re.search(r"<sensor .*?</sensor>", xml, re.S).group(0)
    return xml.replace(cam, cam + cam.replace('origin="0,7,10"', 'origin="6,5,6"'))


@pytest.mark.slow
def test_light_update_replans_only_the_shadow_tables(variant):
    """``params.update()`` of an analytic light's own values updates the
    prepared tables in place (``Tables._update_values``): the light's entry and the tables
    planned from the lights' places (``prepared.LIGHT_FIELDS``: which shapes each light's shadow
    rays test, the light buffers) are made anew, every other table (BVH, materials) is kept,
    no scene build. The scene: 120 quadrics under a BVH with light buffers
    (test_lightbuffer.py), a Mitsuba point light moved from inside three nested transparent
    spheres to outside them and a spot light moved. Both
    sensors' frames are then the frames of the file with the new lights, bit for bit. A
    light's texture (here a point light's intensity) is another object: a whole rebuild,
    the file's frame too."""
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1_mitsuba.prepared import LIGHT_FIELDS

    moved_to = np.array(SPOT_TO)
    moved_to[:3, 3] = [3.5, 4.5, -2.5]

    def xml(pos=(0.7, 2.2, 0.4), to=SPOT_TO, intensity=20):
        return light_scene_xml(pos, to, intensity)

    scene = lm.load_string(xml())
    integ = scene.integrator()
    frames = lambda sc: [np.array(mi.render(sc, sensor=k, seed=0)) for k in (0, 1)]  # noqa: E731
    before = frames(scene)
    P = integ.info()["tables"].base
    assert P.bvh is not None and any(lb is not None for lb in P.lbuf)
    builds, updates = integ.info()["scene_builds"], integ.info()["value_updates"]
    kept = (P.bvh, P.dif, P.eps_table, P.reg_to_slot)
    old = {f: getattr(P, f) for f in LIGHT_FIELDS}
    params = mi.traverse(scene)
    params["pl.position"] = mi.Point3f(-1.5, 4.25, 2.75)
    params["sp.to_world"] = mi.Transform4f(moved_to.tolist())
    params.update()
    after = frames(scene)
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == updates + 1
    Q = integ.info()["tables"].base
    assert Q is P and all(a is b for a, b in zip(kept, (Q.bvh, Q.dif, Q.eps_table, Q.reg_to_slot)))
    # the light tables new, the shapes' part of the occluder planning reused
    assert all(getattr(Q, f) is not old[f] for f in LIGHT_FIELDS if f != "occ_shapes")
    assert Q.occ_shapes is old["occ_shapes"]
    for V in Q.views.values():   # each sensor's view has the new light tables
        assert all(getattr(V, f) is getattr(Q, f) for f in LIGHT_FIELDS)
    # the point light's buffer (its cells' occluder lists) is planned around its new place
    assert old["lbuf"][0].pos == [0.7, 2.2, 0.4] or np.allclose(old["lbuf"][0].pos, [0.7, 2.2, 0.4])
    assert Q.lbuf[0].pos == [-1.5, 4.25, 2.75]
    fresh = frames(lm.load_string(xml(pos=(-1.5, 4.25, 2.75), to=moved_to)))
    for a, b, c in zip(before, after, fresh):
        assert not np.array_equal(a, b)
        assert np.array_equal(b, c)
    # a texture of a light (the point light's intensity): a whole rebuild, the file's frames
    params["pl.intensity.value"] = mi.Color3f(30.0)
    params.update()
    t_frames = frames(scene)
    assert integ.info()["scene_builds"] == builds + 1 and integ.info()["value_updates"] == updates + 1
    fresh = frames(lm.load_string(xml(pos=(-1.5, 4.25, 2.75), to=moved_to, intensity=30)))
    for b, c in zip(t_frames, fresh):
        assert np.array_equal(b, c)



@pytest.mark.slow
def test_shape_update_remakes_only_the_shapes_tables(variant):
    """``params.update()`` of a links1 shape's geometry updates the prepared tables in place: the BVH is built again over the same
    quadrics, the shapes' own tables, the light tables (their occluders' bounds) and each
    camera view's eye buffer are made anew; the materials, slots and lights are kept; no
    scene build. The scene: test_lightbuffer.py's 120 quadrics (a BVH, light buffers), one of
    the transparent spheres around the point light moved, two sensors. Each sensor's frame
    is then the frame of a fresh scene given the same transform, bit for bit."""
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1_mitsuba.prepared import SHAPE_FIELDS

    xml = light_scene_xml((0.7, 2.2, 0.4), SPOT_TO, 20).replace(
        '<shape type="links1_quadric">', '<shape type="links1_quadric" id="q0">', 1)
    key = "links1_whitted.q0.to_world"
    scene = lm.load_string(xml)
    integ = scene.integrator()
    frames = lambda sc: [np.array(mi.render(sc, sensor=k, seed=0)) for k in (0, 1)]  # noqa: E731
    before = frames(scene)
    P = integ.info()["tables"].base
    assert P.bvh is not None and len(P.bvh_slots) == 120    # q0 among them
    builds, updates = integ.info()["scene_builds"], integ.info()["value_updates"]
    kept = (P.dif, P.eps_table, P.reg_to_slot, P.lights, P.bsdf_ptr)
    old = {f: getattr(P, f) for f in ("bvh", "blob_tables", "lbuf", "occ_shapes")}
    old_eye = {k: V.eye_buf for k, V in P.views.items()}
    params = mi.traverse(scene)
    params[key] = mi.Transform4f().translate(mi.Vector3f(0.5, 0.25, -0.5)) @ mi.Transform4f(params[key])
    params.update()
    after = frames(scene)
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == updates + 1
    Q = integ.info()["tables"].base
    assert Q is P and all(a is b for a, b in zip(kept, (Q.dif, Q.eps_table, Q.reg_to_slot, Q.lights, Q.bsdf_ptr)))
    assert all(getattr(Q, f) is not v for f, v in old.items())
    for k, V in Q.views.items():     # each sensor's view: the new shape tables, its own new eye buffer
        assert all(getattr(V, f) is getattr(Q, f) for f in SHAPE_FIELDS)
        assert old_eye[k] is None or V.eye_buf is not old_eye[k]
    m = np.array(mi.Transform4f(params[key]).matrix, dtype=np.float64).reshape(4, 4)
    fresh = lm.load_string(xml)
    fp = mi.traverse(fresh)
    fp[key] = mi.Transform4f(m.tolist())       # the same float32 matrix, before any frame: a whole build
    fp.update()
    expected = frames(fresh)
    assert fresh.integrator().info()["value_updates"] == 0
    for a, b, c in zip(before, after, expected):
        assert not np.array_equal(a, b)
        assert np.array_equal(b, c)
    # the occluder planning's shapes part (the Mitsuba floor's box and plane taken from the last
    # planning, the quadrics' boxes made anew) is the fresh build's
    G, F = Q.occ_shapes, fresh.integrator().info()["tables"].base.occ_shapes
    assert G["mitsuba_slot"].any() and any(p is not None for p in G["plane"])
    for k in ("lo", "hi", "convex", "closed", "mitsuba_slot"):
        assert np.array_equal(G[k], F[k]), k
    assert G["others"] == F["others"] and G["tol"] == F["tol"]
    assert [None if p is None else (tuple(p[0]), p[1]) for p in G["plane"]] == \
        [None if p is None else (tuple(p[0]), p[1]) for p in F["plane"]]


#: :func:`scene_xml`'s blob, quadric and delta lights with a Mitsuba area light over them
AREA_BLOB_XML = scene_xml(CENTRES).replace("</scene>", """
  <shape type="rectangle" id="lamp"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/>
    <translate y="4"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>
</scene>""")


def sensor_key(params, scene, name):
    """The key of the first sensor's (or its film's: ``film.size``) parameter ``name`` in
    ``params`` (``mi.traverse(scene)``): a sensor without an id has a key made from its address."""
    s = scene.sensors()[0]
    return next(k for k, (_, _, node, _) in params.properties.items()
                if (node is s or node is s.film()) and k.endswith("." + name))


@pytest.mark.slow
@pytest.mark.parametrize("source", ["many.xml", "area_blob"])
def test_camera_move_refreshes_only_its_camera_view(variant, source):
    """``params.update()`` of a sensor's ``to_world`` refreshes that sensor's camera view in
    place (``views.refresh_cameras``: camera, eye buffer, the launch's inputs): no
    scene build, one value update, the scene's tables (BVH, lights, materials, shadow plans,
    blob tables) the same objects. The frame is then the frame of a second load of the file
    given the same camera before its first frame (a whole build), bit for bit. scenes/many.xml
    (quadrics under a BVH with an eye buffer) and a blob, a quadric and a Mitsuba area light."""
    import os

    import mitsuba as mi
    import links1_mitsuba as lm
    from tests.plugins.conftest import SCENES

    def load():
        if source == "many.xml":
            return lm.load_file(os.path.join(SCENES, source))
        return lm.load_string(AREA_BLOB_XML)

    collect_earlier_scenes()
    scene = load()
    integ = scene.integrator()
    before = np.array(mi.render(scene, seed=0))
    V = integ.info()["tables"]
    P = V.base
    names = ("bvh", "lights", "area_tab", "dif", "eps_table", "reg_to_slot", "blob_tables", "lbuf",
             "occ_shapes", "shadow_need", "bsdf_ptr")
    kept = {f: getattr(P, f) for f in names}
    old_cam, old_eye = V.cam.copy(), V.eye_buf
    assert (old_eye is not None) == (source == "many.xml")
    assert (len(P.area_tab) == 1 and any(type(sp).__name__ == "BlobSpec" for sp in P.custom)) == \
        (source == "area_blob")
    builds, updates = integ.info()["scene_builds"], integ.info()["value_updates"]
    params = mi.traverse(scene)
    k = sensor_key(params, scene, "to_world")
    params[k] = mi.Transform4f().translate(mi.Vector3f(0.3, 0.2, -0.25)) @ \
        mi.Transform4f().rotate(mi.Vector3f(0, 1, 0), 4.0) @ mi.Transform4f(params[k])
    params.update()
    after = np.array(mi.render(scene, seed=0))
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == updates + 1
    assert integ.info()["tables"] is V and V.base is P
    assert all(getattr(P, f) is v for f, v in kept.items())
    m = np.array(mi.Transform4f(params[k]).matrix, dtype=np.float64).reshape(4, 4)
    assert np.array_equal(V.cam, m) and not np.array_equal(V.cam, old_cam)
    assert old_eye is None or V.eye_buf is not old_eye     # planned around the new eye
    fresh = load()
    fp = mi.traverse(fresh)
    fk = sensor_key(fp, fresh, "to_world")
    fp[fk] = mi.Transform4f(m.tolist())
    fp.update()
    expected = np.array(mi.render(fresh, seed=0))
    assert fresh.integrator().info()["value_updates"] == 0
    assert not np.array_equal(before, after)
    assert np.array_equal(after, expected)


@pytest.mark.slow
def test_film_update_refreshes_only_its_camera_view(variant):
    """``params.update()`` of a sensor's film size (with its crop) refreshes the camera view
    as a camera move does (no scene build), the frame that of a second load given the same
    size; a crop window alone changes no camera: the frozen launch is kept, and the crop's
    pixels are the full frame's."""
    import mitsuba as mi
    import links1_mitsuba as lm

    collect_earlier_scenes()
    scene = lm.load_string(AREA_BLOB_XML)
    integ = scene.integrator()
    mi.render(scene, seed=0)
    P = integ.info()["tables"].base
    builds, updates = integ.info()["scene_builds"], integ.info()["value_updates"]

    def resize(sc, w, h):
        prm = mi.traverse(sc)
        for name in ("film.size", "film.crop_size"):
            prm[sensor_key(prm, sc, name)] = [w, h]
        prm.update()

    resize(scene, 30, 16)
    after = np.array(mi.render(scene, seed=0))
    assert after.shape[:2] == (16, 30) and integ.info()["tables"].film_size == (30, 16)
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == updates + 1
    assert integ.info()["tables"].base is P
    fresh = lm.load_string(AREA_BLOB_XML)
    resize(fresh, 30, 16)
    assert np.array_equal(after, np.array(mi.render(fresh, seed=0)))
    # a crop window: the same camera, the recording kept
    frozen = integ.info()["launch"]
    prm = mi.traverse(scene)
    prm[sensor_key(prm, scene, "film.crop_offset")] = [4, 2]
    prm[sensor_key(prm, scene, "film.crop_size")] = [10, 8]
    prm.update()
    crop = np.array(mi.render(scene, seed=0))
    assert integ.info()["scene_builds"] == builds and integ.info()["value_updates"] == updates + 2
    assert integ.info()["launch"] is frozen and frozen is not None
    assert np.array_equal(crop, after[2:10, 4:14])
