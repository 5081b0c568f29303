"""Shapes, their bounding-box hierarchies and the scene's accelerator (docs/method.md §3).

Modules
-------
bvh          the shape-agnostic hierarchy of bounding boxes (3-2-4): boxes in, packet and lock-step traversals
base         the shape contract: Shape, HierarchyTraced, the helpers shapes share
shapes       TriangleMesh (eq. 3.1-3.3), Quadric (3.4-3.5, clip planes), Disk
quadrics     the clipped quadric's arithmetic (3.4-3.5): its box, roots, clip interval, first hit
blob         weight-function surface (3.6-3.9): 'exact' and 'paper' solvers
sdfgrid      Mitsuba's sdfgrid: trilinear distance grid, the voxel cubic's first root
curves       Mitsuba's linearcurve: round linear segments (Embree's)
ellipsoids   Mitsuba's ellipsoids (entered from outside only) and ellipsoidsmesh (a shell per ellipsoid)
primset      the per-shape hierarchy walk shared by sdfgrid and curves
meshes       what every mesh source shares (vertex normals, transform, flip), rectangle / cube meshes
mesh_files   OBJ / PLY / serialized readers (OBJ / PLY writers)
bezier       bicubic Bezier patches: .patch files, inline lists, tessellation (eq. 3.3)
accel        the scene's accelerator (3-2-4): a BVH over the shapes; nearest hit, any-hit, shadow products

Imports only :mod:`links1.maths` (and :mod:`links1.errors`); never the scene loading, shading or tracing
(docs/architecture.md, "Packages").
"""
