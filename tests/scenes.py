"""The Mitsuba scene XML the tests write: a perspective camera, an integrator, the scene around
them. One place for the boilerplate, so that each test file says only what its scene holds.

    scene(perspective("0, 2.5, 6", "0, 0.7, 0", fov=40, width=32), whitted(2), body)

Every argument is written as given; ``None`` leaves an element out, so Mitsuba's default holds
(no ``spp``: the independent sampler's 4 samples; no ``rfilter``: the gaussian filter).
"""
from __future__ import annotations

from collections.abc import Sequence


def vec(v: str | Sequence[float]) -> str:
    """A point or vector's ``value``: a string as it is, a sequence as ``repr`` floats (exact)."""
    return v if isinstance(v, str) else ", ".join(repr(float(x)) for x in v)


def prop(name: str, value) -> str:
    """One property element, its tag from the Python type (bool, int, float, str)."""
    if isinstance(value, bool):
        return f'<boolean name="{name}" value="{"true" if value else "false"}"/>'
    if isinstance(value, int):
        return f'<integer name="{name}" value="{value}"/>'
    if isinstance(value, float):
        return f'<float name="{name}" value="{value!r}"/>'
    return f'<string name="{name}" value="{value}"/>'


def integrator(kind: str, **props) -> str:
    """``<integrator type=kind>`` with ``props`` (see :func:`prop`)."""
    inner = "".join(prop(k, v) for k, v in props.items())
    return f'<integrator type="{kind}">{inner}</integrator>' if inner else f'<integrator type="{kind}"/>'


def whitted(max_depth: int, **props) -> str:
    """The links1_whitted integrator with ``max_depth`` and any other ``props``."""
    return integrator("links1_whitted", max_depth=max_depth, **props)


def perspective(origin, target, *, fov=40, width=24, height=None, spp: int | None = 1,
                rfilter: str | None = "box", up="0, 1, 0", near=None, far=None, inner="") -> str:
    """A perspective sensor looking from ``origin`` at ``target``: an hdrfilm ``width`` x
    ``height`` (square without ``height``), an independent sampler with ``spp`` samples and the
    ``rfilter`` type, or a whole ``<rfilter>`` element when the string starts with ``<`` (none:
    ``None`` or ``""``).
    ``inner`` is written inside the sensor (more properties, a medium)."""
    clips = "".join(prop(k, float(v)) for k, v in (("near_clip", near), ("far_clip", far)) if v is not None)
    sampler = (f'\n    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>'
               if spp is not None else "")
    filt = rfilter if not rfilter or rfilter.startswith("<") else f'<rfilter type="{rfilter}"/>'
    return (f'<sensor type="perspective"><float name="fov" value="{fov!r}"/>{clips}\n'
            f'    <transform name="to_world"><lookat origin="{vec(origin)}" target="{vec(target)}" '
            f'up="{vec(up)}"/></transform>{sampler}\n'
            f'    <film type="hdrfilm"><integer name="width" value="{width}"/>'
            f'<integer name="height" value="{width if height is None else height}"/>{filt}</film>{inner}</sensor>')


def scene(*parts: str, version: str = "3.0.0") -> str:
    """A whole scene file holding ``parts`` in order."""
    body = "\n  ".join(p for p in parts if p)
    return f'<scene version="{version}">\n  {body}\n</scene>\n'


def lit_floor(y: float, light=(2.0, 4.0, 3.0), intensity: float = 30.0, reflectance: float = 0.6) -> str:
    """A point light at ``light`` over a diffuse 8 x 8 floor (a ``rectangle``) at height ``y``."""
    return (f'<emitter type="point"><point name="position" value="{vec(light)}"/>'
            f'<rgb name="intensity" value="{intensity!r}"/></emitter>\n'
            f'  <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>'
            f'<translate y="{y!r}"/></transform>\n'
            f'    <bsdf type="diffuse"><rgb name="reflectance" value="{reflectance!r}"/></bsdf></shape>')
