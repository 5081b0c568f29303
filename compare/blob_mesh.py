"""The ``links1_blob`` against a triangle mesh of the same surface in Embree, both rendered by
``links1_whitted``, at 1, 4 and 16 samples per pixel.

    python -m compare.blob_mesh [--res 512] [--centres 10,100] [--spp 1,4,16] [--step 0.05]
                                [--rounds 3] [--frames 5]

The scene: ``compare.scaling.blob_centres(k)`` (k centres, S = 0.6, on a unit grid) as one
``links1_blob`` (threshold 0.5) under a directional light, and the same with the blob replaced by
a mesh of its surface, as a user without the plugin would make it: the field ``W(x) =
sum_i w_i P(|x - c_i|)`` (eq. 3.6-3.9) sampled on a grid of ``--step`` and its level set
``W = T`` extracted by marching tetrahedra (:func:`marching_tetrahedra`: each grid cube cut into
six tetrahedra around its main diagonal, so neighbouring cubes share their faces' cuts and the
mesh is closed; a vertex where an edge crosses the level, linearly interpolated), written as a
PLY file (``mi.Mesh.write_ply``) and loaded as Mitsuba's ``ply``. The same ``links1_phong``
material on both.

Each (k, shape, spp) renders in its own process, ``--rounds`` interleaved rounds of ``--frames``
warm frames; the table gives medians over the rounds, the ratio blob / mesh per round (its
median) and the triangles of the mesh. Target: the blob within 2x its mesh at spp 16.

Writes ``compare/results/blob_mesh.{json,md}``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from . import common
from .common import md_table
from .quadric_spp import measure_frames, parse, spawn
from .scaling import CAMERA, blob_centres

THRESHOLD = 0.5
MATERIAL = ('<bsdf type="links1_phong"><rgb name="ambient" value="0.05"/><rgb name="diffuse" value="0.7"/>'
            '<rgb name="specular" value="0.2"/><float name="exponent" value="20"/></bsdf>')

#: the six tetrahedra of a cube around its diagonal 0-7 (corner k at offset ((k>>2)&1, (k>>1)&1, k&1))
TETS = np.array([[0, 7, 1, 3], [0, 7, 3, 2], [0, 7, 2, 6], [0, 7, 6, 4], [0, 7, 4, 5], [0, 7, 5, 1]])


def _falloff(r, S):
    """``P(r)`` of eq. 3.6-3.9: ``1 - r²/(3S²)`` within S, ``(r - 3S)²/(6S²)`` within 3S, 0 beyond."""
    return np.where(r < S, 1.0 - r * r / (3 * S * S), np.where(r < 3 * S, (r - 3 * S) ** 2 / (6 * S * S), 0.0))


def blob_field(centres, x):
    """``W(x) = sum_i w_i P(|x - c_i|)`` (eq. 3.6-3.9) at points ``x`` (n, 3), per centre
    ``(cx, cy, cz, w, S)``."""
    return sum(w * _falloff(np.linalg.norm(x - (cx, cy, cz), axis=1), S) for cx, cy, cz, w, S in centres)


def grid_field(centres, origin, step, shape):
    """:func:`blob_field` on the grid ``origin + step * index`` of ``shape``: each centre adds
    its term to the grid points within its range 3S only."""
    W = np.zeros(shape)
    for cx, cy, cz, w, S in centres:
        c = np.array([cx, cy, cz])
        a = np.maximum(np.floor((c - 3 * S - origin) / step).astype(int), 0)
        b = np.minimum(np.ceil((c + 3 * S - origin) / step).astype(int) + 1, shape)
        ax = [origin[i] + step * np.arange(a[i], b[i]) - c[i] for i in range(3)]
        r = np.sqrt(ax[0][:, None, None] ** 2 + ax[1][None, :, None] ** 2 + ax[2][None, None, :] ** 2)
        W[a[0]:b[0], a[1]:b[1], a[2]:b[2]] += w * _falloff(r, S)
    return W


def marching_tetrahedra(f, origin, step):
    """Triangles ``(n, 3, 3)`` of the level set ``f = 0`` of samples ``f`` (nx, ny, nz) on the grid
    ``origin + step * index``, each turned so that its normal points toward ``f < 0``."""
    nx, ny, nz = f.shape
    corner = np.array([[(k >> 2) & 1, (k >> 1) & 1, k & 1] for k in range(8)])
    pos_in = [f[a:nx - 1 + a, b:ny - 1 + b, c:nz - 1 + c] > 0 for a, b, c in corner]
    crossed = np.logical_or.reduce(pos_in) & ~np.logical_and.reduce(pos_in)   # cubes the level crosses
    idx = np.argwhere(crossed)
    vals = np.stack([f[idx[:, 0] + a, idx[:, 1] + b, idx[:, 2] + c] for a, b, c in corner], 1)
    pos = (idx[:, None, :] + corner[None]) * step + origin    # (m, 8, 3)
    tris = []
    for tet in TETS:
        p, v = pos[:, tet], vals[:, tet]                      # (m, 4, 3), (m, 4)
        inside = v > 0
        code = inside @ (1 << np.arange(4))

        def cut(i, j, sel):
            t = v[sel, i] / (v[sel, i] - v[sel, j])
            return p[sel, i] + t[:, None] * (p[sel, j] - p[sel, i])

        for c in range(1, 15):
            sel = code == c
            if not sel.any():
                continue
            ins = [k for k in range(4) if c >> k & 1]
            out = [k for k in range(4) if not c >> k & 1]
            if len(ins) == 1 or len(out) == 1:
                a, others = (ins[0], out) if len(ins) == 1 else (out[0], ins)
                new = [np.stack([cut(a, o, sel) for o in others], 1)]
            else:
                (a, b), (e, g) = ins, out
                q = [cut(a, e, sel), cut(a, g, sel), cut(b, g, sel), cut(b, e, sel)]
                new = [np.stack([q[0], q[1], q[2]], 1), np.stack([q[0], q[2], q[3]], 1)]
            # outward: from the inside corners' centre toward the outside corners'
            away = p[sel][:, out].mean(1) - p[sel][:, ins].mean(1)
            for t3 in new:
                n = np.cross(t3[:, 1] - t3[:, 0], t3[:, 2] - t3[:, 0])
                flip = np.sum(n * away, 1) < 0
                t3[flip] = t3[flip][:, ::-1]
                tris.append(t3)
    return np.concatenate(tris) if tris else np.zeros((0, 3, 3))


def blob_mesh_ply(k, step, path):
    """The mesh of the blob of ``blob_centres(k)`` at grid ``step`` written to ``path`` (PLY):
    its triangle count."""
    import mitsuba as mi
    c, _ = blob_centres(k)
    lo = c[:, :3].min(0) - 3 * c[:, 4].max() - step
    hi = c[:, :3].max(0) + 3 * c[:, 4].max() + step
    n = np.ceil((hi - lo) / step).astype(int) + 1
    f = grid_field(c, lo, step, tuple(n)) - THRESHOLD
    tris = marching_tetrahedra(f, lo, step)
    verts = tris.reshape(-1, 3).astype(np.float32)
    mesh = mi.Mesh("blob", len(verts), len(tris))
    prm = mi.traverse(mesh)
    prm["vertex_positions"] = mi.Float(verts.ravel())
    prm["faces"] = mi.UInt32(np.arange(len(verts), dtype=np.uint32))
    prm.update()
    mesh.write_ply(str(path))
    return len(tris)


def scene_xml(k, ply=None):
    c, m = blob_centres(k)
    cam = CAMERA.format(ex=0, ey=f"{0.95 * m + 1:.6g}", ez=f"{0.95 * m + 1:.6g}")
    if ply is None:
        vals = " ".join(f"{v:.6g}" for v in c.ravel())
        shape = (f'<shape type="links1_blob"><string name="centers" value="{vals}"/>'
                 f'<float name="threshold" value="{THRESHOLD}"/>{MATERIAL}</shape>')
    else:
        shape = f'<shape type="ply"><string name="filename" value="{ply}"/>{MATERIAL}</shape>'
    return (f'<scene version="3.0.0">\n<default name="res" value="64"/>\n<integrator type="links1_whitted">'
            f'<integer name="max_depth" value="1"/></integrator>\n{cam}\n{shape}\n'
            '<emitter type="directional"><vector name="direction" x="-0.4" y="-1" z="-0.3"/>'
            '<rgb name="irradiance" value="2"/></emitter>\n</scene>\n')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m compare.blob_mesh")
    ap.add_argument("--centres", default="10,100")
    ap.add_argument("--step", type=float, default=0.05, help="grid step of the marching tetrahedra")
    a = parse(ap, argv, measure_frames, frames=5)
    if a is None:
        return 0
    ks, spps = [int(v) for v in a.centres.split(",") if v], a.spps
    with tempfile.TemporaryDirectory() as d:
        paths, tris = {}, {}
        for k in ks:
            ply = Path(d) / f"blob{k}.ply"
            tris[k] = blob_mesh_ply(k, a.step, ply)
            for shape, arg in (("blob", None), ("mesh", ply)):
                paths[(k, shape)] = Path(d) / f"{shape}{k}.xml"
                paths[(k, shape)].write_text(scene_xml(k, arg))
        got = {(k, s, shape): [] for k in ks for s in spps for shape in ("blob", "mesh")}
        for rnd in range(a.rounds):
            for key in got:
                got[key].append(spawn("compare.blob_mesh", {"path": str(paths[(key[0], key[2])]), "spp": key[1],
                                                            "res": a.res, "frames": a.frames}))
                print(f"  round {rnd} k={key[0]} spp={key[1]} {key[2]}: {got[key][-1]['wall_ms']:.1f} ms",
                      file=sys.stderr, flush=True)
    rows = []
    for k in ks:
        for s in spps:
            b, m = got[(k, s, "blob")], got[(k, s, "mesh")]
            row = {"centres": k, "spp": s, "triangles": tris[k]}
            for name, rs in (("blob", b), ("mesh", m)):
                for f in ("wall_ms", "cpu_ms", "tests"):
                    row[f"{name}_{f}"] = float(np.median([r[f] for r in rs]))
                row[f"{name}_kernel_ms"] = float(np.median([sum(x["ms"] for x in r["kernels"]) for r in rs]))
            row["ratio"] = float(np.median([x["wall_ms"] / y["wall_ms"] for x, y in zip(b, m)]))
            row["cpu_ratio"] = float(np.median([x["cpu_ms"] / y["cpu_ms"] for x, y in zip(b, m)]))
            rows.append(row)
    out = {"machine": a.info, "command": a.command, "res": a.res, "step": a.step, "rows": rows,
           "wall_s": time.perf_counter() - a.t0}
    md = ["# links1_blob against a marching-tetrahedra mesh of its surface in Embree\n\n",
          common.machine_markdown(a.info, a.command),
          f"\nThe machine's two cores are shared with other processes: compare ratios within a run.\n\n"
          f"links1_whitted, {a.res}², `compare.blob_mesh.scene_xml(k)`; mesh: grid step {a.step}. Each case "
          f"in its own process, {a.rounds} interleaved rounds of {a.frames} warm frames; ms: medians over the "
          "rounds; ratio: median of the rounds' blob / mesh (wall; CPU: process CPU time); tests / sample: the "
          "`cost` AOV over the camera samples (the blob's field evaluations, one per Embree query; camera and "
          "shadow rays). Target: the blob within 2x its mesh at spp 16.\n\n",
          md_table(["centres", "spp", "triangles", "blob ms", "mesh ms", "ratio", "CPU ratio", "blob kernels ms",
                    "mesh kernels ms", "blob tests / sample", "mesh tests / sample", "target (spp 16: <= 2)"],
                   [[r["centres"], r["spp"], r["triangles"], r["blob_wall_ms"], r["mesh_wall_ms"], r["ratio"],
                     r["cpu_ratio"], r["blob_kernel_ms"], r["mesh_kernel_ms"], r["blob_tests"], r["mesh_tests"],
                     ("met" if r["ratio"] <= 2.0 else "missed") if r["spp"] == 16 else "–"] for r in rows])]
    text = "".join(md)
    written = common.write_results("blob_mesh", out, text, None)
    print(text)
    print("wrote", *(str(p.relative_to(common.ROOT)) for p in written), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
