"""The links1 plugin classes registered per Mitsuba variant: written by
:func:`links1_mitsuba.register` (``_registry``), read by the parts of ``links1_whitted`` that
recognise links1's own plugins in a scene (``isinstance`` against ``links1_phong``,
``links1_point``, ``links1_spot``). A leaf module, so that those parts need not import the
registry, which imports them."""
from __future__ import annotations

#: variant -> {plugin name: class}
REGISTERED: dict[str, dict] = {}


def plugin_class(name: str):
    """The class registered under ``name`` for the active variant."""
    import mitsuba as mi
    return REGISTERED[mi.variant()][name]
