"""What the links1 plugins are registered for: the Mitsuba variants they run on
(:data:`SUPPORTED_VARIANTS`, :func:`unsupported_variant`) and the classes registered per
variant, written by :func:`links1_mitsuba.register` (``_registry``) and read by the parts of
``links1_whitted`` that check the variant or recognise links1's own plugins in a scene
(``isinstance`` against ``links1_phong``, ``links1_point``, ``links1_spot``). A leaf module,
so that those parts need not import the registry, which imports them."""
from __future__ import annotations

#: variant -> {plugin name: class}. A registry, the plugin's one process-wide table besides the
#: module-wide tuning (``tuning.current``): like Mitsuba's own plugin registry, which it
#: mirrors, it is written once per variant (``links1_mitsuba.register``) and never per call;
#: per-call state (a load's places, a frozen launch's engine) is passed as arguments.
REGISTERED: dict[str, dict] = {}


def plugin_class(name: str):
    """The class registered under ``name`` for the active variant."""
    import mitsuba as mi
    return REGISTERED[mi.variant()][name]


#: The Mitsuba variants links1_whitted renders on (its kernels are Dr.Jit JIT code over RGB).
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")


def unsupported_variant(variant: str) -> str | None:
    """None if the links1 plugins can run on ``variant``, else one line saying why not and
    what works (scalar variants have no JIT arrays for the integrator's kernels; spectral and
    mono variants carry other spectra than the RGB triples its tables hold)."""
    works = "use the variant llvm_ad_rgb (CPU) or cuda_ad_rgb (NVIDIA GPU), or the core renderer (--renderer core)"
    if variant in SUPPORTED_VARIANTS:
        return None
    import mitsuba as mi
    if variant not in mi.variants():
        return f"unknown Mitsuba variant '{variant}' (this Mitsuba has {', '.join(mi.variants())}): {works}"
    if variant.startswith("scalar"):
        return (f"links1_whitted cannot run on variant {variant}: its kernels need a JIT variant "
                f"(Dr.Jit LLVM or CUDA arrays); {works}")
    what = "polarized " if "polarized" in variant else ""
    what += "spectral" if "spectral" in variant else "monochrome" if "mono" in variant else "non-RGB"
    return (f"links1_whitted cannot run on variant {variant}: the links1 plugins render RGB variants "
            f"only, not {what} ones; {works}")


_KIND_TAGS = {"Bool": "boolean", "Integer": "integer", "Float": "float", "Vector": "vector",
              "Transform": "transform", "Color": "rgb", "Spectrum": "spectrum", "String": "string"}


def check_properties(tag: str, plugin: str, props) -> None:
    """Refuse a property links1 plugin ``plugin`` does not take, before Mitsuba's own
    "unreferenced property" check would: ValueError ``<tag type='plugin' id='..'> <kind
    name='..'>: unknown parameter ...`` (:func:`links1.scene.params.unknown_in`, the rule of the
    core's reader and of :func:`links1_mitsuba.load_file`). This is what ``mi.load_file`` and
    ``mi.load_dict`` meet; :func:`links1_mitsuba.load_file` has judged the file before, naming
    its lines. Nested objects and the loader's own entries (``_...``) are not parameters."""
    from links1.scene.params import unknown_in
    kinds = {k: _KIND_TAGS[props.type(k).name] for k in props.keys()
             if not k.startswith("_") and props.type(k).name in _KIND_TAGS}
    found = unknown_in(tag, plugin, kinds)
    if found:
        name, message = found
        pid = props.id()
        elem = f"<{tag} type='{plugin}'" + (f" id='{pid}'" if pid and not pid.startswith("_") else "") + ">"
        raise ValueError(f"{elem} <{kinds[name]} name='{name}'>: {message}")
