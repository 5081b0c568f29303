"""The plugin's gradients against the float64 core's finite differences.

The same file, its values given as ``$name`` parameters, is rendered by ``links1_whitted``
(reverse mode: ``mi.render(scene, params)`` + ``dr.backward``) and by the core
(``links1.tracing.render.render``, float64 numpy, another implementation of the same method:
its own quadric roots, shading and ray tree), whose central differences come from loading the
file with each value moved by ±h. The loss is the weighted sum over the pixels that see the
moving sphere, eroded twice (``test_geometry_gradients.interior``: no silhouette or shadow edge
in it), so both are derivatives of a smooth function there.

Step and tolerance: h = 1e-3 moves the sphere's silhouette by ~0.006 pixel (one unit is ~5.5
pixels at this camera), far from the loss's pixels; the core's central difference then errs by
h²/6 · f''' (~1e-7 relative) plus float64 rounding (~1e-13 / 2h). The two renderers' frames
differ by float32 rounding and their own arithmetic (the plugin's quadric in float32 against the
core's float64 roots: ~1e-6 relative in these pixels): the plugin's gradient vector must equal
the core's to 1e-4 of its length (measured: 1.8e-6 for the translation, 3e-7 for the light; a
gradient missing a term is far off: with the moving hit's normal held fixed, 0.84).
"""
from __future__ import annotations

import numpy as np
import pytest

from tests.plugins.test_geometry_gradients import BLOB, CAMERA, SPHERE, interior

pytestmark = pytest.mark.mitsuba

DEFAULTS = dict(tx=0.2, ty=1.4, tz=0.3, lx=2.0, ly=4.0, lz=3.0)

def _with(text, *pairs):
    """``text`` with each ``(old, new)`` replaced, each ``old`` found exactly once."""
    for old, new in pairs:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


def _defaults(values):
    return "".join(f'<default name="{k}" value="{v!r}"/>' for k, v in values.items())


# test_geometry_gradients' sphere over the mirror-ish floor, its translation and the links1
# point light's position as parameters
SCENE = _defaults(DEFAULTS) + CAMERA.format(depth=3) + _with(
    SPHERE, ('<translate x="0.2" y="1.4" z="0.3"/>', '<translate x="$tx" y="$ty" z="$tz"/>'),
    ('<point name="position" x="2" y="4" z="3"/>', '<point name="position" x="$lx" y="$ly" z="$lz"/>'))

H = 1e-3


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("grad_core") / "scene.xml"
    path.write_text(f'<scene version="3.0.0">{SCENE}</scene>')
    return path


def core_sum(path, weights, defaults, **moved):
    """The weighted sum of the core's frame of the file, its parameters ``defaults`` with ``moved``."""
    from links1.scene.loader import load_scene
    from links1.tracing.render import render
    values = {k: repr(float(v)) for k, v in {**defaults, **moved}.items()}
    img = render(load_scene(str(path), **values), spp=1)
    return float(np.sum(img[..., :3] * weights))


def core_gradient(path, weights, names, defaults=DEFAULTS):
    """The core's central differences of :func:`core_sum` in the parameters ``names``."""
    return np.array([(core_sum(path, weights, defaults, **{k: defaults[k] + H})
                      - core_sum(path, weights, defaults, **{k: defaults[k] - H})) / (2 * H) for k in names])


def assert_same_vector(g, ref, tol=1e-4):
    err = float(np.linalg.norm(g - ref) / np.linalg.norm(ref))
    assert err <= tol, (g, ref, err)


def test_quadric_translation_matches_the_cores_finite_difference(variant, scene_file):
    """d(loss)/d(translation) of a ``links1_quadric``: the plugin's implicit differentiation of
    the moving hit against the core's frames with the file's translation moved."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    scene = lm.load_file(str(scene_file))
    w = interior(scene, "ball")
    key = "links1_whitted.ball.to_world"
    params = mi.traverse(scene)
    old = mi.Transform4f(params[key])
    t = mi.Vector3f(0.0)
    dr.enable_grad(t)
    params[key] = mi.Transform4f().translate(t) @ old
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    g = np.array(dr.grad(t), dtype=np.float64).ravel()
    params[key] = old
    params.update()
    ref = core_gradient(scene_file, w, ("tx", "ty", "tz"))
    assert np.linalg.norm(ref) > 0.3, ref
    assert_same_vector(g, ref)


@pytest.mark.slow
def test_light_position_matches_the_cores_finite_difference(variant, scene_file):
    """d(loss)/d(position) of a ``links1_point`` light (eq. 3.10 with inverse-square falloff):
    the plugin's reverse mode against the core's frames with the file's light moved."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    scene = lm.load_file(str(scene_file))
    w = interior(scene, "ball")
    params = mi.traverse(scene)
    old = mi.Point3f(params["lp.position"])
    pos = mi.Point3f(old)
    dr.enable_grad(pos)
    params["lp.position"] = pos
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    g = np.array(dr.grad(pos), dtype=np.float64).ravel()
    params["lp.position"] = old
    params.update()
    ref = core_gradient(scene_file, w, ("lx", "ly", "lz"))
    assert np.linalg.norm(ref) > 0.05, ref
    assert_same_vector(g, ref)


BLOB_DEFAULTS = dict(bx=-0.625, by=1.375, bz=0.0, T=0.5)

# test_geometry_gradients' 6-centre blob (eq. 3.6-3.9), its first centre and threshold as parameters
BLOB_SCENE = _defaults(BLOB_DEFAULTS) + CAMERA.format(depth=3) + _with(
    BLOB, ('"-0.625 1.375 0 1 0.75,', '"$bx $by $bz 1 0.75,'),
    ('<float name="threshold" value="0.5"/>', '<float name="threshold" value="$T"/>'))


@pytest.mark.slow
def test_blob_centre_and_threshold_match_the_cores_finite_difference(variant, tmp_path):
    """d(loss)/d(first centre, threshold) of a ``links1_blob``: the plugin's implicit
    differentiation of W(x) = T against the core's frames (its own field and root finder) with
    the file's values moved. The kernel P is C¹ only (eq. 3.9), so where a pixel's point crosses
    r = S within ±h the central difference errs by O(h) (~2e-5 relative at h = 1e-3:
    test_geometry_gradients), and the plugin's float32 root carries ~1e-6 of the distance:
    tolerance 5e-4 of the vector's length (measured 2.4e-6)."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    path = tmp_path / "blob.xml"
    path.write_text(f'<scene version="3.0.0">{BLOB_SCENE}</scene>')
    scene = lm.load_file(str(path))
    w = interior(scene, "blob")
    params = mi.traverse(scene)
    ck, tk = "links1_whitted.blob.centers", "links1_whitted.blob.threshold"
    old_c, old_t = type(params[ck])(params[ck]), type(params[tk])(params[tk])
    c, T = type(params[ck])(params[ck]), type(params[tk])(params[tk])
    dr.enable_grad(c, T)
    params[ck], params[tk] = c, T
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    gc = np.array(dr.grad(c), dtype=np.float64)      # (3, centres): Point3f
    g = np.array([*gc[:, 0], float(np.array(dr.grad(T)).ravel()[0])])
    params[ck], params[tk] = old_c, old_t
    params.update()
    ref = core_gradient(path, w, ("bx", "by", "bz", "T"), BLOB_DEFAULTS)
    assert np.linalg.norm(ref[:3]) > 0.3 and abs(ref[3]) > 0.3, ref
    assert_same_vector(g, ref, tol=5e-4)
