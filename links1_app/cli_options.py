"""The options of ``links1 render`` and ``links1 schedule`` (:mod:`links1_app.cli`,
:mod:`links1_app.partition.cli`) and the renderer options they give.

Both command modules import this one and it imports neither, so the main parser and the
partitioning commands it wires in depend on one shared base
instead of on each other (docs/architecture.md, "Dependencies").
"""
from __future__ import annotations

import argparse

from links1.errors import UsageError
from links1.scene import params
from links1.tracing.adaptive import DEFAULT_ADAPTIVE_DEPTH, check_options
from links1.tracing.aovs import check_aovs


def int_option(name, minimum: int = 1, maximum: int | None = None):
    """An argparse type: an integer >= ``minimum`` (and <= ``maximum``), with a message naming
    the option."""
    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"{name} must be >= {minimum}, got {v}")
        if maximum is not None and v > maximum:
            raise argparse.ArgumentTypeError(f"{name} must be <= {maximum}, got {v}")
        return v
    return parse


def positive_int(name):
    return int_option(name, 1)


def nonneg_int(name):
    return int_option(name, 0)


def _define(text):
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"-D expects name=value, got {text!r}")
    return name, value


def _aov_list(text):
    try:
        return check_aovs(text)
    except UsageError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_render_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``render`` and ``schedule`` (scene, renderer, sampling)."""
    p.add_argument("scene", help="Mitsuba 3 XML scene file")
    p.add_argument("--renderer", choices=("mitsuba", "core"), default="mitsuba",
                   help="mitsuba: the links1_whitted Dr.Jit integrator (default); core: the float64 numpy reference")
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant for --renderer mitsuba: llvm_ad_rgb (default) or cuda_ad_rgb (default "
                        "with a GPU); scalar, spectral and mono variants are refused")
    p.add_argument("--sensor", type=nonneg_int("--sensor"), default=None, metavar="K",
                   help="render from the scene's sensor K (0-based, file order; default 0): its camera, "
                        "film and sample count")
    p.add_argument("--integrator", choices=("links1", "scene"), default="links1",
                   help="mitsuba renderer: links1_whitted (default) or the integrator the file names")
    p.add_argument("--spp", type=positive_int("--spp"), default=None, help="samples per pixel (default: the scene's)")
    p.add_argument("--width", type=positive_int("--width"), default=None, help="film width override")
    p.add_argument("--height", type=positive_int("--height"), default=None, help="film height override")
    p.add_argument("--max-depth", type=int_option("--max-depth", 1, params.MAX_MAX_DEPTH), default=None,
                   help="surface interactions per ray-tree branch (default: the scene's, else 5)")
    p.add_argument("--seed", type=nonneg_int("--seed"), default=0, help="seed of the sample pattern (spp > 1)")
    p.add_argument("--light-samples", type=int_option("--light-samples", 1, params.MAX_LIGHT_SAMPLES), default=None,
                   help="shadow rays per area light / environment per sample (default 1)")
    p.add_argument("--aov", type=_aov_list, default=(), help="extra EXR channels: depth,normal,id,cost,samples")
    p.add_argument("--adaptive", type=float, default=None, metavar="THRESHOLD",
                   help="adaptive anti-aliasing: split a pixel's square of samples while "
                        "its corners differ by more than THRESHOLD (tone-mapped v/(1+v), e.g. 0.05); "
                        "replaces --spp")
    p.add_argument("--adaptive-depth", type=nonneg_int("--adaptive-depth"), default=None, metavar="D",
                   help="most refinement levels of --adaptive (default 2: up to 5x5 samples per pixel)")
    p.add_argument("-D", dest="defines", type=_define, action="append", default=[], metavar="NAME=VALUE",
                   help="set a scene parameter ($NAME), overriding its <default>")


def add_progress_arguments(p: argparse.ArgumentParser) -> None:
    """``--progress`` / ``--no-progress``; neither: a bar only when stderr is a terminal."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--progress", action="store_true",
                   help="show the progress bar even when stderr is not a terminal")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def progress_choice(args) -> bool | None:
    """``progress=`` of the renderers from :func:`add_progress_arguments`'s options: True
    (``--progress``), False (``--no-progress``) or None (a bar only on a terminal)."""
    if getattr(args, "progress", False):
        return True
    return False if getattr(args, "no_progress", False) else None


def renderer_options(args) -> dict:
    opts = dict(params=dict(args.defines), spp=args.spp, max_depth=args.max_depth, seed=args.seed,
                aovs=tuple(args.aov))
    if getattr(args, "sensor", None) is not None:
        opts["sensor"] = args.sensor
    if args.width is not None or args.height is not None:  # film override (keeps the fov)
        opts.update(width=args.width, height=args.height)
    return opts


def adaptive_options(args) -> dict:
    """``adaptive``/``adaptive_depth`` renderer options from ``--adaptive``/``--adaptive-depth``."""
    if getattr(args, "adaptive", None) is None:
        if getattr(args, "adaptive_depth", None) is not None:
            raise UsageError("--adaptive-depth needs --adaptive THRESHOLD")
        return {}
    if args.spp is not None:
        raise UsageError("--adaptive replaces --spp: give one of them")
    if args.renderer == "mitsuba" and getattr(args, "integrator", "links1") == "scene":
        raise UsageError("--adaptive needs the links1 integrator (not --integrator scene)")
    depth = DEFAULT_ADAPTIVE_DEPTH if args.adaptive_depth is None else args.adaptive_depth
    t, d = check_options(args.adaptive, depth)
    return {"adaptive": t, "adaptive_depth": d}
