"""The plugin's ``exact`` blob solver with many centres: each ray sums only its candidate
centres (those whose 3S sphere its line crosses, found with a hierarchy of boxes), held in
registers, in a local-memory list when there are more, or all centres beyond that. Checked
against the float64 core (links1/geometry/blob.py) and against the plugin's own all-centres sum."""
from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba


def _cloud(n, seed):
    """n centres on a jittered grid in the plane y = 0 (spacing 1, S = 0.6, one negative)."""
    rng = np.random.default_rng(seed)
    m = int(np.ceil(np.sqrt(n)))
    ij = np.array([(i, j) for i in range(m) for j in range(m)][:n], dtype=np.float64) - (m - 1) / 2
    c = np.c_[ij[:, 0] + rng.uniform(-0.15, 0.15, n), rng.uniform(-0.2, 0.2, n),
              ij[:, 1] + rng.uniform(-0.15, 0.15, n), np.ones(n), np.full(n, 0.6)]
    c[n // 2, 3] = -0.5
    return c


def _row(n):
    """n centres along the x axis, spacing 0.5: a ray along the axis crosses all of them."""
    x = np.arange(n) * 0.5 - n / 4
    return np.c_[x, np.zeros(n), np.zeros(n), np.ones(n), np.full(n, 0.6)]


def _rays(c, n, seed):
    """Rays from above and from the side toward random points among the centres, plus rays
    along the x axis (grazing a row: many candidates)."""
    rng = np.random.default_rng(seed)
    lo, hi = c[:, :3].min(0) - 1, c[:, :3].max(0) + 1
    tgt = rng.uniform(lo, hi, (n, 3))
    o = tgt + rng.normal(size=(n, 3)) * [3.0, 0.0, 3.0] + [0.0, 12.0, 0.0]
    o[: n // 4] = tgt[: n // 4] + [-40.0, 0.3, 0.0] + rng.normal(size=(n // 4, 3)) * [0, 0.3, 0.3]
    d = tgt - o
    return o, d / np.linalg.norm(d, axis=1)[:, None]


def _plugin(spec, o, d, lists):
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba import blob_candidates
    old = blob_candidates.LIST_MIN_CENTRES
    blob_candidates.LIST_MIN_CENTRES = 1 if lists else 10 ** 9
    try:
        n = len(o)
        cost = dr.zeros(mi.UInt32, n)
        O, D = mi.Vector3f(o.T), mi.Vector3f(d.T)
        t, prim = spec.intersect(O, D, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, n), cost)
        ng = spec.normal(O, D, t, prim)
        tsh, _ = spec.intersect(O, D, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, n), None, any_hit=True)
        return (np.array(t, dtype=np.float64), np.array(ng, dtype=np.float64).reshape(3, -1).T,
                np.array(cost), np.array(tsh, dtype=np.float64))
    finally:
        blob_candidates.LIST_MIN_CENTRES = old


@pytest.mark.slow
@pytest.mark.parametrize("centres", ["cloud300", "row80"])
def test_candidate_lists_match_core_and_all_centres(centres, variant):
    from links1.geometry.blob import Blob
    from links1_mitsuba.blob import BlobSpec
    from links1_mitsuba.blob_candidates import LIST_CAP, SLOTS
    c = _cloud(300, 3) if centres == "cloud300" else _row(80)
    o, d = _rays(c, 4000, 5)
    if centres == "row80":   # along the row: all 80 centres (more than the list holds)
        o[:200] = [-60.0, 0.0, 0.0] + np.random.default_rng(1).normal(size=(200, 3)) * [0, 0.05, 0.05]
        d[:200] = [1.0, 0.0, 0.0]
    spec = BlobSpec(0, "b", c, 0.5, "exact")
    t_l, n_l, cost_l, sh_l = _plugin(spec, o, d, lists=True)
    t_a, n_a, cost_a, sh_a = _plugin(spec, o, d, lists=False)
    core = Blob(c, 0.5, solver="exact")
    t_c, _ = core.intersect(o, d, np.zeros(len(o)), np.full(len(o), np.inf))
    # the candidate counts the test reaches: registers, local list, and (row80) all centres
    rel = c[None, :, :3] - o[:, None, :]
    met = np.sum(np.sum(np.cross(rel, d[:, None, :]) ** 2, axis=2) < 9 * c[None, :, 4] ** 2, axis=1)
    assert np.any((met > 0) & (met <= SLOTS)) and np.any(met > SLOTS)
    if centres == "row80":
        assert np.any(met > LIST_CAP)
    hc, hl, ha = np.isfinite(t_c), np.isfinite(t_l), np.isfinite(t_a)
    assert hc.sum() > len(o) // 4
    # candidates only, or all centres: the same terms, summed in another order (float32 rounding)
    assert np.array_equal(hl, ha)
    both = hl & hc
    assert np.max(np.abs(t_l[hl] - t_a[hl]) / t_a[hl]) <= 1e-5
    dc = np.abs(cost_l.astype(int) - cost_a.astype(int))   # evaluations: the same march
    assert np.mean(dc > 1) <= 3e-2 and abs(cost_l.mean() / cost_a.mean() - 1) <= 1e-2
    assert np.max(np.abs(n_l[hl] - n_a[hl])) <= 1e-5
    # against the float64 core
    assert np.mean(hl != hc) <= 5e-3   # grazing rays along the rows (float32 tangents)
    assert np.max(np.abs(t_l[both] - t_c[both]) / t_c[both]) <= 1e-4
    # shadow rays (any hit): blocked exactly where the nearest-hit query hits
    assert np.array_equal(np.isfinite(sh_l), hl)



