"""A Mitsuba 3 XML file to a :class:`links1.scene.scene.Scene`.

Modules
-------
params        the links1_* plugins' parameters and the scene-wide value rules (read by the plugin too)
xmlparse      Mitsuba 3 XML -> generic nodes (defaults, $params, include, path, ref, transforms)
loader        nodes -> Scene (Mitsuba semantics + links1 plugins; instances flattened); load_scene
properties    an element's parameters read with Mitsuba's rules (types, colours, spectra, textures)
load_sensors  the loader's sensors, films, filters, samplers
load_shapes   the loader's shapes (instances flattened)
load_bsdfs    the loader's BSDFs
load_emitters the loader's emitters
scene         the Scene: shapes, lights, camera, film, content-keyed caches
scenefile     a scene file read and built once, given other $name values in place (sequences)

Imports the packages below it (maths, imaging, geometry, shading, sensor), never tracing or a
front end (docs/architecture.md, "Packages").
"""
