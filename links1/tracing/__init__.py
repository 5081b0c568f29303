"""Rays through a scene to pixels: the Whitted recursion, AOVs, adaptive anti-aliasing, render.

Modules
-------
occluders    which shapes can shadow each light (no shadow rays where no occluder can be)
integrator   Whitted recursion (3.12-3.16), shadows with transmittance, AOVs
aovs         the AOV table and its one checker
adaptive     adaptive anti-aliasing: the lattice, its refinement, the driver both renderers share
render       render(scene, ...) -> (H, W, C) float64 (also ``links1.render``); CoreRenderer

The top layer of the core: may import every core package; imported by the plugin and the front
ends (docs/architecture.md, "Packages").
"""
