"""The ``links1`` command line: ``render``, ``diff``, ``schedule``.

Bad input (scene or options) prints one line ``links1: error: ...`` naming what and where,
exits with status 2 and leaves no output file behind (``--debug`` shows the traceback).
"""
from __future__ import annotations

import argparse
import inspect
import os
import signal
import statistics
import sys
import threading
import time

import numpy as np

from links1 import __version__
from links1.errors import Links1Error, RenderAborted, UsageError, one_line_warnings
from links1.imaging.image import write_image
from links1.interrupts import (COMMAND_INTERRUPTED as _INTERRUPTED, held_interrupts, ignore_interrupts,
                               raise_if_interrupted, restore_interrupts, stop_resource_sharer)

from . import animate, diff
from .cli_options import (nonneg_int, adaptive_options, add_progress_arguments, add_render_arguments,
                          progress_choice, renderer_options)
from .partition import cli as partition_cli
from .partition import schedule
from .renderers import make_renderer, renderer_warnings, require_mitsuba

RENDER_EXAMPLES = """examples:
  links1 render scenes/fig11.xml -o fig11.png
  links1 render scenes/fig4.xml -o fig4.exr --renderer core --spp 16 --aov depth,normal,id,cost
  links1 render scenes/fig6a.xml -o blob.exr -D threshold=0.4 --width 512 --height 512
  links1 render scenes/many.xml -o many.exr --repeat 5          # prints a timing: line
"""

MAIN_EXAMPLES = """commands:
  render     render a Mitsuba 3 XML scene with the LINKS-1 method
  diff       compare two images (EXR/PNG) under a metric and threshold
  schedule   run a root/node screen-partitioning experiment
  animate    render a sequence of frames (per-frame $name values) over the nodes

examples:
  links1 render scenes/fig11.xml -o fig11.png
  links1 diff out/a.exr out/b.exr --metric relmse --threshold 1e-4 --heatmap d.png
  links1 schedule scenes/many.xml --nodes 4 --partition subscreen --report r.json --plot r.png
"""

class _Parser(argparse.ArgumentParser):
    """argparse with exit status 2 and a one-line message (argparse's default is close)."""

    def error(self, message):
        cmd = self.prog.split()[-1]       # "links1" itself: no second "links1:" after the prefix
        self.exit(2, f"links1: error: {message}\n" if cmd == "links1" else f"links1: error: {cmd}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="links1", description="LINKS-1 ray tracing: render Mitsuba 3 XML scenes, "
                     "compare images, run screen-partitioning experiments.",
                     epilog=MAIN_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"links1 {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("render", help="render a scene to EXR or PNG", epilog=RENDER_EXAMPLES,
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="Render a Mitsuba 3 XML scene with the LINKS-1 method. EXR output is "
                       "linear float32 (AOVs as extra channels); PNG is 8-bit sRGB.")
    add_render_arguments(p)
    p.add_argument("-o", "--output", required=True, help="output image (.exr or .png)")
    p.add_argument("--repeat", type=nonneg_int("--repeat"), default=0,
                   help="render N more frames and print 'timing: first=... ms median=... ms min=... ms max=... ms' on stderr")
    p.add_argument("--min-weight", type=float, default=None,
                   help="stop a ray-tree branch whose weight falls to this or below (default 1/255; 0: never)")
    add_progress_arguments(p)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.set_defaults(func=cmd_render)
    partition_cli.add_render_options(p)

    diff.add_cli(sub)             # links1 diff
    schedule.add_cli(sub)         # links1 schedule
    animate.add_cli(sub)          # links1 animate
    return parser


def _output_kind(path: str) -> str:
    low = path.lower()
    if low.endswith(".exr"):
        return "exr"
    if low.endswith(".png"):
        return "png"
    raise UsageError(f"output {path!r}: unknown image type (use .exr or .png)")


def make_cli_renderer(args):
    opts = renderer_options(args)
    if getattr(args, "min_weight", None) is not None:
        opts["min_weight"] = args.min_weight
    if getattr(args, "light_samples", None) is not None:
        opts["light_samples"] = args.light_samples
    opts.update(adaptive_options(args))
    if args.renderer == "mitsuba":
        opts["variant"] = args.variant
        if args.integrator == "scene":
            opts["integrator"] = "scene"
    elif args.variant is not None or args.integrator != "links1":
        raise UsageError("--variant and --integrator apply to --renderer mitsuba only")
    return make_renderer(args.renderer, args.scene, **opts)


def cmd_render(args) -> int:
    with held_interrupts():   # Mitsuba's native imports: Ctrl-C is raised once they are done
        if args.renderer == "mitsuba":
            require_mitsuba(args.variant)
        renderer_warnings(args.renderer)
    kind = _output_kind(args.output)
    if kind == "png" and args.aov:
        raise UsageError("AOVs need an EXR output (-o something.exr)")
    if args.min_weight is not None and not args.min_weight >= 0:
        raise UsageError(f"--min-weight must be >= 0, got {args.min_weight}")
    distributed = getattr(args, "workers", None) not in (None, 0) or getattr(args, "dask_local", None) \
        or getattr(args, "scheduler", None)
    t0 = time.perf_counter()
    if distributed:
        image, channels = partition_cli.render_distributed(args)
        first = time.perf_counter() - t0
        renderer = None
    else:
        renderer = make_cli_renderer(args)
        t0 = time.perf_counter()
        image = renderer.render(progress=progress_choice(args)) if _takes_progress(renderer) else renderer.render()
        first = time.perf_counter() - t0
        channels = renderer.channels
    if args.repeat:
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            if renderer is None:
                partition_cli.render_distributed(args)
            else:
                renderer.render()
            times.append(time.perf_counter() - t)
        print(f"timing: first={first * 1e3:.1f} ms median={statistics.median(times) * 1e3:.1f} ms "
              f"min={min(times) * 1e3:.1f} ms max={max(times) * 1e3:.1f} ms", file=sys.stderr)
    _check_finite_image(image, args.renderer)
    raise_if_interrupted()
    ignore_interrupts()   # the frame is complete: Ctrl-C from here on no longer stops its writing
    if kind == "png":
        write_image(args.output, image[..., :3])
    else:
        write_image(args.output, image, channels)
    print(f"links1: wrote {args.output} ({image.shape[1]}x{image.shape[0]}, {args.renderer})", file=sys.stderr)
    return 0


