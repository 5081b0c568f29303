"""What a hit point looks like: spectra, textures, materials, lights (docs/method.md §4.1-4.2).

Modules
-------
spectra      <spectrum> -> RGB exactly as Mitsuba's *_rgb variants (tables in links1/data)
textures     Mitsuba bitmap / checkerboard; a mesh's vertex_* / face_* attributes at the hit
materials    Phong (3.11), Mitsuba diffuse/conductor/dielectric/thindielectric/plastic/mask/null
lights       parallel, point (3.10), spot and projector (images), area lights and environments (sampled)

Imports :mod:`links1.maths`, :mod:`links1.geometry` (area lights on shapes) and
:mod:`links1.imaging` (bitmap textures) (docs/architecture.md, "Packages").
"""