@pytest.mark.parametrize("centres", ["cloud300", "row80"])
def test_normal_reuses_hit_search_candidates(centres, variant):
    """The normal sums over the nearest-hit search's candidates of the same ray (every
    centre whose 3S sphere the line crosses) instead of walking the hierarchy again with the
    hit point: the same non-zero terms in the same (leaf) order, so the same bits."""
    import drjit as dr
    import mitsuba as mi
    from links1_mitsuba.blob import BlobSpec
    c = _cloud(300, 3) if centres == "cloud300" else _row(80)
    o, d = _rays(c, 4000, 5)
    if centres == "row80":   # along the row: more candidates than the list holds
        o[:200] = [-60.0, 0.0, 0.0] + np.random.default_rng(1).normal(size=(200, 3)) * [0, 0.05, 0.05]
        d[:200] = [1.0, 0.0, 0.0]
    spec = BlobSpec(0, "b", c, 0.5, "exact")
    assert spec.uses_lists()
    n = len(o)
    O, D = mi.Vector3f(o.T), mi.Vector3f(d.T)
    t, prim = spec.intersect(O, D, mi.Float(0.0), mi.Float(np.inf), dr.ones(mi.Bool, n), dr.zeros(mi.UInt32, n))
    assert spec._line is not None
    n_reuse = spec.normal(O, D, t, prim, reuse=True)
    assert spec._line is None   # consumed: the next call walks (or uses the next search's)
    n_walk = spec.normal(O, D, t, prim, reuse=True)
    dr.eval(t, n_reuse, n_walk)   # the list is a local array of the search's kernel
    n_reuse, n_walk = np.array(n_reuse), np.array(n_walk)
    hit = np.isfinite(np.array(t))
    assert hit.sum() > n // 4
    assert np.array_equal(n_reuse.view(np.uint32), n_walk.view(np.uint32))


@pytest.mark.slow
def test_many_centre_blob_scene_matches_core(tmp_path, variant):
    """A 120-centre blob lit by a point light over a mirror floor, through the renderer
    (frozen launch, shadow rays, reflections, normals): plugin against the core."""
    import warnings
    from links1.scene.loader import load_scene
    from links1.tracing.render import render
    from links1_mitsuba import MitsubaRenderer
    from links1_mitsuba.blob_candidates import LIST_MIN_CENTRES
    c = _cloud(120, 7)
    assert len(c) >= LIST_MIN_CENTRES
    centres = " ".join(f"{v:.6g}" for v in c.ravel())
    path = tmp_path / "cloud.xml"
    path.write_text(f"""<scene version="3.0.0">
  <integrator type="links1_whitted"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 9, 11" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="48"/><integer name="height" value="48"/>
      <rfilter type="box"/></film></sensor>
  <shape type="links1_blob"><string name="centers" value="{centres}"/><float name="threshold" value="0.5"/>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.7, 0.3, 0.2"/>
      <rgb name="specular" value="0.4"/><float name="exponent" value="30"/></bsdf></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="12"/><rotate x="1" angle="-90"/>
    <translate y="-0.8"/></transform>
    <bsdf type="links1_phong"><rgb name="ambient" value="0.03"/><rgb name="diffuse" value="0.4"/>
      <rgb name="reflectance" value="0.3"/></bsdf></shape>
  <emitter type="links1_point"><point name="position" x="3" y="8" z="4"/><rgb name="L1" value="0.9"/></emitter>
</scene>""")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = MitsubaRenderer(str(path), aovs=("id",))
        plug = r.integrator.render_window(r.scene, None, spp=1, seed=0, aovs=("id",))
        core = render(load_scene(str(path)), spp=1, seed=0, aovs=("id",))
    a, b = plug[..., :3], core[..., :3]
    assert np.all(np.isfinite(a)) and b.max() > 0.1
    hit_a, hit_b = plug[..., 3] == 0, core[..., 3] == 0      # the blob (slot 0)
    assert hit_b.mean() > 0.2
    assert np.mean(hit_a != hit_b) <= 1e-3
    assert float(np.sum((a - b) ** 2) / np.sum(b ** 2)) <= 1e-5
