"""links1_whitted's prepared tables follow the scene: keyed on the scene's objects
and parameters, not on ``id(scene)``; a scene changed with ``mi.traverse`` after a render, or
another scene given to the same integrator, renders as a scene loaded that way."""
from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import perspective, scene

pytestmark = pytest.mark.mitsuba

XML = scene(perspective("0, 3, 6", "0, 0.5, 0", fov=45, width=24, spp=None), """
 <integrator type="links1_whitted"/>
 <shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
  <bsdf type="diffuse"/></shape>
 <shape type="sphere" id="ball"><point name="center" x="BX" y="1" z="0"/><float name="radius" value="0.6"/>
  <bsdf type="links1_phong"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.6"/></bsdf></shape>
 <emitter type="point" id="lamp"><point name="position" x="LX" y="5" z="1"/><rgb name="intensity" value="20"/></emitter>""")


def _scene(variant, lx=0.0, bx=0.0):
    from links1_mitsuba import load_string
    return load_string(XML.replace("LX", str(lx)).replace("BX", str(bx)), variant=variant)


def _render(scene, integrator=None):
    return (integrator or scene.integrator()).render_window(scene, None, spp=1)


def _move_lamp(mi, params):
    params["lamp.position"] = mi.Point3f(2.0, 5.0, 1.0)


def _move_ball(mi, params):
    params["ball.to_world"] = mi.ScalarTransform4f().translate([1.0, 1.0, 0.0]).scale(0.6)


@pytest.mark.slow
@pytest.mark.parametrize("change, fresh", [(_move_lamp, {"lx": 2.0}), (_move_ball, {"bx": 1.0})],
                         ids=["light moved", "occluder moved"])
