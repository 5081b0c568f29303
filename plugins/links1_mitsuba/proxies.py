"""``links1_quadric`` and ``links1_blob`` as Mitsuba plugins, for scenes Mitsuba loads itself.

Mitsuba 3.9.1 cannot hold a shape written in Python, so :func:`links1_mitsuba.load_file` takes
these two out of the file before Mitsuba instantiates it and hands them to ``links1_whitted``.
A file given to ``mi.load_file`` / ``mi.load_string`` (or a dict to ``mi.load_dict``) gets no
such help: for it each of the two is registered as a *proxy*, an empty :class:`mitsuba.Mesh`
(one triangle of zero area: Mitsuba's own ray queries never hit it) that carries the shape's parameters,
read by the same ``from_props`` as the loader, and its nested BSDF. ``links1_whitted`` finds the
proxies among the scene's shapes (:func:`specs_of`) and intersects the analytic surfaces
itself, as for a scene from :func:`links1_mitsuba.load_file`. Mitsuba's own integrators see
nothing there (as ``load_file(..., links1_integrator="scene")``, which warns).
"""
from __future__ import annotations

import copy

import numpy as np

#: the proxies made so far, by ``id()``: Mitsuba keeps the C++ object alive, this keeps the
#: Python one (and with it the spec), so ``scene.shapes()`` gives back the proxy class
_LIVE: dict = {}


def define_proxies() -> dict:
    """The proxy classes of the active variant: plugin name -> class."""
    import mitsuba as mi

    from .blob import BlobSpec
    from .shapes import QuadricSpec
    from .util import Hidden, hidden_attr

    def make(plugin, spec_cls):
        class Proxy(mi.Mesh):
            __doc__ = f"``{plugin}`` loaded by Mitsuba itself: an empty mesh holding the analytic shape."
            PLUGIN = plugin
            spec = hidden_attr("spec")    # (out of dr.freeze's walk of the scene)

            def __init__(self, props):
                self._hidden = Hidden()
                for k in props.keys():
                    if props.type(k) == mi.Properties.Type.Object and isinstance(props[k], mi.Emitter):
                        raise ValueError(f"{plugin}: an emitter inside this shape needs "
                                         "links1_mitsuba.load_file() (Mitsuba cannot sample an analytic "
                                         "surface's area)")
                # (the spec reads and checks the parameters as the loader's path does)
                self.spec = spec_cls.from_props(-1, props)
                # one triangle of zero area at the shape's origin: never hit (an empty mesh
                # would break Mitsuba's ray queries), and the scene's bounds stay the shape's
                super().__init__(props.id() or plugin, 3, 1, props)
                prm = mi.traverse(self)
                o = np.asarray(self.spec.to_world if self.spec.to_world is not None else np.eye(4))[:3, 3]
                prm["vertex_positions"] = mi.Float(np.tile(o, 3).astype(np.float32))
                prm["faces"] = mi.UInt32([0, 1, 2])
                prm.update()
                # a mesh attribute keeps Mitsuba's mesh merging (mi.load_file's default) away
                self.add_attribute("vertex_links1_proxy", 1, mi.Float([0.0, 0.0, 0.0]))
                _LIVE[id(self)] = self

            def to_string(self):
                return f"{type(self).__name__}[{plugin} {self.spec.name!r}]"

        Proxy.__name__ = Proxy.__qualname__ = "Links1" + plugin.split("_")[1].capitalize() + "Proxy"
        return Proxy

    return {"links1_quadric": make("links1_quadric", QuadricSpec),
            "links1_blob": make("links1_blob", BlobSpec)}


def is_proxy(shape) -> bool:
    return hasattr(shape, "spec") and getattr(shape, "PLUGIN", None) is not None


def specs_of(shapes) -> list:
    """``(index, spec)`` of each proxy among ``shapes`` (a scene's, in its order): a copy of the
    proxy's spec with the index as its slot."""
    out = []
    for i, s in enumerate(shapes):
        if is_proxy(s):
            sp = copy.copy(s.spec)
            sp.slot = i
            out.append((i, sp))
    return out
