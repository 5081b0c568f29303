"""links1_mitsuba: the LINKS-1 method as Mitsuba 3 plugins.

Plugins (registered per variant by :func:`register`): integrator ``links1_whitted``, emitters
``links1_point`` and ``links1_spot``, BSDF ``links1_phong``, mesh shape ``links1_bicubic``.
The analytic shapes ``links1_quadric`` and ``links1_blob`` are read by :func:`load_file` /
:func:`load_string` and intersected by ``links1_whitted`` itself (Mitsuba 3.9.1 has no
Python shapes).

Public API::

    register(variant=None) -> str
    log_to_warnings() -> None        Mitsuba's log warnings through Python's warnings (the CLI)
    load_file(path, *, links1_integrator="links1", variant=None, params=None, **scene_params) -> mi.Scene
    load_string(xml, *, links1_integrator="links1", variant=None, base_dir=None, params=None,
                **scene_params) -> mi.Scene
                                     (every other keyword is a scene's $name, as mi.load_file's)
    MitsubaRenderer(path, *, params=None, spp=None, max_depth=None, seed=0, aovs=(), variant=None,
                    integrator="links1", width=None, height=None, min_weight=None)
                                     (defaults: links1.scene.params.PLUGINS["integrator", "links1_whitted"])
"""
from __future__ import annotations

from ._registry import (SUPPORTED_VARIANTS, default_variant, log_to_warnings, probe_variant, register,
                        unsupported_variant)

__all__ = ["register", "load_file", "load_string", "MitsubaRenderer", "default_variant",
           "probe_variant", "log_to_warnings", "SUPPORTED_VARIANTS", "unsupported_variant"]


def load_file(path, **kwargs):
    from .loader import load_file as _lf
    return _lf(path, **kwargs)


load_file.__doc__ = "See :func:`links1_mitsuba.loader.load_file`."


def load_string(xml, **kwargs):
    from .loader import load_string as _ls
    return _ls(xml, **kwargs)


load_string.__doc__ = "See :func:`links1_mitsuba.loader.load_string`."


def __getattr__(name):
    if name == "MitsubaRenderer":
        from .renderer import MitsubaRenderer
        return MitsubaRenderer
    raise AttributeError(name)
