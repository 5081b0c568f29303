"""The search of a blob's camera crossings by its margin's secant (boundary.py ``_narrowed``,
``guided``) against the bisection it replaces: the same crossings, to a few float32 steps of
the line parameter, in fewer queries.

A two-centre blob over a floor, seen from above at an angle, with a point light: its outline
against the floor, the seam where its lobes meet (a change of dominant centre on one sheet),
and its shadow edges (not guided: bisected in both runs)."""
from __future__ import annotations

import numpy as np
import pytest

from tests.plugins.test_boundary_gradients import FLOOR, PHONG, SHADOW_CAMERA, SHADOW_LIGHT
from tests.scenes import scene, whitted

pytestmark = pytest.mark.mitsuba

BLOB = f"""<shape type="links1_blob" id="blob">
    <string name="centers" value="-0.45 0.7 0 1 0.9,  0.45 0.8 0 1 0.9"/><float name="threshold" value="0.5"/>{PHONG}</shape>"""


@pytest.mark.slow
def test_guided_crossings_are_the_bisections(variant, tmp_path, monkeypatch):
    """Every crossing of the guided search is an interval no wider than the bisection's (one
    float32 step where that can be halved no further) whose first end sees what the
    interval's first point saw and whose last end does not (queried anew); on the blob's
    outline against the floor (``mode`` ±1) each is the bisection's to 8 float32 steps and
    takes at most 0.7 of its queries on average; on the seam of its lobes (``mode`` 2) at most
    0.8; the shadow edges' are the bisection's, bit for bit."""
    import drjit as dr
    import mitsuba as mi
    import links1_mitsuba as lm
    from links1_mitsuba import boundary
    path = tmp_path / "scene.xml"
    path.write_text(scene(whitted(1, projective=True) + SHADOW_CAMERA, FLOOR, BLOB, SHADOW_LIGHT))
    sc = lm.load_file(str(path))
    caught = []
    real = boundary._bisected

    def keep(P, scene_, *args):
        caught.append((P, scene_, args))
        return real(P, scene_, *args)
    monkeypatch.setattr(boundary, "_bisected", keep)
    params = mi.traverse(sc)
    key = "links1_whitted.blob.centers"
    dr.enable_grad(params[key])
    params.update()
    dr.backward(dr.sum(mi.render(sc, params, seed=0), axis=None))
    P, scene_, args = caught[-1]
    lo0, hi0, colm, fxd, key_, kd, c_lo, o_lo, c_hi = args
    runs = {}
    for guided in (False, True):
        boundary._drop_lines(P)
        out = boundary._narrowed(P, scene_, *args, guided)
        dr.eval(out)
        runs[guided] = [np.array(v) for v in out]
    mode = np.array(boundary._guides(P, kd, c_lo, c_hi)[0])
    kinds = np.array(kd)
    (lp, hp, sp_), (lg, hg, sg) = runs[False], runs[True]
    ulp = np.spacing(np.abs(lp).astype(np.float32))
    assert all(np.count_nonzero(mode == m) >= 20 for m in (1, -1, 2)), np.unique(mode, return_counts=True)
    assert np.all(hg - lg <= np.maximum(hp - lp, np.spacing(np.abs(lg).astype(np.float32)))), np.max(hg - lg - (hp - lp))
    # what the guided ends see, queried anew
    lts = boundary._lights(P)
    seen = []
    for e in (lg, hg):
        cm, sm = boundary._status(P, scene_, *boundary._at(mi.Float(e), colm, fxd), key_, lts, only=kd)
        occ = boundary._pick(kd, [cm[3]] + [s_[2] for s_ in sm])
        seen.append(np.array((cm[3] == c_lo) & ((kd == 0) | (occ == o_lo))))
    assert seen[0].all() and not seen[1].any()
    sil = (mode == 1) | (mode == -1)
    assert np.all(np.abs(lg - lp)[sil] <= 8 * ulp[sil]) and np.all(np.abs(hg - hp)[sil] <= 8 * ulp[sil])
    assert sg[sil].mean() <= 0.7 * sp_[sil].mean(), (sg[sil].mean(), sp_[sil].mean())
    assert sg[mode == 2].mean() <= 0.8 * sp_[mode == 2].mean(), (sg[mode == 2].mean(), sp_[mode == 2].mean())
    shadow = kinds > 0
    assert shadow.any() and np.array_equal(lg[shadow], lp[shadow]) and np.array_equal(sg[shadow], sp_[shadow])
