"""Numbers with no scene objects in them: the bottom layer of the core.

Modules
-------
vec          elementwise (N,3) vector helpers (bit-stable whatever the batch size)
transform    4x4 transforms, Mitsuba conventions (look_at columns: left, up, dir, origin)
sampling     the deterministic sample pattern (shared with the plugin; exact spec inside)

Imports nothing of links1 (docs/architecture.md, "Packages").
"""
