"""Write ``links1/data/mitsuba_properties.json``: for each Mitsuba 3 plugin, the property names
its constructor may query.

Mitsuba's parser refuses a scene whose plugin leaves a property unqueried ("Found 1
unreferenced property in bsdf plugin of type ..."). The core reads only part of each
plugin's parameters, so it needs Mitsuba's list to tell a misspelt name (an error in both
renderers) from a real parameter the core ignores (a warning). This script reads the list
from Mitsuba's sources: every identifier-like string literal of the plugin's ``.cpp`` (and
the plugin-local headers it includes) — a superset of the names it queries, never a
subset — plus the names its base classes query (``src/render/*.cpp``, the
``include/mitsuba/render`` helpers it includes).

Usage::

    git clone --branch v3.9.1 https://github.com/mitsuba-renderer/mitsuba3 /tmp/mitsuba3
    python tools/make_mitsuba_properties.py /tmp/mitsuba3 > links1/data/mitsuba_properties.json
"""
from __future__ import annotations

import json
import os
import re
import sys

LITERAL = re.compile(r'"([a-z_][a-z0-9_]*)"')
QUERY = re.compile(r'props\.(?:get|get_texture|get_unbounded_texture|get_emissive_texture|get_volume|'
                   r'get_any|try_get|mark_queried)(?:<[^>(]*>)?\(\s*"([a-z_][a-z0-9_]*)"')
LOCAL_INCLUDE = re.compile(r'#include\s+"([^"]+)"')
RENDER_INCLUDE = re.compile(r'#include\s+<mitsuba/render/([a-z_]+\.h)>')

#: plugin directory -> (the element it is, the base-class sources whose queries it inherits)
CATEGORIES = {
    "bsdfs": ("bsdf", []),
    "shapes": ("shape", ["shape.cpp", "mesh.cpp"]),
    "emitters": ("emitter", ["emitter.cpp", "endpoint.cpp"]),
    "sensors": ("sensor", ["sensor.cpp", "endpoint.cpp"]),
    "films": ("film", ["film.cpp"]),
    "samplers": ("sampler", ["sampler.cpp"]),
    "rfilters": ("rfilter", []),
    "textures": ("texture", []),
    "spectra": ("spectrum", []),
    "integrators": ("integrator", ["integrator.cpp"]),
    "media": ("medium", ["medium.cpp"]),
    "phase": ("phase", []),
    "volumes": ("volume", ["volume.cpp"]),
}


def _read(path: str) -> str:
    with open(path, encoding="utf-8", errors="replace") as f:
        return f.read()


def plugin_names(root: str) -> dict:
    src = os.path.join(root, "src")
    render = os.path.join(src, "render")
    headers = os.path.join(root, "include", "mitsuba", "render")
    out = {}
    for folder, (tag, bases) in CATEGORIES.items():
        base_names = set()
        for b in bases:
            base_names |= set(QUERY.findall(_read(os.path.join(render, b))))
        cmake = _read(os.path.join(src, folder, "CMakeLists.txt"))
        for name, cpp in re.findall(r"add_plugin\(\s*(\w+)\s+(\w+\.cpp)", cmake):
            text = _read(os.path.join(src, folder, cpp))
            names = set(LITERAL.findall(text)) | base_names
            for inc in LOCAL_INCLUDE.findall(text):
                p = os.path.join(src, folder, inc)
                if os.path.isfile(p):
                    names |= set(LITERAL.findall(_read(p)))
            for inc in RENDER_INCLUDE.findall(text):
                p = os.path.join(headers, inc)
                if os.path.isfile(p):
                    names |= set(QUERY.findall(_read(p)))
            out.setdefault(tag, {})[name] = sorted(names)
    scene = set(QUERY.findall(_read(os.path.join(render, "scene.cpp"))))
    scene |= set(QUERY.findall(_read(os.path.join(render, "scene_embree.inl"))))
    scene |= set(QUERY.findall(_read(os.path.join(render, "kdtree.cpp"))))
    out["scene"] = {"scene": sorted(scene)}
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    data = {"mitsuba": "3.9.1", "source": "tools/make_mitsuba_properties.py",
            "plugins": plugin_names(argv[0])}
    json.dump(data, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