def _check_finite_image(image, renderer) -> None:
    """Never a silent NaN: scene values are checked where they enter
    (links1.scene.params), so a non-finite pixel is a bug; stop with one line and write nothing."""
    bad = ~np.isfinite(image)
    if bad.any():
        y, x = (int(v[0]) for v in np.nonzero(bad.any(axis=-1)))
        raise RenderAborted(f"the {renderer} renderer produced {int(bad.sum())} non-finite values "
                            f"(first at pixel {x},{y}); nothing written (a bug in links1: please report the scene)")


def _takes_progress(renderer) -> bool:
    try:
        return "progress" in inspect.signature(renderer.render).parameters
    except (TypeError, ValueError):
        return False


def main(argv=None, *, program: bool | None = None) -> int:
    """The command line -> exit status. Ctrl-C (SIGINT) at any moment: the line ``links1:
    interrupted``, status 130, no output file (it is written atomically, and once a finished
    frame is being written the interrupt is ignored: the file is then complete), no process left
    (the partitioning back ends stop their workers and clusters, :mod:`links1.interrupts`).
    ``program`` (default: ``argv`` is None, as the console script calls it): the process ends
    with this call, so after that line its stderr goes nowhere: what the standard library's
    teardown prints of the stopped pools (a queue's feeder thread writing to a pipe closed under
    it) is not the command's to show."""
    handler = hooks = None
    try:   # from the first statement: a Ctrl-C before the handler below is in place is Python's
        _INTERRUPTED.clear()
        handler = ignore_interrupts(False)
        if handler is signal.default_int_handler:   # Python's own (main thread): noted, then raised
            signal.signal(signal.SIGINT, _on_interrupt)
        hooks = threading.excepthook, sys.excepthook, sys.unraisablehook
        threading.excepthook, sys.excepthook = _quiet_once_interrupted, _quiet_sys_once_interrupted
        sys.unraisablehook = _quiet_unraisable_once_interrupted
        return _main(argv)
    except KeyboardInterrupt:
        _INTERRUPTED.set()    # (also when Python's own handler raised it, before ours was set)
        ignore_interrupts()   # a second Ctrl-C does not break what is left of the clean-up
        stop_resource_sharer()
        print("links1: interrupted", file=sys.stderr)
        if (argv is None) if program is None else program:
            _quiet_from_here()
        return 130
    finally:
        restore_interrupts(handler)   # main() called from Python: as it was
        if hooks is not None and not _INTERRUPTED.is_set():
            threading.excepthook, sys.excepthook, sys.unraisablehook = hooks


def _on_interrupt(signum, frame):
    _INTERRUPTED.set()
    signal.default_int_handler(signum, frame)


def _quiet_from_here() -> None:
    """stderr (the descriptor, so threads' direct prints too) to the null device."""
    try:
        sys.stderr.flush()
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
    except (OSError, ValueError):
        pass


def _quiet_unraisable_once_interrupted(unraisable) -> None:
    """``sys.unraisablehook`` of the command: the KeyboardInterrupt that Python drops there is
    the interrupt :func:`raise_if_interrupted` raises again, not an error to print."""
    if not (_INTERRUPTED.is_set() and isinstance(unraisable.exc_value, KeyboardInterrupt)):
        sys.__unraisablehook__(unraisable)


def _quiet_once_interrupted(args) -> None:
    """``threading.excepthook`` of the command: Python's, except that once Ctrl-C has reached the
    command an exception in a helper thread (the standard library's process pool marking a pool
    whose workers were stopped as broken) belongs to the teardown and is not printed around
    ``links1: interrupted``."""
    if not _INTERRUPTED.is_set():
        threading.__excepthook__(args)


def _quiet_sys_once_interrupted(exc_type, exc_value, exc_traceback) -> None:
    """``sys.excepthook`` likewise: multiprocessing's resource-sharer thread reports through it
    (a worker stopped while it was taking a connection resets the sharer's handshake)."""
    if not _INTERRUPTED.is_set():
        sys.__excepthook__(exc_type, exc_value, exc_traceback)


def _main(argv) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help(sys.stderr)
        return 2
    one_line_warnings()
    debug = getattr(args, "debug", False)
    try:
        return int(args.func(args) or 0)
    except Links1Error as e:
        if debug:
            raise
        print(f"links1: error: {e}", file=sys.stderr)
        return 2
    except RenderAborted as e:
        if debug:
            raise
        print(f"links1: error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # noqa: BLE001 - last resort: one line, not a traceback
        if debug:
            raise
        print(f"links1: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