def test_params_update_after_a_render(variant, change, fresh):
    import mitsuba as mi
    s = _scene(variant)
    before = _render(s)
    params = mi.traverse(s)
    change(mi, params)
    params.update()
    after = _render(s)
    expected = _render(_scene(variant, **fresh))
    assert not np.array_equal(before, expected)  # the change shows
    np.testing.assert_allclose(after, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_another_scene_through_the_same_integrator(variant):
    a, b = _scene(variant), _scene(variant, lx=-2.0)
    integ = a.integrator()
    ra = _render(a, integ)
    rb = _render(b, integ)                     # a's integrator, b's scene
    assert not np.array_equal(ra, rb)
    np.testing.assert_array_equal(rb, _render(b))
    np.testing.assert_array_equal(_render(a, integ), ra)


# --: the tables are watched by their parameters' Dr.Jit variables -----------

MESH_XML = """<scene version="3.0.0">
 <sensor type="perspective" id="cam"><float name="fov" value="45"/>
  <transform name="to_world"><lookat origin="0, 3, 6" target="0, 0.5, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="20"/><rfilter type="gaussian"/></film>
 </sensor>
 <integrator type="links1_whitted"/>
 <shape type="rectangle" id="floor"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
  <bsdf type="diffuse" id="floormat"><rgb name="reflectance" value="0.5"/></bsdf></shape>
 <shape type="cube" id="box"><transform name="to_world"><translate x="0" y="0.5" z="0"/><scale value="0.5"/></transform>
  <bsdf type="diffuse" id="boxmat"><rgb name="reflectance" value="0.2, 0.4, 0.7"/></bsdf></shape>
 <emitter type="point" id="lamp"><point name="position" x="1" y="5" z="2"/><rgb name="intensity" value="20"/></emitter>
</scene>"""


def _moved_sensor(mi, params, scene):
    params["cam.to_world"] = mi.ScalarTransform4f().look_at(origin=[1, 3, 6], target=[0, 0.5, 0], up=[0, 1, 0])


def _fov(mi, params, scene):
    params["cam.x_fov"] = mi.Float(30.0)


def _bsdf_colour(mi, params, scene):
    params["box.bsdf.reflectance.value"] = mi.Color3f(0.8, 0.1, 0.1)


def _light_moved(mi, params, scene):
    params["lamp.position"] = mi.Point3f(-2.0, 5.0, 1.0)


def _light_intensity(mi, params, scene):
    params["lamp.intensity.value"] = mi.Color3f(5.0, 30.0, 5.0)


def _vertices_assigned(mi, params, scene):
    v = params["box.vertex_positions"]
    params["box.vertex_positions"] = v + 0.3      # every third coordinate too: moved diagonally


def _vertices_scattered(mi, params, scene):
    import drjit as dr
    v = params["box.vertex_positions"]              # the mesh's own array, written in place
    dr.scatter(v, dr.gather(mi.Float, v, mi.UInt32([1, 4, 7, 10])) + 0.4, mi.UInt32([1, 4, 7, 10]))
    params.set_dirty("box.vertex_positions")


def _film_size(mi, params, scene):
    params["cam.film.size"] = mi.ScalarVector2u(20, 24)


CHANGES = [_moved_sensor, _fov, _bsdf_colour, _light_moved, _light_intensity, _vertices_assigned,
           _vertices_scattered, _film_size]


def _fresh_render(scene, sensor=0):
    """``scene`` as it is now, through a new links1_whitted (its own tables, built now)."""
    import mitsuba as mi
    return np.array(mi.render(scene, sensor=sensor, integrator=mi.load_dict({"type": "links1_whitted"}),
                              spp=1))


@pytest.mark.slow
def test_unchanged_scene_prepares_nothing(variant):
    """Frames of an unchanged scene (``mi.render``, ``render_window``, reading ``mi.traverse``'s
    values, an ``update()`` that changes nothing) build the tables once; the frames record the
    frozen launch at most twice in all (the second recording makes changed literals opaque), and
    once more where Dr.Jit's freeze sees its inputs' layout change."""
    import mitsuba as mi

    from links1_mitsuba import load_string
    scene = load_string(MESH_XML, variant=variant)
    integ = scene.integrator()
    first = np.array(mi.render(scene, spp=1))
    assert integ.info()["scene_builds"] == 1 and integ.info()["camera_views"] == 1
    for seed in range(4):
        img = np.array(mi.render(scene, spp=1, seed=seed % 2))
        if seed % 2 == 0:
            np.testing.assert_array_equal(img, first)
    integ.render_window(scene, (3, 2, 9, 7), spp=1)
    params = mi.traverse(scene)
    _ = [params[k] for k in params.keys()]
    params.update()
    np.testing.assert_array_equal(np.array(mi.render(scene, spp=1)), first)
    assert integ.info()["scene_builds"] == 1 and integ.info()["camera_views"] == 1
    # twice, and once more where Dr.Jit's freeze records again as its inputs' layout changes
    # (seen once in the suite's test order), never once a frame (seven frames here)
    assert integ.info()["recordings"] <= 3


@pytest.mark.slow
@pytest.mark.parametrize("change", CHANGES, ids=[c.__name__.strip("_") for c in CHANGES])
def test_each_params_update_prepares_again(variant, change):
    """After a render, one ``params.update()`` of each kind (camera, BSDF, light, a mesh's
    vertices assigned or scattered in place, the film) builds the tables once more (a light's
    own position, the camera, its fov and film, a ``diffuse`` reflectance of one value: updates
    them in place,
    ``Tables._update_values``, the camera's view only), and the next frame
    equals a new integrator's render of the changed scene; the frame after it builds nothing;
    each set of tables records its frozen launch at most twice (and once more on freeze's layout
    change)."""
    import mitsuba as mi

    from links1_mitsuba import load_string
    scene = load_string(MESH_XML, variant=variant)
    integ = scene.integrator()
    before = np.array(mi.render(scene, spp=1))
    mi.render(scene, spp=1)
    assert integ.info()["scene_builds"] == 1
    params = mi.traverse(scene)
    change(mi, params, scene)
    params.update()
    after = np.array(mi.render(scene, spp=1))
    in_place = change in (_light_moved, _moved_sensor, _fov, _film_size, _bsdf_colour)
    assert (integ.info()["scene_builds"], integ.info()["value_updates"]) == ((1, 1) if in_place else (2, 0))
    expected = _fresh_render(scene)
    assert before.shape != expected.shape or not np.array_equal(before, expected)   # the change shows
    np.testing.assert_array_equal(after, expected)
    np.testing.assert_array_equal(np.array(mi.render(scene, spp=1)), after)
    assert (integ.info()["scene_builds"], integ.info()["value_updates"]) == ((1, 1) if in_place else (2, 0))
    assert integ.info()["recordings"] <= 3     # (as above: freeze's layout change once at most)


@pytest.mark.slow
def test_sensor_made_apart_is_watched(variant):
    """A sensor from ``mi.load_dict`` gets one camera view while unchanged, and a new one after
    its ``params.update()`` (the scene's tables are kept)."""
    import mitsuba as mi

    from links1_mitsuba import load_string
    scene = load_string(MESH_XML, variant=variant)
    integ = scene.integrator()
    sensor = mi.load_dict({"type": "perspective", "fov": 40, "to_world": mi.ScalarTransform4f().look_at(
        origin=[-3, 2, 4], target=[0, 0.5, 0], up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": 16, "height": 12, "rfilter": {"type": "box"}}})
    a = np.array(mi.render(scene, sensor=sensor, spp=1))
    np.testing.assert_array_equal(np.array(mi.render(scene, sensor=sensor, spp=1)), a)
    assert (integ.info()["scene_builds"], integ.info()["camera_views"]) == (1, 1)
    prm = mi.traverse(sensor)
    prm["to_world"] = mi.ScalarTransform4f().look_at(origin=[3, 2, 4], target=[0, 0.5, 0], up=[0, 1, 0])
    prm.update()
    b = np.array(mi.render(scene, sensor=sensor, spp=1))
    assert (integ.info()["scene_builds"], integ.info()["camera_views"]) == (1, 2)
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(b, _fresh_render(scene, sensor))


def test_param_watch_values_of_python_plugins_and_scalars(variant):
    """``ParamWatch`` on a scene whose Python BSDF puts a Dr.Jit value of its own (its object,
    which ``parameters_changed`` may replace: each check traverses that BSDF again) and on a scene of
    C++ objects only (one traversal; the scene's own scalar and a sensor's float compared by
    value): unchanged after an ``update()`` that changes nothing, changed after each kind of
    assignment, and a new watch agrees with the new values."""
    import mitsuba as mi

    from links1_mitsuba.paramwatch import ParamWatch

    class Tinted(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.tint = mi.Color3f(0.5)

        def traverse(self, callback):
            callback.put("tint", self.tint, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            self.tint = mi.Color3f(self.tint)   # a new object, as a plugin may make

    mi.register_bsdf("links1_test_tinted", Tinted)
    sensor = {"type": "perspective", "film": {"type": "hdrfilm", "width": 8, "height": 8}}
    py = mi.load_dict({"type": "scene", "s": {"type": "sphere", "bsdf": {"type": "links1_test_tinted"}},
                       "cam": sensor})
    cpp = mi.load_dict({"type": "scene", "s": {"type": "sphere", "bsdf": {"type": "diffuse"}}, "cam": sensor})
    for scene, key, value in [(py, "s.bsdf.tint", mi.Color3f(0.1, 0.2, 0.3)),
                              (py, "s.bsdf.tint", mi.Color3f(0.7)),      # the replaced object
                              (cpp, "s.bsdf.reflectance.value", mi.Float(0.9)),
                              (cpp, "s.silhouette_sampling_weight", 0.25),
                              (cpp, "allow_thread_reordering", False)]:
        w = ParamWatch(scene)
        assert w.unchanged(scene)
        params = mi.traverse(scene)
        params.update()
        assert w.unchanged(scene)
        params[key] = value
        params.update()
        assert not w.unchanged(scene), key
        assert ParamWatch(scene).unchanged(scene)
    # neither is traversed whole at a check: the Python BSDF's node is traversed again alone
    wp, wc = ParamWatch(py), ParamWatch(cpp)
    assert not wp._retraverse and not wc._retraverse
    assert [keys for _, keys in wp._own] == [["s.bsdf.tint"]] and wc._own == []


def test_own_param_reads_what_mi_traverse_reads(variant):
    """``paramwatch.own_param`` (one ``obj.traverse`` with a callback class made once, instead of
    ``mi.traverse``, which makes its class at every call) gives ``mi.traverse(obj)[name]``: a
    rectangle's ``to_world`` after a ``params.update()`` and a sensor's ``x_fov``; a name the
    object does not hold, or one of a child object, is a KeyError."""
    import mitsuba as mi

    from links1_mitsuba.paramwatch import own_param
    scene = _scene(variant)
    floor = next(s for s in scene.shapes() if s.id() == "floor")
    params = mi.traverse(scene)
    params["floor.to_world"] = mi.Transform4f().translate(mi.Vector3f(0.5, 0.25, 0)) @ mi.Transform4f(params["floor.to_world"])
    params.update()
    for obj, name in ((floor, "to_world"), (scene.sensors()[0], "x_fov")):
        got, want = own_param(obj, name), mi.traverse(obj)[name]
        got, want = (got.matrix, want.matrix) if name == "to_world" else (got, want)
        assert np.array_equal(np.array(got), np.array(want)), name
    assert np.array(own_param(floor, "to_world").matrix)[0][3] == 0.5
    with pytest.raises(KeyError):
        own_param(floor, "no_such_parameter")
    with pytest.raises(KeyError):
        own_param(floor, "bsdf.reflectance.value")     # a child's (the BSDF's), not the shape's


def test_changed_reads_what_a_traversal_reads(variant):
    """``ParamWatch.changed`` reads the values the way ``unchanged`` does (the C++ objects'
    fields by address, the Python plugins' and the scene's integrator's values by traversing
    their nodes one level), not from a whole ``mi.traverse`` (~0.1 ms an update): for changes
    of every kind (a Mitsuba BSDF's value, a links1_phong colour, a Mitsuba light, a
    links1_quadric's transform among the integrator's values, the sensor's field of view, a
    sampling weight without variables, the scene's own flag) it
    finds the parameters a traversal finds, and its renewed watch is the traversal's."""
    import mitsuba as mi

    from links1_mitsuba import load_string
    from links1_mitsuba.paramwatch import ParamWatch
    xml = XML.replace("LX", "0.0").replace("BX", "0.0").replace(
        "</scene>", """ <shape type="links1_quadric" id="q"><string name="kind" value="sphere"/>
  <transform name="to_world"><scale value="0.3"/><translate x="1" y="0.5" z="0"/></transform></shape>
</scene>""")
    scene = load_string(xml, variant=variant)
    params = mi.traverse(scene)
    fast, slow = ParamWatch(scene), ParamWatch(scene)
    slow._retraverse = True           # the whole traversal, as for a node it cannot match
    assert not fast._retraverse
    params["floor.bsdf.reflectance.value"] = mi.Float(0.3)
    params["ball.bsdf.diffuse.value"] = mi.Color3f(0.1, 0.5, 0.9)
    params["lamp.position"] = mi.Point3f(1.0, 4.0, 2.0)
    params["links1_whitted.q.to_world"] = mi.Transform4f().translate(mi.Vector3f(0.0, 0.25, 0.0)) \
        @ mi.Transform4f(params["links1_whitted.q.to_world"])
    fov = [k for k in params.keys() if k.endswith("x_fov")]
    assert len(fov) == 1 and fov[0] in fast._jit_keys
    params[fov[0]] = mi.Float(50.0)
    assert "lamp.sampling_weight" in fast._scalar_keys and fast._root_keys == ["allow_thread_reordering"]
    params["lamp.sampling_weight"] = 2.0                       # a value without variables
    params["allow_thread_reordering"] = not params["allow_thread_reordering"]   # the scene's own
    params.update()
    got, want = fast.changed(scene), slow.changed(scene)
    assert type(fast.traversed) is not type(slow.traversed)   # (the fast path was taken)
    assert sorted(fast.changed_keys) == sorted(slow.changed_keys)
    assert {"floor.bsdf.reflectance.value", "ball.bsdf.diffuse.value", "lamp.position",
            "links1_whitted.q.to_world", fov[0], "lamp.sampling_weight",
            "allow_thread_reordering"} <= set(fast.changed_keys)
    assert sorted((n, id(o)) for n, o in got) == sorted((n, id(o)) for n, o in want)
    a, b, fresh = fast.renewed(scene), slow.renewed(scene), ParamWatch(scene)
    assert a.state == b.state == fresh.state and a._jit_ids == fresh._jit_ids
    assert a.unchanged(scene) and b.unchanged(scene)


def test_a_renewed_watch_is_a_new_watch(variant):
    """``ParamWatch.renewed`` (a rebuild's watch made from the last one): after
    ``changed`` found the changed parameters (a Mitsuba BSDF's value, a links1_phong
    colour, a Mitsuba light's position), the renewed watch reads only those again and has
    the state of a whole new watch; it sees the scene unchanged, and a later change."""
    import mitsuba as mi

    from links1_mitsuba import load_string
    from links1_mitsuba.paramwatch import ParamWatch
    scene = load_string(XML.replace("LX", "0.0").replace("BX", "0.0"), variant=variant)
    params = mi.traverse(scene)
    w = ParamWatch(scene)
    params["floor.bsdf.reflectance.value"] = mi.Float(0.3)
    params["ball.bsdf.diffuse.value"] = mi.Color3f(0.1, 0.5, 0.9)
    params["lamp.position"] = mi.Point3f(1.0, 4.0, 2.0)
    params.update()
    assert not w.unchanged(scene)
    # (a links1_phong hands out new objects for all its values at an update: those too)
    assert {"diffuse", "position", "reflectance"} <= {n for n, _ in w.changed(scene)}
    changed = sorted(w.changed_keys)
    read = []
    real = ParamWatch._read_all

    def counting(self, params, pin=False, keys=None):
        read.append(None if keys is None else sorted(keys))
        return real(self, params, pin, keys)
    ParamWatch._read_all = counting
    try:
        w2 = w.renewed(scene)
    finally:
        ParamWatch._read_all = real
    assert w.traversed is None     # let go (it holds the scene: a cycle through the tables)
    assert {"floor.bsdf.reflectance.value", "ball.bsdf.diffuse.value", "lamp.position"} <= set(changed)
    assert len(changed) < len(w.state) // 2
    assert read and all(r == changed for r in read)          # never the whole scene
    fresh = ParamWatch(scene)
    assert w2.state == fresh.state and w2._jit_ids == fresh._jit_ids
    assert w2.unchanged(scene) and fresh.unchanged(scene)
    params["lamp.position"] = mi.Point3f(1.0, 4.0, 3.0)
    params.update()
    assert not w2.unchanged(scene)


PHONG_BALL = """<scene version="3.0.0">
 <integrator type="links1_whitted"/>
 <sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 2.5, 5" target="0, 0.8, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/><rfilter type="box"/></film>
  <sampler type="independent"><integer name="sample_count" value="1"/></sampler></sensor>
 <shape type="rectangle" id="floor"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>
  <bsdf type="FLOOR_BSDF"/></shape>
 <shape type="sphere" id="ball"><point name="center" x="0" y="1" z="0"/><float name="radius" value="1"/>
  <bsdf type="links1_phong"><rgb name="diffuse" value="0.7, 0.3, 0.2"/></bsdf></shape>
 <emitter type="links1_point" id="lp"><point name="position" x="2" y="4" z="3"/><rgb name="L1" value="0.6"/></emitter>
 <emitter type="point" id="mp"><point name="position" x="-2" y="3" z="4"/><rgb name="intensity" value="6"/></emitter>
</scene>"""


@pytest.mark.slow
def test_a_scene_dropped_after_gradients_is_freed_and_another_records(variant):
    """An inverse-rendering loop on one scene (its parameters changed and updated each
    iteration: the tables' watch sees which, ``ParamWatch.renewed``), then the scene dropped
    while Python's cyclic collector is off, then another scene's first frame. Two faults
    seen in ``compare.inverse``: the watch kept the scene's traversal, a cycle
    through C++ objects that kept every such scene alive; and a scene that is garbage but
    not yet collected still has its BSDFs registered, so the new scene's frozen launch,
    whose calls through the BSDF pointers reach them, failed to record (Dr.Jit: "... no such
    object instance was found in the function's inputs"). Now the first scene is freed once
    collected, and the second records and renders (as a fresh process renders it)."""
    import gc
    import weakref

    import drjit as dr
    import mitsuba as mi

    from links1_mitsuba import load_string

    def fit_a_few(xml):
        scene = load_string(xml, variant=variant)
        params = mi.traverse(scene)
        target = mi.render(scene, seed=0)
        opt = mi.ad.Adam(lr=0.05)
        opt["ball.bsdf.diffuse.value"] = mi.Color3f(0.4, 0.4, 0.4)
        params.update(opt)
        for _ in range(3):
            img = mi.render(scene, params, seed=0)
            dr.backward(dr.mean(dr.square(img - target), axis=None))
            opt.step()
            params.update(opt)
        return weakref.ref(scene.integrator())

    all_phong = PHONG_BALL.replace('<bsdf type="FLOOR_BSDF"/>', '<bsdf type="links1_phong"/>')
    mixed = PHONG_BALL.replace('<bsdf type="FLOOR_BSDF"/>', '<bsdf type="diffuse"/>')
    expected = np.array(mi.render(load_string(mixed, variant=variant), seed=0))
    gc.collect()
    gc.disable()
    try:
        integrator = fit_a_few(all_phong)      # the scene is garbage now, not collected
        # (a new integrator: its frozen launch records anew)
        second = np.array(mi.render(load_string(mixed, variant=variant), seed=0))
    finally:
        gc.enable()
    np.testing.assert_array_equal(second, expected)
    gc.collect()
    assert integrator() is None, "the first scene is still alive after a collection"
