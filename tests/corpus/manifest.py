"""The corpus: real Mitsuba 3 scenes from public repositories, and what each must do.

One entry per scene. ``committed`` scenes live under ``tests/corpus/<repo dir>/``; the others
have no licence that allows committing them (see SOURCES.md) and are copied, at the pinned
commit, into ``tests/corpus/external/`` by ``python tools/fetch_corpus.py`` (the corpus test
skips them, saying so, until then).

``expect``:
  ``"direct"``   delta lights and diffuse surfaces only: both renderers at ``max_depth`` 1
                 agree with Mitsuba's ``direct`` within 2x Mitsuba's own error at equal spp;
  ``"renders"``  both renderers render it without error or NaN, and each approximation listed
                 in ``warns`` is named in a one-line warning (``FILE:LINE: ...``).
``xfail``: renderer -> why it does not (yet) meet ``expect`` (the test is ``xfail(strict)``).

Every scene, whatever ``expect``, is also compared with ``whitted_reference``
(tests/corpus/whitted_reference.py: Mitsuba's sampling restricted to Whitted's light paths):
links1_whitted's relMSE against the reference at 16x the spp must be within 1.5x the
reference's own at equal spp. ``vs_reference``: why the plugin does not (yet), for a scene where
it does not (``xfail(strict)``); compare/results/corpus.md has the figures.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

HERE = os.path.dirname(os.path.abspath(__file__))
EXTERNAL = os.path.join(HERE, "external")

MITSUBA_DATA = ("mitsuba-renderer/mitsuba-data", "01100fa9b0b154492061a92404f26dcd7b784dbb")
TUTORIALS = ("mitsuba-renderer/mitsuba-tutorials", "a8dbee7e81b1039a983770ce1042f2d78688d0ae")
BLENDER = ("mitsuba-renderer/mitsuba-blender", "862d44f24fbebcd6ef4c6521cf2e1fc9aa49fbbe")

NO_LICENCE = "none stated (no LICENSE in the repository)"
BSD3 = "BSD-3-Clause (repository LICENSE)"


@dataclass(frozen=True)
class CorpusScene:
    id: str
    repo: str
    commit: str
    path: str
    licence: str
    committed: bool
    expect: str
    warns: tuple = ()
    xfail: dict = field(default_factory=dict)
    params: dict = field(default_factory=dict)
    vs_reference: str = ""

    @property
    def local_path(self) -> str:
        root = HERE if self.committed else EXTERNAL
        return os.path.join(root, self.repo.replace("/", "+"), self.path)


def _s(id, src, path, licence, committed, expect, **kw):
    return CorpusScene(id, src[0], src[1], path, licence, committed, expect, **kw)


SCENES = [
    _s("blender_test1", BLENDER, "tests/res/scenes/test1.xml", BSD3, True, "renders"),
    _s("data_hello", MITSUBA_DATA, "scenes/hello.xml", NO_LICENCE, False, "direct"),
    _s("data_directional", MITSUBA_DATA, "tests/scenes/floating_sphere/test_directional_direct.xml",
       NO_LICENCE, False, "direct"),
    _s("data_cbox_spectral", MITSUBA_DATA, "scenes/cbox/cbox-spectral.xml", NO_LICENCE, False, "direct",
       params={"spp": "4", "res": "32"}),
    _s("data_pointlight_spheres", MITSUBA_DATA, "tests/scenes/bsdf_spheres/test_pointlight_path.xml",
       NO_LICENCE, False, "renders"),
    _s("data_constant_spheres", MITSUBA_DATA, "tests/scenes/bsdf_spheres/test_constant_path.xml",
       NO_LICENCE, False, "renders"),
    _s("data_texture_interp", MITSUBA_DATA, "tests/scenes/texture_interp/test_texture_interp_direct.xml",
       NO_LICENCE, False, "direct"),  # no rfilter: Mitsuba's default gaussian, in both renderers
    _s("data_spot", MITSUBA_DATA, "tests/scenes/spot_light/test_spot_direct.xml",
       NO_LICENCE, False, "direct"),   # a projector: spot with a bitmap texture
    _s("data_mesh_attributes", MITSUBA_DATA,
       "tests/scenes/mesh_attributes/test_mesh_attributes_3_face_direct.xml",
       NO_LICENCE, False, "direct"),   # a PLY's face_color through a mesh_attribute texture
    _s("data_orthographic", MITSUBA_DATA, "tests/scenes/orthographic_sensor/test_orthographic_path.xml",
       NO_LICENCE, False, "direct"),
    _s("data_instancing", MITSUBA_DATA, "tests/scenes/instancing/test_instancing_path.xml",
       NO_LICENCE, False, "direct"),   # point light, diffuse: path at max_depth 2 is direct light
    _s("tutorials_simple", TUTORIALS, "scenes/simple.xml", NO_LICENCE, False, "direct",
       params={"spp": "4", "res": "32"}),
    # mirror and glass spheres: not a direct-light-only scene (Mitsuba's direct sees the light in
    # the mirror), so it is held to "renders" (its tent filter is rendered as Mitsuba's)
    _s("tutorials_cbox", TUTORIALS, "scenes/cbox.xml", NO_LICENCE, False, "renders"),
    # -- one scene or more per plugin family (mitsuba-data's documentation and test scenes; the
    # documentation scenes' objects are `serialized` meshes under an `envmap`)
    # shapes
    _s("data_serialized", MITSUBA_DATA, "docs/scenes/bsdf_diffuse_plain.xml", NO_LICENCE, False, "renders"),
    _s("data_sdfgrid", MITSUBA_DATA, "docs/scenes/shape_sdfgrid.xml", NO_LICENCE, False, "renders"),
    _s("data_bsplinecurve", MITSUBA_DATA, "docs/scenes/shape_bsplinecurve_basic.xml", NO_LICENCE, False,
       "renders"),
    _s("data_linearcurve", MITSUBA_DATA, "docs/scenes/shape_linearcurve_basic.xml", NO_LICENCE, False,
       "renders"),
    _s("data_cylinder", MITSUBA_DATA, "docs/scenes/shape_cylinder_twosided.xml", NO_LICENCE, False, "renders"),
    _s("data_disk", MITSUBA_DATA, "docs/scenes/shape_disk.xml", NO_LICENCE, False, "renders"),
    _s("data_ply_bunny", MITSUBA_DATA, "docs/scenes/shape_ply_bunny.xml", NO_LICENCE, False, "renders"),
    _s("data_sphere_light", MITSUBA_DATA, "docs/scenes/shape_sphere_light_analytic.xml", NO_LICENCE, False,
       "renders"),
    # BSDFs
    _s("data_conductor", MITSUBA_DATA, "docs/scenes/bsdf_conductor_gold.xml", NO_LICENCE, False, "renders"),
    _s("data_dielectric", MITSUBA_DATA, "docs/scenes/bsdf_dielectric_glass.xml", NO_LICENCE, False, "renders"),
    _s("data_thindielectric", MITSUBA_DATA, "docs/scenes/bsdf_thindielectric_glass.xml", NO_LICENCE, False,
       "renders"),
    _s("data_plastic", MITSUBA_DATA, "docs/scenes/bsdf_plastic_shiny.xml", NO_LICENCE, False, "renders"),
    _s("data_roughconductor", MITSUBA_DATA, "docs/scenes/bsdf_roughconductor_copper.xml", NO_LICENCE, False,
       "renders"),
    _s("data_roughdielectric", MITSUBA_DATA, "docs/scenes/bsdf_roughdielectric_glass.xml", NO_LICENCE, False,
       "renders"),
    _s("data_roughplastic", MITSUBA_DATA, "docs/scenes/bsdf_roughplastic_ggx.xml", NO_LICENCE, False, "renders"),
    _s("data_pplastic", MITSUBA_DATA, "docs/scenes/bsdf_pplastic.xml", NO_LICENCE, False, "renders"),
    _s("data_principled", MITSUBA_DATA, "tests/scenes/bsdf_spheres/test_texturedprincipled1_path.xml",
       NO_LICENCE, False, "renders"),
    _s("data_blendbsdf", MITSUBA_DATA, "docs/scenes/bsdf_blendbsdf.xml", NO_LICENCE, False, "renders"),
    _s("data_bumpmap", MITSUBA_DATA, "docs/scenes/bsdf_bumpmap_with.xml", NO_LICENCE, False, "renders"),
    _s("data_normalmap", MITSUBA_DATA, "docs/scenes/bsdf_normalmap_with.xml", NO_LICENCE, False, "renders"),
    _s("data_mask", MITSUBA_DATA, "docs/scenes/bsdf_mask_after.xml", NO_LICENCE, False, "renders"),
    # emitters
    _s("data_area_bitmap", MITSUBA_DATA, "tests/scenes/various_emitters/test_various_emitters_ptracer.xml",
       NO_LICENCE, False, "renders", params={"integrator": "path"}),
    _s("data_arealight_spheres", MITSUBA_DATA, "tests/scenes/bsdf_spheres/test_arealight_path.xml",
       NO_LICENCE, False, "renders"),
    _s("data_envmap_spheres", MITSUBA_DATA, "tests/scenes/bsdf_spheres/test_envmap_path.xml", NO_LICENCE,
       False, "renders"),
    _s("data_projector", MITSUBA_DATA, "tests/scenes/projector/test_projector_textured_direct.xml",
       NO_LICENCE, False, "renders"),
    # sensors
    _s("data_thinlens", MITSUBA_DATA, "docs/scenes/sensor_thinlens.xml", NO_LICENCE, False, "renders",
       params={"spp": "4"}),  # its $spp has no default before the sensor: plain mi.load_file needs it
]


def table_rows() -> list:
    """SOURCES.md's table rows (``python -m tests.corpus.manifest`` prints them)."""
    rows = ["| id | repository | path | commit | licence | committed | expected |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for s in SCENES:
        exp = s.expect + (f", warns {', '.join(repr(w) for w in s.warns)}" if s.warns else "")
        exp += "".join(f"; {k}: xfail ({v})" for k, v in s.xfail.items())
        exp += f"; vs reference: xfail ({s.vs_reference})" if s.vs_reference else ""
        rows.append(f"| `{s.id}` | [{s.repo}](https://github.com/{s.repo}) | `{s.path}` | "
                    f"`{s.commit[:12]}` | {s.licence} | {'yes' if s.committed else 'no'} | {exp} |")
    return rows


if __name__ == "__main__":
    print("\n".join(table_rows()))
